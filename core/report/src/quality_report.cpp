// Quality report pieces: mesh volume change and inversions, bone rigidity, label counts, JSON.
#include "posewarp/report/quality_report.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <iomanip>
#include <mutex>
#include <sstream>
#include <string>
#include <tuple>

#include "posewarp/common/parallel.h"

namespace posewarp::report {

namespace {

// body(begin, end, partial) over fixed blocks of `n` tets in parallel, each block's figures in its own partial: the
// blocks are the same whatever the thread count, so that figures added up in block order are the same on any machine.
template <typename Partial, typename Body>
std::vector<Partial> per_block(int64_t n, const Partial& zero, const Body& body) {
  constexpr int64_t kBlock = 16384;
  std::vector<Partial> partial(static_cast<size_t>((n + kBlock - 1) / kBlock), zero);
  parallel_for(0, static_cast<int64_t>(partial.size()), 1, [&](int64_t b0, int64_t b1) {
    for (int64_t b = b0; b < b1; ++b) body(b * kBlock, std::min(n, (b + 1) * kBlock), partial[static_cast<size_t>(b)]);
  });
  return partial;
}

}  // namespace

MeshChange mesh_change(const TetMesh& rest, const Eigen::VectorXd& det, const Eigen::VectorXd& rest_volume) {
  MeshChange change;
  double soft_rest = 0.0, soft_posed = 0.0, body_rest = 0.0, body_posed = 0.0, soft_local = 0.0;
  change.det_min = std::numeric_limits<double>::infinity();
  change.det_max = -std::numeric_limits<double>::infinity();
  for (int64_t t = 0; t < rest.tet_count(); ++t) {
    const double d = det(t);
    change.det_min = std::min(change.det_min, d);
    change.det_max = std::max(change.det_max, d);
    if (d <= 0.0) ++change.inverted_tets;
    const double v0 = rest_volume(t), v1 = rest_volume(t) * d;
    body_rest += v0;
    body_posed += v1;
    if (rest.tet_class(t) == kSoftTissueClass) soft_rest += v0, soft_posed += v1, soft_local += v0 * std::abs(d - 1.0);
  }
  if (rest.tet_count() == 0) change.det_min = change.det_max = 1.0;
  change.soft_tissue_volume_change = soft_rest > 0.0 ? soft_posed / soft_rest - 1.0 : 0.0;
  change.body_volume_change = body_rest > 0.0 ? body_posed / body_rest - 1.0 : 0.0;
  change.soft_tissue_local_volume_error = soft_rest > 0.0 ? soft_local / soft_rest : 0.0;
  return change;
}

std::vector<SegmentRigidity> bone_rigidity(const TetMesh& rest, const Eigen::MatrixXd& posed,
                                           const std::vector<Eigen::Matrix3d>& rotation,
                                           const std::vector<Eigen::Vector3d>& translation,
                                           const std::vector<std::string>& segment_names) {
  std::vector<SegmentRigidity> result(static_cast<size_t>(rest.segment_count));
  for (int k = 0; k < rest.segment_count; ++k) {
    result[static_cast<size_t>(k)].segment =
        k < static_cast<int>(segment_names.size()) ? segment_names[static_cast<size_t>(k)] : std::to_string(k);
  }
  const auto segments = static_cast<size_t>(rest.segment_count);
  const std::vector<std::vector<double>> worst = per_block(
      rest.tet_count(), std::vector<double>(segments, 0.0), [&](int64_t t0, int64_t t1, std::vector<double>& most) {
        for (int64_t t = t0; t < t1; ++t) {
          const int k = rest.tet_class(t) - kFirstBoneClass;
          if (k < 0 || k >= rest.segment_count || static_cast<size_t>(k) >= rotation.size()) continue;
          for (int c = 0; c < 4; ++c) {
            const int32_t v = rest.tets(t, c);
            const Eigen::Vector3d expected = rotation[static_cast<size_t>(k)] * rest.vertices.row(v).transpose() +
                                             translation[static_cast<size_t>(k)];
            most[static_cast<size_t>(k)] =
                std::max(most[static_cast<size_t>(k)], (posed.row(v).transpose() - expected).norm());
          }
        }
      });
  for (const std::vector<double>& most : worst) {
    for (size_t k = 0; k < segments; ++k) result[k].max_error_mm = std::max(result[k].max_error_mm, most[k]);
  }
  return result;
}

std::map<Label, int64_t> label_counts(const LabelVolume& labels, std::optional<std::pair<Label, Label>> expected) {
  std::map<Label, int64_t> counts;
  const int64_t n = labels.voxel_count();
  if (n == 0) return counts;
  const Label* v = labels.data();
  std::mutex merge;
  Label lo = v[0], hi = v[0];
  if (expected && expected->first <= expected->second) {
    std::tie(lo, hi) = *expected;
  } else {
    parallel_for(0, n, int64_t{1} << 20, [&](int64_t begin, int64_t end) {
      const auto [a, b] = std::minmax_element(v + begin, v + end);
      const std::lock_guard<std::mutex> lock(merge);
      lo = std::min(lo, *a);
      hi = std::max(hi, *b);
    });
  }
  const int64_t range = static_cast<int64_t>(hi) - static_cast<int64_t>(lo) + 1;
  if (range > (int64_t{1} << 16)) {  // sparse values: a map
    for (int64_t i = 0; i < n; ++i) ++counts[v[i]];
    return counts;
  }
  const Label first = lo;
  std::vector<int64_t> total(static_cast<size_t>(range), 0);
  int64_t outside = 0;  // values off the expected range
  parallel_for(0, n, int64_t{1} << 18, [&](int64_t begin, int64_t end) {
    std::vector<int64_t> local(static_cast<size_t>(range), 0);
    int64_t off = 0;
    auto add = [&](Label value, int64_t count) {
      const auto bin = static_cast<uint64_t>(static_cast<int64_t>(value) - first);
      if (bin < static_cast<uint64_t>(range)) {
        local[bin] += count;
      } else {
        off += count;
      }
    };
    // Labels come in long runs: counted a run at a time, since a count per voxel waits on the store of the one before
    // it (the body's moved root: report-labels 8.0-8.2 -> 4.5-4.7 ms).
    int64_t run = begin;
    Label value = v[begin];
    for (int64_t i = begin + 1; i < end; ++i) {
      if (v[i] == value) continue;
      add(value, i - run);
      run = i;
      value = v[i];
    }
    add(value, end - run);
    const std::lock_guard<std::mutex> lock(merge);
    for (size_t b = 0; b < local.size(); ++b) total[b] += local[b];
    outside += off;
  });
  if (outside > 0) return label_counts(labels);
  for (size_t b = 0; b < total.size(); ++b) {
    if (total[b] > 0) counts[static_cast<Label>(first + static_cast<int64_t>(b))] = total[b];
  }
  return counts;
}

LabelChange label_change(const std::map<Label, int64_t>& before, const std::map<Label, int64_t>& after) {
  LabelChange change;
  for (const auto& [label, count] : before) change.voxels[label].first = count;
  for (const auto& [label, count] : after) change.voxels[label].second = count;
  for (const auto& [label, counts] : change.voxels) {
    if (counts.first > 0 && counts.second == 0) change.vanished.push_back(label);
    if (counts.first == 0 && counts.second > 0) change.appeared.push_back(label);
  }
  return change;
}

std::vector<JointRegionChange> joint_region_changes(const TetMesh& rest, const Eigen::VectorXd& det,
                                                   const Eigen::VectorXd& rest_volume,
                                                   const std::vector<std::pair<std::string, Eigen::Vector3d>>& joints,
                                                   const std::vector<double>& radii_mm) {
  // One pass over the soft tets: per joint and radius, the rest and posed volume, folded and stretched.
  const size_t regions = joints.size() * radii_mm.size();
  using Sums = std::vector<std::array<double, 4>>;
  const std::vector<Sums> partial =
      per_block(rest.tet_count(), Sums(regions, {0.0, 0.0, 0.0, 0.0}), [&](int64_t t0, int64_t t1, Sums& sums) {
        for (int64_t t = t0; t < t1; ++t) {
          if (rest.tet_class(t) != kSoftTissueClass) continue;
          Eigen::Vector3d c = Eigen::Vector3d::Zero();
          for (int q = 0; q < 4; ++q) c += rest.vertices.row(rest.tets(t, q)).transpose();
          const double v = rest_volume(t), d = det(t);
          for (size_t j = 0; j < joints.size(); ++j) {
            const double distance2 = (0.25 * c - joints[j].second).squaredNorm();
            for (size_t r = 0; r < radii_mm.size(); ++r) {
              if (distance2 > radii_mm[r] * radii_mm[r]) continue;
              std::array<double, 4>& sum = sums[j * radii_mm.size() + r];
              sum[0] += v;
              sum[1] += v * d;
              if (d <= 0.0) {
                sum[2] += v;
              } else if (d > 2.0 || d < 0.5) {
                sum[3] += v;
              }
            }
          }
        }
      });
  std::vector<JointRegionChange> changes;
  for (size_t j = 0; j < joints.size(); ++j) {
    for (size_t r = 0; r < radii_mm.size(); ++r) {
      double rest_sum = 0.0, posed_sum = 0.0, folded = 0.0, stretched = 0.0;
      for (const Sums& sums : partial) {
        const std::array<double, 4>& sum = sums[j * radii_mm.size() + r];
        rest_sum += sum[0];
        posed_sum += sum[1];
        folded += sum[2];
        stretched += sum[3];
      }
      JointRegionChange change;
      change.joint = joints[j].first;
      change.radius_mm = radii_mm[r];
      change.rest_volume_ml = rest_sum / 1000.0;
      if (rest_sum > 0.0) {
        change.volume_change = posed_sum / rest_sum - 1.0;
        change.folded_fraction = folded / rest_sum;
        change.stretched_fraction = stretched / rest_sum;
      }
      changes.push_back(change);
    }
  }
  return changes;
}

void add_warnings(QualityReport& r, double voxel_mm, const WarningThresholds& limits) {
  auto percent = [](double x) {
    char text[32];
    std::snprintf(text, sizeof text, "%+.1f%%", 100.0 * x);
    return std::string(text);
  };
  auto mm = [](double x) {
    char text[32];
    std::snprintf(text, sizeof text, "%.1f mm", x);
    return std::string(text);
  };
  for (const SegmentVoxelRigidity& s : r.voxel_rigidity) {
    if (s.max_mm > limits.bone_deviation_voxels * voxel_mm) {
      r.warnings.push_back("bone '" + s.segment + "' is not rigid at voxel level: voxels up to " + mm(s.max_mm) +
                           " off its rigid motion (99th percentile " + mm(s.p99_mm) + ")");
    }
  }
  for (const BoneOverlap& o : r.bone_overlaps) {
    if (o.volume_ml > limits.bone_overlap_ml) {
      char ml[32];
      std::snprintf(ml, sizeof ml, "%.1f ml", o.volume_ml);
      r.warnings.push_back("bones '" + o.segment_a + "' and '" + o.segment_b + "' pass through each other: " + ml +
                           " overlap (a centre of rotation off the joint, or a pose past the joint's range)");
    }
  }
  for (const JointRegionChange& c : r.joint_regions) {
    const std::string where = "soft tissue within " + std::to_string(static_cast<int>(c.radius_mm)) + " mm of '" + c.joint + "'";
    if (std::abs(c.volume_change) > limits.local_volume_change) {
      r.warnings.push_back(where + " changed volume by " + percent(c.volume_change));
    }
    if (c.folded_fraction > limits.folded_fraction) {
      r.warnings.push_back(where + ": " + percent(c.folded_fraction).substr(1) + " of it is folded (det <= 0)");
    }
    const int64_t inside = c.skin_inside_tissue + c.skin_inside_bone;
    if (c.skin_vertices > 0 && static_cast<double>(inside) > limits.skin_inside_fraction * static_cast<double>(c.skin_vertices)) {
      r.warnings.push_back(where + ": " + std::to_string(inside) + " of its " + std::to_string(c.skin_vertices) +
                           " skin vertices passed into the tissue or bone facing them (a crease without contact)");
    }
    if (c.stretched_fraction > limits.stretched_fraction) {
      r.warnings.push_back(where + ": " + percent(c.stretched_fraction).substr(1) +
                           " of it is strongly stretched or squashed (det > 2 or < 0.5)");
    }
  }
  for (const JointPastRange& p : r.past_range) {
    std::ostringstream text;
    text << std::fixed << std::setprecision(0) << "'" << p.joint << "' " << p.motion << " " << p.angle_deg
         << " degrees is past its range measured at rig build (" << (0.0 - p.negative_deg) << " to " << p.positive_deg
         << " degrees, where its bones meet): expect bone overlap and crushed tissue there";
    r.warnings.push_back(text.str());
  }
  if (!r.labels.appeared.empty()) r.warnings.push_back("labels appeared that the input does not hold");
  if (!r.labels.vanished.empty()) r.warnings.push_back("labels vanished in this pose");
}

std::string to_json(const QualityReport& r) {
  using json = nlohmann::json;
  json doc;
  doc["format"] = "posewarp.quality_report";
  doc["version"] = 1;
  doc["pose"] = r.pose_name;
  doc["method"] = r.method;
  doc["tets"] = {{"inverted", r.mesh.inverted_tets},
                 {"degenerate_after_posing", r.degenerate_tets},
                 {"rasterized", r.rasterized_tets},
                 {"det_min", r.mesh.det_min},
                 {"det_max", r.mesh.det_max}};
  doc["volume_change"] = {{"soft_tissue", r.mesh.soft_tissue_volume_change},
                          {"body", r.mesh.body_volume_change},
                          {"soft_tissue_local_error", r.mesh.soft_tissue_local_volume_error}};
  json rigidity = json::array();
  for (const SegmentRigidity& s : r.rigidity) rigidity.push_back({{"segment", s.segment}, {"max_error_mm", s.max_error_mm}});
  doc["bone_rigidity"] = {{"max_error_mm", r.bone_rigidity_error_mm},
                          {"max_error_voxels", r.bone_rigidity_error_voxels},
                          {"segments", rigidity},
                          {"measured_on", "bone tet vertices"}};
  json voxel_rigidity = json::array();
  for (const SegmentVoxelRigidity& s : r.voxel_rigidity) {
    voxel_rigidity.push_back({{"segment", s.segment}, {"max_mm", s.max_mm}, {"p99_mm", s.p99_mm}});
  }
  doc["bone_voxel_rigidity"] = {{"max_mm", r.bone_voxel_deviation_mm},
                                {"segments", voxel_rigidity},
                                {"measured_on", "output voxels holding a bone's value: distance of their source from the "
                                                "bone's rigid inverse"}};
  json overlaps = json::array();
  for (const BoneOverlap& o : r.bone_overlaps) {
    overlaps.push_back({{"segments", {o.segment_a, o.segment_b}}, {"voxels", o.voxels}, {"volume_ml", o.volume_ml}});
  }
  doc["bone_overlaps"] = overlaps;
  json regions = json::array();
  for (const JointRegionChange& c : r.joint_regions) {
    regions.push_back({{"joint", c.joint},
                       {"radius_mm", c.radius_mm},
                       {"rest_soft_tissue_ml", c.rest_volume_ml},
                       {"volume_change", c.volume_change},
                       {"folded_fraction", c.folded_fraction},
                       {"stretched_fraction", c.stretched_fraction},
                       {"skin_vertices", c.skin_vertices},
                       {"skin_inside_tissue", c.skin_inside_tissue},
                       {"skin_inside_bone", c.skin_inside_bone}});
  }
  doc["moved_joints"] = regions;
  json past = json::array();
  for (const JointPastRange& p : r.past_range) {
    past.push_back({{"joint", p.joint}, {"motion", p.motion}, {"angle_deg", p.angle_deg},
                    {"range_deg", {0.0 - p.negative_deg, p.positive_deg}}});
  }
  doc["joints_past_range"] = past;
  doc["warnings"] = r.warnings;
  doc["voxels"] = {{"covered", r.covered_voxels},
                   {"conflicted", r.conflicted_voxels},
                   {"extrapolated", r.extrapolated_voxels},
                   {"background", r.background_voxels},
                   {"bone", r.bone_voxels},
                   {"kept_from_crossing_skin_contacts", r.skin_contact_voxels}};
  json labels = json::array();
  for (const auto& [label, counts] : r.labels.voxels) {
    json entry{{"value", label}, {"before", counts.first}, {"after", counts.second}};
    auto name = r.label_names.find(label);
    if (name != r.label_names.end()) entry["name"] = name->second;
    if (counts.first > 0) entry["change"] = static_cast<double>(counts.second) / static_cast<double>(counts.first) - 1.0;
    labels.push_back(entry);
  }
  doc["labels"] = labels;
  doc["vanished_labels"] = r.labels.vanished;
  doc["new_labels"] = r.labels.appeared;
  json stages = json::object();
  for (const auto& [stage, seconds] : r.stage_seconds) stages[stage] = seconds;
  doc["stage_seconds"] = stages;
  return doc.dump(2) + "\n";
}

}  // namespace posewarp::report
