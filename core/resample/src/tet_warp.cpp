// TetWarp: rasterize posed tets over output slabs (each thread owns whole slabs, as ITK threads over output
// regions), resolve folds (bones win), extend boundary tets over the skin shell, then sample the source.
#include "posewarp/resample/tet_warp.h"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <limits>
#include <new>

#include "posewarp/common/parallel.h"

namespace posewarp::resample {
namespace {

constexpr double kInsideTolerance = 1e-9;

// Affine physical -> continuous index of a grid: u = M (x - o).
struct IndexSpace {
  Eigen::Matrix3d to_index;
  Eigen::Vector3d origin;
  Eigen::Matrix3d to_physical;  // inverse of to_index: x = o + to_physical u
};

IndexSpace index_space(const ImageGeometry& g) {
  Eigen::Matrix3d d;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) d(r, c) = g.direction[static_cast<size_t>(3 * r + c)] * g.spacing[static_cast<size_t>(c)];
  return {d.inverse(), Eigen::Vector3d(g.origin[0], g.origin[1], g.origin[2]), d};
}

// Height of every vertex over its opposite face, mm (for the shell distance).
std::array<double, 4> heights(const Eigen::Vector3d v[4]) {
  const double six_volume = std::abs((v[1] - v[0]).dot((v[2] - v[0]).cross(v[3] - v[0])));
  std::array<double, 4> h{};
  for (int m = 0; m < 4; ++m) {
    const Eigen::Vector3d& a = v[(m + 1) % 4];
    const Eigen::Vector3d& b = v[(m + 2) % 4];
    const Eigen::Vector3d& c = v[(m + 3) % 4];
    const double twice_area = (b - a).cross(c - a).norm();
    h[static_cast<size_t>(m)] = twice_area > 0.0 ? six_volume / twice_area : 0.0;
  }
  return h;
}

// Per-tet data for rasterizing in output index space: barycentric map and the inside interval of a row.
// Barycentrics of voxel (i, j, k) are lambda_m = origin[m] + i * di[m] + j * dj[m] + k * dk[m] for m = 0..3
// (lambda_0 = 1 - lambda_1 - lambda_2 - lambda_3), all affine in the output index.
struct RasterTet {
  double origin[4], di[4], dj[4], dk[4];
  double inv_di[4];  // 1 / di, 0 where di is 0
  double lo[3], hi[3];  // index bounding box
};

// floor and ceil without libm calls (baseline x86-64 has no SSE4.1 rounding instruction); |x| < 2^62.
inline double fast_floor(double x) {
  const double t = static_cast<double>(static_cast<int64_t>(x));
  return t - (x < t);
}
inline double fast_ceil(double x) {
  const double t = static_cast<double>(static_cast<int64_t>(x));
  return t + (x > t);
}

// The i-interval of row (j, k) inside the tet, intersected with [first, last]; false when empty.
inline bool row_interval(const RasterTet& r, int64_t j, int64_t k, int64_t& first, int64_t& last, double tolerance) {
  double lo = static_cast<double>(first), hi = static_cast<double>(last);
  const double jd = static_cast<double>(j), kd = static_cast<double>(k);
  for (int m = 0; m < 4; ++m) {
    const double alpha = r.origin[m] + jd * r.dj[m] + kd * r.dk[m] + tolerance;  // alpha + di * i >= 0
    if (r.di[m] > 0.0) {
      lo = std::max(lo, fast_ceil(-alpha * r.inv_di[m]));
    } else if (r.di[m] < 0.0) {
      hi = std::min(hi, fast_floor(-alpha * r.inv_di[m]));
    } else if (alpha < 0.0) {
      return false;
    }
  }
  if (lo > hi) return false;
  first = static_cast<int64_t>(lo);
  last = static_cast<int64_t>(hi);
  return true;
}

// Round to nearest without a libm call (ties away from zero do not matter at voxel centres).
inline int64_t round_index(double x) {
  const double y = x + 0.5;
  int64_t r = static_cast<int64_t>(y);
  return r - (y < static_cast<double>(r));
}

inline void apply_map(const double* m, double i, double j, double k, double s[3]) {
  s[0] = m[0] * i + m[1] * j + m[2] * k + m[9];
  s[1] = m[3] * i + m[4] * j + m[5] * k + m[10];
  s[2] = m[6] * i + m[7] * j + m[8] * k + m[11];
}

}  // namespace

Status validate(const ResampleParams& params) {
  if (params.shell_mm < 0.0 || !std::isfinite(params.shell_mm)) return invalid_argument_error("shell_mm must be >= 0");
  if (params.max_output_voxels < 1) return invalid_argument_error("max_output_voxels must be positive");
  if (params.grow_margin_mm < 0.0) return invalid_argument_error("grow_margin_mm must be >= 0");
  return ok_status();
}

RestTopology rest_topology(const TetMesh& rest) {
  // A face is on the boundary when exactly one tet has it: sort all faces and look for unpaired ones.
  constexpr int kFaces[4][3] = {{1, 2, 3}, {0, 2, 3}, {0, 1, 3}, {0, 1, 2}};
  struct Face {
    std::array<int32_t, 3> key;
    int32_t tet;
  };
  std::vector<Face> faces;
  faces.reserve(static_cast<size_t>(rest.tet_count()) * 4);
  for (int64_t t = 0; t < rest.tet_count(); ++t) {
    for (const auto& f : kFaces) {
      std::array<int32_t, 3> key{rest.tets(t, f[0]), rest.tets(t, f[1]), rest.tets(t, f[2])};
      std::sort(key.begin(), key.end());
      faces.push_back({key, static_cast<int32_t>(t)});
    }
  }
  std::sort(faces.begin(), faces.end(), [](const Face& a, const Face& b) { return a.key < b.key; });
  std::vector<uint8_t> boundary(static_cast<size_t>(rest.tet_count()), 0);
  for (size_t i = 0; i < faces.size();) {
    size_t j = i + 1;
    while (j < faces.size() && faces[j].key == faces[i].key) ++j;
    if (j - i == 1) boundary[static_cast<size_t>(faces[i].tet)] = 1;
    i = j;
  }
  RestTopology topology;
  for (int64_t t = 0; t < rest.tet_count(); ++t) {
    if (boundary[static_cast<size_t>(t)]) topology.boundary_tets.push_back(static_cast<int32_t>(t));
  }
  return topology;
}

Result<TetWarp> TetWarp::build(const TetMesh& rest, const RestTopology& topology, const Eigen::MatrixXd& posed,
                               const ImageGeometry& source, const ImageGeometry& output,
                               const Eigen::Matrix3d& background_rotation, const Eigen::Vector3d& background_translation,
                               const std::vector<uint8_t>* rest_coverage, const ResampleParams& params,
                               const ProgressHooks& hooks) {
  POSEWARP_RETURN_IF_ERROR(validate(params));
  if (posed.rows() != rest.vertex_count() || posed.cols() != 3) {
    return invalid_argument_error("posed vertices (" + std::to_string(posed.rows()) + ") do not match the mesh (" +
                                  std::to_string(rest.vertex_count()) + ")");
  }
  POSEWARP_RETURN_IF_ERROR(source.validate().with_context("source grid"));
  POSEWARP_RETURN_IF_ERROR(output.validate().with_context("output grid"));
  if (output.voxel_count() > params.max_output_voxels) {
    return resource_exhausted_error("the output grid has " + std::to_string(output.voxel_count()) +
                                    " voxels, over the limit of " + std::to_string(params.max_output_voxels));
  }
  if (rest_coverage && static_cast<int64_t>(rest_coverage->size()) != source.voxel_count()) {
    return invalid_argument_error("the rest coverage mask does not match the source grid");
  }
  StageProgress progress(hooks, "warp-prepare");
  TetWarp warp;
  warp.source_ = source;
  warp.output_ = output;
  warp.rest_coverage_ = rest_coverage;
  warp.label_background_ = params.label_background;
  warp.intensity_background_ = params.intensity_background;
  const double shell_mm =
      params.shell_mm > 0.0 ? params.shell_mm : 1.5 * std::max({source.spacing[0], source.spacing[1], source.spacing[2]});

  try {
    const IndexSpace out_space = index_space(output);
    const IndexSpace src_space = index_space(source);
    const int64_t nt = rest.tet_count();

    // Background: output index -> output physical -> rest physical (inverse rigid) -> source index.
    {
      const Eigen::Matrix3d a = src_space.to_index * background_rotation.transpose() * out_space.to_physical;
      const Eigen::Vector3d b =
          src_space.to_index * (background_rotation.transpose() * (out_space.origin - background_translation) - src_space.origin);
      for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) warp.background_map_[3 * r + c] = a(r, c);
        warp.background_map_[9 + r] = b(r);
      }
    }

    // Vertices into output (posed) and source (rest) index space once, row-major.
    const int64_t nv = rest.vertex_count();
    std::vector<double> posed_index(static_cast<size_t>(nv) * 3), rest_index(static_cast<size_t>(nv) * 3);
    parallel_for(0, nv, 8192, [&](int64_t begin, int64_t end) {
      for (int64_t v = begin; v < end; ++v) {
        const Eigen::Vector3d u = out_space.to_index * (posed.row(v).transpose() - out_space.origin);
        const Eigen::Vector3d s = src_space.to_index * (rest.vertices.row(v).transpose() - src_space.origin);
        for (int a = 0; a < 3; ++a) {
          posed_index[static_cast<size_t>(3 * v + a)] = u(a);
          rest_index[static_cast<size_t>(3 * v + a)] = s(a);
        }
      }
    });
    // Per tet: the output-index -> source-index map and the raster data.
    warp.maps_.assign(static_cast<size_t>(nt) * 12, 0.0);
    std::vector<RasterTet> raster(static_cast<size_t>(nt));
    std::vector<uint8_t> usable(static_cast<size_t>(nt), 0);
    parallel_for(0, nt, 4096, [&](int64_t begin, int64_t end) {
      for (int64_t t = begin; t < end; ++t) {
        Eigen::Vector3d u[4], s[4];
        for (int c = 0; c < 4; ++c) {
          const size_t v = static_cast<size_t>(rest.tets(t, c)) * 3;
          u[c] = Eigen::Vector3d(posed_index[v], posed_index[v + 1], posed_index[v + 2]);
          s[c] = Eigen::Vector3d(rest_index[v], rest_index[v + 1], rest_index[v + 2]);
        }
        Eigen::Matrix3d ue, se;
        for (int c = 0; c < 3; ++c) ue.col(c) = u[c + 1] - u[0], se.col(c) = s[c + 1] - s[0];
        const double det = ue.determinant();
        if (!(std::abs(det) > 1e-12) || !std::isfinite(det)) continue;
        const Eigen::Matrix3d inverse = ue.inverse();
        RasterTet& r = raster[static_cast<size_t>(t)];
        const Eigen::Vector3d origin = -(inverse * u[0]);
        r.origin[0] = 1.0 - origin.sum();
        r.di[0] = -inverse.col(0).sum();
        r.dj[0] = -inverse.col(1).sum();
        r.dk[0] = -inverse.col(2).sum();
        for (int m = 1; m < 4; ++m) {
          r.origin[m] = origin(m - 1);
          r.di[m] = inverse(m - 1, 0);
          r.dj[m] = inverse(m - 1, 1);
          r.dk[m] = inverse(m - 1, 2);
        }
        for (int m = 0; m < 4; ++m) r.inv_di[m] = r.di[m] != 0.0 ? 1.0 / r.di[m] : 0.0;
        for (int a = 0; a < 3; ++a) {
          r.lo[a] = std::min({u[0](a), u[1](a), u[2](a), u[3](a)});
          r.hi[a] = std::max({u[0](a), u[1](a), u[2](a), u[3](a)});
        }
        const Eigen::Matrix3d a = se * inverse;
        const Eigen::Vector3d b = s[0] - a * u[0];
        double* m = warp.maps_.data() + 12 * t;
        for (int row = 0; row < 3; ++row) {
          for (int c = 0; c < 3; ++c) m[3 * row + c] = a(row, c);
          m[9 + row] = b(row);
        }
        usable[static_cast<size_t>(t)] = 1;
      }
    });
    for (const uint8_t ok : usable) warp.stats_.degenerate_tets += ok ? 0 : 1;
    POSEWARP_RETURN_IF_ERROR(progress.check_cancel());
    progress.update(0.2);

    // Slabs along output k; each tet goes to every slab its index box meets (boundary tets with the shell margin).
    const Index3& n = output.size;
    const int64_t slab_count = std::clamp<int64_t>(n[2], 1, 16 * static_cast<int64_t>(thread_count()));
    const int64_t slab_depth = (n[2] + slab_count - 1) / slab_count;
    std::vector<std::vector<int32_t>> interior(static_cast<size_t>(slab_count)), shell(static_cast<size_t>(slab_count));
    const double margin[3] = {shell_mm / output.spacing[0], shell_mm / output.spacing[1], shell_mm / output.spacing[2]};
    auto add_to_slabs = [&](std::vector<std::vector<int32_t>>& lists, int32_t t, double pad) {
      const RasterTet& r = raster[static_cast<size_t>(t)];
      const int64_t k0 = std::max<int64_t>(0, static_cast<int64_t>(fast_ceil(r.lo[2] - pad)));
      const int64_t k1 = std::min<int64_t>(n[2] - 1, static_cast<int64_t>(fast_floor(r.hi[2] + pad)));
      if (k0 > k1) return;
      for (int64_t s = k0 / slab_depth; s <= k1 / slab_depth; ++s) lists[static_cast<size_t>(s)].push_back(t);
    };
    for (int64_t t = 0; t < nt; ++t) {
      if (usable[static_cast<size_t>(t)]) add_to_slabs(interior, static_cast<int32_t>(t), 0.0);
    }
    for (const int32_t t : topology.boundary_tets) {
      if (t < nt && usable[static_cast<size_t>(t)]) add_to_slabs(shell, t, margin[2]);
    }

    warp.owner_.assign(static_cast<size_t>(output.voxel_count()), -1);
    std::vector<uint8_t> conflict(static_cast<size_t>(output.voxel_count()), 0);
    const Eigen::VectorXi& tet_class = rest.tet_class;
    auto priority = [&tet_class](int32_t t) { return tet_class(t) >= kFirstBoneClass ? 1 : 0; };

    parallel_for(0, slab_count, 1, [&](int64_t s0, int64_t s1) {
      std::vector<float> best;
      for (int64_t s = s0; s < s1; ++s) {
        const int64_t kb = s * slab_depth, ke = std::min(n[2], kb + slab_depth);
        if (kb >= ke) continue;
        for (const int32_t t : interior[static_cast<size_t>(s)]) {
          const RasterTet& r = raster[static_cast<size_t>(t)];
          const int64_t k0 = std::max(kb, static_cast<int64_t>(fast_ceil(r.lo[2])));
          const int64_t k1 = std::min(ke - 1, static_cast<int64_t>(fast_floor(r.hi[2])));
          const int64_t j0 = std::max<int64_t>(0, static_cast<int64_t>(fast_ceil(r.lo[1])));
          const int64_t j1 = std::min<int64_t>(n[1] - 1, static_cast<int64_t>(fast_floor(r.hi[1])));
          const int64_t i0 = std::max<int64_t>(0, static_cast<int64_t>(fast_ceil(r.lo[0])));
          const int64_t i1 = std::min<int64_t>(n[0] - 1, static_cast<int64_t>(fast_floor(r.hi[0])));
          for (int64_t k = k0; k <= k1; ++k) {
            for (int64_t j = j0; j <= j1; ++j) {
              int64_t first = i0, last = i1;
              if (!row_interval(r, j, k, first, last, kInsideTolerance)) continue;
              int64_t v = output.offset(first, j, k);
              for (int64_t i = first; i <= last; ++i, ++v) {
                int32_t& owner = warp.owner_[static_cast<size_t>(v)];
                if (owner < 0) {
                  owner = t;
                  continue;
                }
                // Two posed tets cover this voxel: a fold when they map it to different rest places.
                double a[3], b[3];
                apply_map(warp.maps_.data() + 12 * owner, double(i), double(j), double(k), a);
                apply_map(warp.maps_.data() + 12 * t, double(i), double(j), double(k), b);
                if (std::abs(a[0] - b[0]) + std::abs(a[1] - b[1]) + std::abs(a[2] - b[2]) > 0.5) {
                  conflict[static_cast<size_t>(v)] = 1;
                }
                const int pt = priority(t), po = priority(owner);
                if (pt > po || (pt == po && t < owner)) owner = t;
              }
            }
          }
        }
        // Skin shell: uncovered voxels near a boundary tet take the nearest one's map.
        const int64_t slab_voxels = (ke - kb) * n[0] * n[1];
        best.assign(static_cast<size_t>(slab_voxels), std::numeric_limits<float>::infinity());
        std::vector<int32_t> best_tet(static_cast<size_t>(slab_voxels), -1);
        for (const int32_t t : shell[static_cast<size_t>(s)]) {
          const RasterTet& r = raster[static_cast<size_t>(t)];
          Eigen::Vector3d corners[4];
          for (int c = 0; c < 4; ++c) corners[c] = posed.row(rest.tets(t, c)).transpose();
          const std::array<double, 4> h = heights(corners);
          const int64_t k0 = std::max(kb, static_cast<int64_t>(fast_ceil(r.lo[2] - margin[2])));
          const int64_t k1 = std::min(ke - 1, static_cast<int64_t>(fast_floor(r.hi[2] + margin[2])));
          const int64_t j0 = std::max<int64_t>(0, static_cast<int64_t>(fast_ceil(r.lo[1] - margin[1])));
          const int64_t j1 = std::min<int64_t>(n[1] - 1, static_cast<int64_t>(fast_floor(r.hi[1] + margin[1])));
          const int64_t i0 = std::max<int64_t>(0, static_cast<int64_t>(fast_ceil(r.lo[0] - margin[0])));
          const int64_t i1 = std::min<int64_t>(n[0] - 1, static_cast<int64_t>(fast_floor(r.hi[0] + margin[0])));
          for (int64_t k = k0; k <= k1; ++k) {
            for (int64_t j = j0; j <= j1; ++j) {
              double base[4];
              for (int m = 0; m < 4; ++m) base[m] = r.origin[m] + double(j) * r.dj[m] + double(k) * r.dk[m];
              for (int64_t i = i0; i <= i1; ++i) {
                const int64_t v = output.offset(i, j, k);
                if (warp.owner_[static_cast<size_t>(v)] >= 0) continue;
                double d = 0.0;
                for (int m = 0; m < 4; ++m) {
                  const double lambda = base[m] + double(i) * r.di[m];
                  d = std::max(d, std::max(0.0, -lambda) * h[static_cast<size_t>(m)]);
                }
                if (d > shell_mm) continue;
                const size_t local = static_cast<size_t>(v - kb * n[0] * n[1]);
                if (d < best[local] || (d == best[local] && t < best_tet[local])) {
                  best[local] = static_cast<float>(d);
                  best_tet[local] = t;
                }
              }
            }
          }
        }
        for (int64_t local = 0; local < slab_voxels; ++local) {
          if (best_tet[static_cast<size_t>(local)] >= 0) {
            warp.owner_[static_cast<size_t>(kb * n[0] * n[1] + local)] = -2 - best_tet[static_cast<size_t>(local)];
          }
        }
        progress.advance(1, slab_count);
      }
    });
    POSEWARP_RETURN_IF_ERROR(progress.check_cancel());
    for (size_t v = 0; v < warp.owner_.size(); ++v) {
      const int32_t o = warp.owner_[v];
      if (o >= 0) {
        ++warp.stats_.covered_voxels;
      } else if (o <= -2) {
        ++warp.stats_.extrapolated_voxels;
      } else {
        ++warp.stats_.background_voxels;
      }
      warp.stats_.conflicted_voxels += conflict[v];
    }
  } catch (const std::bad_alloc&) {
    return resource_exhausted_error("out of memory preparing the warp onto " + output.describe());
  }
  progress.finish();
  return warp;
}

bool TetWarp::source_index(int64_t v, int64_t i, int64_t j, int64_t k, double s[3]) const {
  const int32_t o = owner_[static_cast<size_t>(v)];
  if (o >= 0) {
    apply_map(maps_.data() + 12 * o, double(i), double(j), double(k), s);
    return true;
  }
  if (o <= -2) {
    apply_map(maps_.data() + 12 * (-2 - o), double(i), double(j), double(k), s);
    return true;
  }
  apply_map(background_map_, double(i), double(j), double(k), s);
  if (rest_coverage_ != nullptr) {
    const int64_t x = round_index(s[0]), y = round_index(s[1]), z = round_index(s[2]);
    if (x >= 0 && y >= 0 && z >= 0 && x < source_.size[0] && y < source_.size[1] && z < source_.size[2] &&
        (*rest_coverage_)[static_cast<size_t>(source_.offset(x, y, z))]) {
      return false;  // that source voxel belongs to the body, which the mesh moved elsewhere
    }
  }
  return true;
}

template <typename Sample>
void TetWarp::for_each_mapped_voxel(const Sample& sample) const {
  const Index3& n = output_.size;
  parallel_for(0, n[2], 1, [&](int64_t k0, int64_t k1) {
    for (int64_t k = k0; k < k1; ++k) {
      for (int64_t j = 0; j < n[1]; ++j) {
        int64_t v = output_.offset(0, j, k);
        for (int64_t i = 0; i < n[0]; ++i, ++v) {
          double s[3];
          if (source_index(v, i, j, k, s)) sample(v, s);
        }
      }
    }
  });
}

Result<LabelVolume> TetWarp::warp_labels(const LabelVolume& labels) const {
  if (!labels.geometry().same_grid(source_, 1e-3)) {
    return invalid_argument_error("the label volume is not on the grid the rig was built from");
  }
  LabelVolume out;
  try {
    out = LabelVolume(output_, label_background_);
  } catch (const std::bad_alloc&) {
    return resource_exhausted_error("out of memory for the output labels (" + output_.describe() + ")");
  }
  out.set_source_type(labels.source_type());
  const Index3& m = source_.size;
  for_each_mapped_voxel([&](int64_t v, const double s[3]) {
    const int64_t x = round_index(s[0]), y = round_index(s[1]), z = round_index(s[2]);
    if (x < 0 || y < 0 || z < 0 || x >= m[0] || y >= m[1] || z >= m[2]) return;
    out.data()[v] = labels.data()[source_.offset(x, y, z)];
  });
  return out;
}

Result<IntensityVolume> TetWarp::warp_intensities(const IntensityVolume& source, Interpolation interpolation) const {
  if (!source.geometry().same_grid(source_, 1e-3)) {
    return invalid_argument_error("the intensity volume is not on the grid the rig was built from");
  }
  IntensityVolume out;
  try {
    out = IntensityVolume(output_, intensity_background_);
  } catch (const std::bad_alloc&) {
    return resource_exhausted_error("out of memory for the output intensities (" + output_.describe() + ")");
  }
  out.set_source_type(source.source_type());
  const Index3& m = source_.size;
  const float* in = source.data();
  const int64_t sx = 1, sy = m[0], sz = m[0] * m[1];
  for_each_mapped_voxel([&](int64_t v, const double s[3]) {
    if (s[0] < -0.5 || s[1] < -0.5 || s[2] < -0.5 || s[0] > m[0] - 0.5 || s[1] > m[1] - 0.5 || s[2] > m[2] - 0.5) {
      return;
    }
    if (interpolation == Interpolation::kNearest) {
      out.data()[v] = in[source_.offset(round_index(s[0]), round_index(s[1]), round_index(s[2]))];
      return;
    }
    int64_t base[3];
    double f[3];
    for (int a = 0; a < 3; ++a) {
      const double c = std::clamp(s[a], 0.0, static_cast<double>(m[a] - 1));
      base[a] = std::min<int64_t>(static_cast<int64_t>(c), std::max<int64_t>(0, m[a] - 2));  // c >= 0
      f[a] = m[a] > 1 ? c - static_cast<double>(base[a]) : 0.0;
    }
    const int64_t dx = m[0] > 1 ? sx : 0, dy = m[1] > 1 ? sy : 0, dz = m[2] > 1 ? sz : 0;
    const float* p = in + base[0] * sx + base[1] * sy + base[2] * sz;
    const double c00 = p[0] + f[0] * (p[dx] - p[0]);
    const double c10 = p[dy] + f[0] * (p[dy + dx] - p[dy]);
    const double c01 = p[dz] + f[0] * (p[dz + dx] - p[dz]);
    const double c11 = p[dz + dy] + f[0] * (p[dz + dy + dx] - p[dz + dy]);
    const double c0 = c00 + f[1] * (c10 - c00);
    const double c1 = c01 + f[1] * (c11 - c01);
    out.data()[v] = static_cast<float>(c0 + f[2] * (c1 - c0));
  });
  return out;
}

std::vector<uint8_t> TetWarp::coverage() const {
  std::vector<uint8_t> covered(owner_.size());
  for (size_t v = 0; v < owner_.size(); ++v) covered[v] = owner_[v] != -1 ? 1 : 0;
  return covered;
}

std::vector<float> TetWarp::inverse_displacement() const {
  const Index3& n = output_.size;
  std::vector<float> field(static_cast<size_t>(output_.voxel_count()) * 3, 0.0f);
  parallel_for(0, n[2], 1, [&](int64_t k0, int64_t k1) {
    for (int64_t k = k0; k < k1; ++k) {
      for (int64_t j = 0; j < n[1]; ++j) {
        for (int64_t i = 0; i < n[0]; ++i) {
          const int64_t v = output_.offset(i, j, k);
          double s[3];
          const int32_t o = owner_[static_cast<size_t>(v)];
          apply_map(o >= 0 ? maps_.data() + 12 * o : o <= -2 ? maps_.data() + 12 * (-2 - o) : background_map_, double(i),
                    double(j), double(k), s);
          const Vec3 from = output_.index_to_physical({double(i), double(j), double(k)});
          const Vec3 to = source_.index_to_physical({s[0], s[1], s[2]});
          for (int a = 0; a < 3; ++a) field[static_cast<size_t>(3 * v + a)] = static_cast<float>(to[a] - from[a]);
        }
      }
    }
  });
  return field;
}

}  // namespace posewarp::resample
