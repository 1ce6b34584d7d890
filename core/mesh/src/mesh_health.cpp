// Downsampling of class volumes and the health checks every mesh passes before the rig goes on.
#include <Eigen/Dense>

#include <algorithm>
#include <cmath>

#include "posewarp/common/disjoint_sets.h"
#include "posewarp/common/parallel.h"
#include "posewarp/mesh/mesher.h"

namespace posewarp::mesh {

Status validate(const MeshParams& p) {
  auto positive = [](double value, const char* name) -> Status {
    if (!(value > 0.0) || !std::isfinite(value)) {
      return invalid_argument_error(std::string("mesh parameter ") + name + " must be positive (got " +
                                    std::to_string(value) + ")");
    }
    return ok_status();
  };
  POSEWARP_RETURN_IF_ERROR(positive(p.facet_size_mm, "facet_size_mm"));
  POSEWARP_RETURN_IF_ERROR(positive(p.facet_distance_mm, "facet_distance_mm"));
  POSEWARP_RETURN_IF_ERROR(positive(p.bone_cell_size_mm, "bone_cell_size_mm"));
  POSEWARP_RETURN_IF_ERROR(positive(p.soft_cell_size_mm, "soft_cell_size_mm"));
  if (p.facet_angle_deg <= 0.0 || p.facet_angle_deg > 30.0) {
    return invalid_argument_error("mesh facet_angle_deg must lie in (0, 30] degrees (larger may never terminate)");
  }
  if (p.cell_radius_edge_ratio < 2.0) {
    return invalid_argument_error("mesh cell_radius_edge_ratio must be at least 2 (refinement may not terminate)");
  }
  if (p.size_growth < 0.0) return invalid_argument_error("mesh size_growth must not be negative");
  if (p.voxel_budget < 1000) return invalid_argument_error("mesh voxel_budget must be at least 1000 voxels");
  if (!(p.exude_time_limit_s >= 0.0) || !std::isfinite(p.exude_time_limit_s)) {
    return invalid_argument_error("mesh exude_time_limit_s must be a finite number of seconds, 0 or more");
  }
  if (p.max_vertices < 1000 || p.max_vertices > 50'000'000) {
    return invalid_argument_error("mesh max_vertices must lie in 1000..50000000");
  }
  constexpr double kSmallestMm = 0.25;  // below a quarter millimetre no CT or MR mesh is meaningful
  for (const auto& [value, name] : {std::pair{p.facet_size_mm, "facet_size_mm"}, {p.bone_cell_size_mm, "bone_cell_size_mm"},
                                    {p.soft_cell_size_mm, "soft_cell_size_mm"}}) {
    if (value < kSmallestMm) {
      return invalid_argument_error(std::string("mesh parameter ") + name + " must be at least 0.25 mm (got " +
                                    std::to_string(value) + "); finer meshes grow without bound");
    }
  }
  if (!(p.joint_cell_size_mm == 0.0 || (p.joint_cell_size_mm >= kSmallestMm && p.joint_cell_size_mm <= 1000.0))) {
    return invalid_argument_error("mesh joint_cell_size_mm must be 0 (off) or 0.25..1000 mm (got " +
                                  std::to_string(p.joint_cell_size_mm) + ")");
  }
  if (!(p.joint_radius_mm >= 0.0 && p.joint_radius_mm <= 1000.0)) {
    return invalid_argument_error("mesh joint_radius_mm must lie in 0..1000 mm (got " + std::to_string(p.joint_radius_mm) + ")");
  }
  if (!(p.parallel_watchdog_s >= 0.0) || !std::isfinite(p.parallel_watchdog_s)) {
    return invalid_argument_error("mesh parallel_watchdog_s must be a finite number of seconds, 0 or more (0: none)");
  }
  return ok_status();
}

Index3 downsample_factor_for(const ImageGeometry& g, int64_t budget) {
  Index3 factor{1, 1, 1};
  auto count = [&] {
    int64_t n = 1;
    for (int a = 0; a < 3; ++a) n *= (g.size[a] + factor[a] - 1) / factor[a];
    return n;
  };
  // Grow the factor of the finest axis first, so the downsampled grid becomes more isotropic.
  while (count() > budget) {
    int finest = 0;
    for (int a = 1; a < 3; ++a) {
      if (g.spacing[a] * factor[a] < g.spacing[finest] * factor[finest]) finest = a;
    }
    ++factor[finest];
  }
  return factor;
}

LabelVolume downsample_classes(const LabelVolume& classes, const Index3& factor) {
  if (factor == Index3{1, 1, 1}) return classes;
  const ImageGeometry& in = classes.geometry();
  ImageGeometry out = in;
  for (int a = 0; a < 3; ++a) {
    out.size[a] = (in.size[a] + factor[a] - 1) / factor[a];
    out.spacing[a] = in.spacing[a] * static_cast<double>(factor[a]);
  }
  out.origin = in.index_to_physical({(factor[0] - 1) / 2.0, (factor[1] - 1) / 2.0, (factor[2] - 1) / 2.0});
  LabelVolume result(out, 0);
  result.set_source_type(classes.source_type());
  Label max_class = 0;
  for (const Label c : classes.voxels()) max_class = std::max(max_class, c);
  parallel_for(0, out.size[2], 1, [&](int64_t k0, int64_t k1) {
    std::vector<int> votes(static_cast<size_t>(max_class) + 1);
    for (int64_t k = k0; k < k1; ++k) {
      for (int64_t j = 0; j < out.size[1]; ++j) {
        for (int64_t i = 0; i < out.size[0]; ++i) {
          std::fill(votes.begin(), votes.end(), 0);
          int total = 0;
          for (int64_t dk = 0; dk < factor[2]; ++dk)
            for (int64_t dj = 0; dj < factor[1]; ++dj)
              for (int64_t di = 0; di < factor[0]; ++di) {
                const int64_t x = i * factor[0] + di, y = j * factor[1] + dj, z = k * factor[2] + dk;
                if (!classes.contains(x, y, z)) continue;
                ++votes[static_cast<size_t>(classes.at(x, y, z))];
                ++total;
              }
          int bone_votes = 0, best_bone = 0;
          for (size_t c = kFirstBoneClass; c < votes.size(); ++c) {
            bone_votes += votes[c];
            if (votes[c] > votes[static_cast<size_t>(best_bone)] || best_bone == 0) {
              if (votes[c] > 0) best_bone = static_cast<int>(c);
            }
          }
          Label value = 0;
          if (best_bone != 0 && 4 * bone_votes >= total) {
            value = best_bone;
          } else if (2 * (total - votes[0]) >= total) {
            value = kSoftTissueClass;
          }
          result.at(i, j, k) = value;
        }
      }
    }
  });
  return result;
}

int64_t separate_bone_segments(TetMesh& mesh) {
  const int segments = mesh.segment_count;
  if (segments < 2) return 0;
  // Incident bone tets per (vertex, segment).
  std::vector<int32_t> counts(static_cast<size_t>(mesh.vertex_count()) * static_cast<size_t>(segments), 0);
  for (int64_t t = 0; t < mesh.tet_count(); ++t) {
    const int k = mesh.tet_class(t) - kFirstBoneClass;
    if (k < 0 || k >= segments) continue;
    for (int c = 0; c < 4; ++c) ++counts[static_cast<size_t>(mesh.tets(t, c)) * static_cast<size_t>(segments) + static_cast<size_t>(k)];
  }
  std::vector<int32_t> owner(static_cast<size_t>(mesh.vertex_count()), -1);
  for (int64_t v = 0; v < mesh.vertex_count(); ++v) {
    const int32_t* row = counts.data() + v * segments;
    int best = -1;
    for (int k = 0; k < segments; ++k) {
      if (row[k] > 0 && (best < 0 || row[k] > row[best])) best = k;
    }
    owner[static_cast<size_t>(v)] = best;
  }
  int64_t relabelled = 0;
  for (int64_t t = 0; t < mesh.tet_count(); ++t) {
    const int k = mesh.tet_class(t) - kFirstBoneClass;
    if (k < 0 || k >= segments) continue;
    for (int c = 0; c < 4; ++c) {
      const int32_t o = owner[static_cast<size_t>(mesh.tets(t, c))];
      if (o >= 0 && o != k) {
        mesh.tet_class(t) = kSoftTissueClass;
        ++relabelled;
        break;
      }
    }
  }
  return relabelled;
}

int64_t split_bone_gaps(TetMesh& mesh) {
  const int segments = mesh.segment_count;
  const int64_t n = mesh.vertex_count();
  if (segments < 2) return 0;
  // Each vertex's bone segments, as a bit set (segments beyond 64 share bits: a conservative "in common").
  std::vector<uint64_t> bones(static_cast<size_t>(n), 0);
  for (int64_t t = 0; t < mesh.tet_count(); ++t) {
    const int k = mesh.tet_class(t) - kFirstBoneClass;
    if (k < 0 || k >= segments) continue;
    for (int c = 0; c < 4; ++c) bones[static_cast<size_t>(mesh.tets(t, c))] |= uint64_t{1} << (k % 64);
  }
  std::vector<std::array<int32_t, 4>> tets(static_cast<size_t>(mesh.tet_count()));
  std::vector<int> classes(static_cast<size_t>(mesh.tet_count()));
  std::vector<std::vector<int32_t>> vertex_tets(static_cast<size_t>(n));
  std::vector<std::pair<int32_t, int32_t>> gap_edges;
  for (int64_t t = 0; t < mesh.tet_count(); ++t) {
    for (int c = 0; c < 4; ++c) {
      tets[static_cast<size_t>(t)][static_cast<size_t>(c)] = mesh.tets(t, c);
      vertex_tets[static_cast<size_t>(mesh.tets(t, c))].push_back(static_cast<int32_t>(t));
    }
    classes[static_cast<size_t>(t)] = mesh.tet_class(t);
    for (int a = 0; a < 4; ++a) {
      for (int b = a + 1; b < 4; ++b) {
        const int32_t u = mesh.tets(t, a), w = mesh.tets(t, b);
        const uint64_t bu = bones[static_cast<size_t>(u)], bw = bones[static_cast<size_t>(w)];
        if (bu != 0 && bw != 0 && (bu & bw) == 0) gap_edges.emplace_back(std::min(u, w), std::max(u, w));
      }
    }
  }
  std::sort(gap_edges.begin(), gap_edges.end());
  gap_edges.erase(std::unique(gap_edges.begin(), gap_edges.end()), gap_edges.end());
  std::vector<Eigen::Vector3d> added;
  for (const auto& [u, w] : gap_edges) {
    const auto m = static_cast<int32_t>(n + static_cast<int64_t>(added.size()));
    added.emplace_back(0.5 * (mesh.vertices.row(u) + mesh.vertices.row(w)).transpose());
    vertex_tets.emplace_back();
    // Every tet holding u and w now (earlier splits may have made more of them): one half keeps u, the other w.
    std::vector<int32_t> holding;
    for (const int32_t t : vertex_tets[static_cast<size_t>(u)]) {
      const auto& corner = tets[static_cast<size_t>(t)];
      if (std::find(corner.begin(), corner.end(), w) != corner.end()) holding.push_back(t);
    }
    for (const int32_t t : holding) {
      const auto half = static_cast<int32_t>(tets.size());
      std::array<int32_t, 4> other = tets[static_cast<size_t>(t)];
      for (int32_t& v : tets[static_cast<size_t>(t)]) v = v == w ? m : v;  // t keeps u
      for (int32_t& v : other) v = v == u ? m : v;                         // the new half keeps w
      tets.push_back(other);
      classes.push_back(classes[static_cast<size_t>(t)]);
      for (const int32_t v : other) {
        if (v == w) {
          std::replace(vertex_tets[static_cast<size_t>(w)].begin(), vertex_tets[static_cast<size_t>(w)].end(), t, half);
        } else if (v == m) {
          vertex_tets[static_cast<size_t>(m)].push_back(t);
          vertex_tets[static_cast<size_t>(m)].push_back(half);
        } else {
          vertex_tets[static_cast<size_t>(v)].push_back(half);
        }
      }
    }
  }
  if (added.empty()) return 0;
  mesh.vertices.conservativeResize(n + static_cast<Eigen::Index>(added.size()), 3);
  for (size_t i = 0; i < added.size(); ++i) mesh.vertices.row(n + static_cast<Eigen::Index>(i)) = added[i].transpose();
  mesh.tets.resize(static_cast<Eigen::Index>(tets.size()), 4);
  mesh.tet_class.resize(static_cast<Eigen::Index>(tets.size()));
  for (size_t t = 0; t < tets.size(); ++t) {
    for (int c = 0; c < 4; ++c) mesh.tets(static_cast<Eigen::Index>(t), c) = tets[t][static_cast<size_t>(c)];
    mesh.tet_class(static_cast<Eigen::Index>(t)) = classes[t];
  }
  return static_cast<int64_t>(added.size());
}

Status check_mesh_health(const TetMesh& mesh, const LabelVolume& classes, const std::vector<std::string>& segment_names,
                         MeshHealth* health) {
  MeshHealth local;
  MeshHealth& h = health ? *health : local;
  const int class_count = kFirstBoneClass + mesh.segment_count;
  h.tets_per_class.assign(static_cast<size_t>(class_count), 0);
  h.voxel_volume_ml.assign(static_cast<size_t>(class_count), 0.0);
  h.mesh_volume_ml.assign(static_cast<size_t>(class_count), 0.0);
  h.lost_segments.clear();
  const ImageGeometry& g = classes.geometry();
  const double voxel_ml = g.spacing[0] * g.spacing[1] * g.spacing[2] / 1000.0;
  for (const Label c : classes.voxels()) {
    if (c > 0 && c < class_count) h.voxel_volume_ml[static_cast<size_t>(c)] += voxel_ml;
  }
  h.degenerate_tets = 0;
  h.min_tet_quality = 1.0;
  for (int64_t t = 0; t < mesh.tet_count(); ++t) {
    const int c = mesh.tet_class(t);
    if (c < kSoftTissueClass || c >= class_count) {
      return internal_error("tet " + std::to_string(t) + " has class " + std::to_string(c) + " outside 1.." +
                            std::to_string(class_count - 1));
    }
    const Eigen::Vector3d a = mesh.vertices.row(mesh.tets(t, 0));
    const Eigen::Vector3d e1 = mesh.vertices.row(mesh.tets(t, 1)).transpose() - a;
    const Eigen::Vector3d e2 = mesh.vertices.row(mesh.tets(t, 2)).transpose() - a;
    const Eigen::Vector3d e3 = mesh.vertices.row(mesh.tets(t, 3)).transpose() - a;
    const double volume = e1.dot(e2.cross(e3)) / 6.0;
    double longest = std::max({e1.norm(), e2.norm(), e3.norm(), (e2 - e1).norm(), (e3 - e1).norm(), (e3 - e2).norm()});
    // 6 sqrt(2) V / l_max^3 is 1 for a regular tet and 0 for a flat one.
    const double quality = longest > 0.0 ? 6.0 * std::sqrt(2.0) * volume / (longest * longest * longest) : 0.0;
    h.min_tet_quality = std::min(h.min_tet_quality, quality);
    if (quality < 1e-4) ++h.degenerate_tets;
    ++h.tets_per_class[static_cast<size_t>(c)];
    h.mesh_volume_ml[static_cast<size_t>(c)] += volume / 1000.0;
  }
  double voxel_body = 0.0, mesh_body = 0.0;
  h.max_bone_volume_error = 0.0;
  for (int c = kSoftTissueClass; c < class_count; ++c) {
    voxel_body += h.voxel_volume_ml[static_cast<size_t>(c)];
    mesh_body += h.mesh_volume_ml[static_cast<size_t>(c)];
    if (c >= kFirstBoneClass && h.voxel_volume_ml[static_cast<size_t>(c)] > 0.0) {
      const double error = std::abs(h.mesh_volume_ml[static_cast<size_t>(c)] - h.voxel_volume_ml[static_cast<size_t>(c)]) /
                           h.voxel_volume_ml[static_cast<size_t>(c)];
      h.max_bone_volume_error = std::max(h.max_bone_volume_error, error);
    }
  }
  h.body_volume_error = voxel_body > 0.0 ? std::abs(mesh_body - voxel_body) / voxel_body : 0.0;

  // Components through shared vertices.
  DisjointSets components(mesh.vertex_count());
  std::vector<uint8_t> used(static_cast<size_t>(mesh.vertex_count()), 0);
  for (int64_t t = 0; t < mesh.tet_count(); ++t) {
    for (int corner = 0; corner < 4; ++corner) {
      used[static_cast<size_t>(mesh.tets(t, corner))] = 1;
      components.unite(mesh.tets(t, 0), mesh.tets(t, corner));
    }
  }
  h.body_components = 0;
  for (int64_t v = 0; v < mesh.vertex_count(); ++v) {
    if (used[static_cast<size_t>(v)] && components.find(v) == v) ++h.body_components;
  }

  for (int k = 0; k < mesh.segment_count; ++k) {
    const size_t c = static_cast<size_t>(kFirstBoneClass + k);
    if (h.voxel_volume_ml[c] > 0.0 && h.tets_per_class[c] == 0) {
      h.lost_segments.push_back(k < static_cast<int>(segment_names.size()) ? segment_names[static_cast<size_t>(k)]
                                                                            : "segment " + std::to_string(k));
    }
  }
  if (mesh.tet_count() == 0) {
    return failed_precondition_error("the mesher produced no tetrahedra; check that the body mask is not empty and "
                                     "that the mesh sizes are not larger than the body");
  }
  if (!h.lost_segments.empty()) {
    std::string names;
    for (const std::string& name : h.lost_segments) names += (names.empty() ? "" : ", ") + name;
    return failed_precondition_error("the mesh lost bone segment(s) " + names +
                                     " (too thin for the mesh sizes); lower --bone-size/--facet-size or "
                                     "--facet-distance so they are meshed");
  }
  return ok_status();
}

}  // namespace posewarp::mesh
