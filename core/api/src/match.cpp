// The facade's posture match: segments' labels found in the target by name, then pose::match_posture.
#include "posewarp/api/match.h"

#include <nlohmann/json.hpp>

#include <Eigen/Geometry>

#include <cmath>
#include <map>

#include "posewarp/common/stopwatch.h"
#include "posewarp/pose/match.h"

namespace posewarp::api {
namespace {

// (+ 0.0: what rounds to nothing is written 0, not -0.)
double to_hundredth(double v) {
  return std::round(v * 100.0) / 100.0 + 0.0;
}

// A pose's joint angles to a hundredth of a degree: what a fit cannot tell apart is written alike.
void round_angles(Pose& pose) {
  for (JointRotation& j : pose.joints) {
    if (j.angles_deg) *j.angles_deg = j.angles_deg->unaryExpr(&to_hundredth);
  }
}

}  // namespace

Result<PostureMatch> match_posture(const Rig& rig, const LabelVolume& target, const LabelMap& target_map,
                                   const MatchOptions& options) {
  const Stopwatch clock;
  PostureMatch out;
  std::map<std::string, Label> target_value;
  for (const LabelEntry& e : target_map.entries()) target_value[e.name] = e.value;
  std::vector<std::vector<Label>> target_labels;
  for (const Segment& segment : rig.skeleton.segments) {
    std::vector<Label> values;
    for (Label label : segment.labels) {
      const LabelEntry* entry = rig.label_map.find(label);
      const auto found = entry == nullptr ? target_value.end() : target_value.find(entry->name);
      if (found == target_value.end()) {
        out.unnamed_labels.push_back(entry == nullptr ? "label " + std::to_string(label) : entry->name);
        continue;
      }
      values.push_back(found->second);
    }
    target_labels.push_back(std::move(values));
  }
  POSEWARP_ASSIGN_OR_RETURN(out.match, pose::match_posture(rig.skeleton, rig.labels, target, target_labels, options));
  out.match.pose.name = "matched";
  // Angles to a hundredth of a degree, the root's motion dropped below that (and below a hundredth of a mm): what
  // the fit cannot tell from rest is written as rest.
  round_angles(out.match.pose);
  for (SegmentMatch& s : out.match.segments) s.angles_deg = s.angles_deg.unaryExpr(&to_hundredth);
  RigidTransform& root = out.match.pose.root;
  if (Eigen::AngleAxisd(root.rotation).angle() < 1e-4 && root.translation.norm() < 1e-2) {
    root = RigidTransform::identity();
  } else {
    root.translation = root.translation.unaryExpr(&to_hundredth);
  }
  out.seconds = clock.seconds();
  return out;
}

Result<Pose> standard_posture(const Rig& rig, const std::string& name) {
  POSEWARP_ASSIGN_OR_RETURN(Pose p, pose::standard_posture(rig.skeleton, name));
  round_angles(p);
  return p;
}

std::string posture_match_to_json(const PostureMatch& m) {
  using Json = nlohmann::ordered_json;
  Json segments = Json::array();
  for (const SegmentMatch& s : m.match.segments) {
    Json row{{"segment", s.segment}, {"joint", s.joint}, {"volume_ml", s.volume_ml}, {"matched", s.matched}};
    if (s.matched) {
      if (!s.joint.empty()) {
        row["angles_deg"] = {
            {"flexion", s.angles_deg.x()}, {"abduction", s.angles_deg.y()}, {"rotation", s.angles_deg.z()}};
      }
      row["mean_distance_mm"] = s.mean_distance_mm;
      row["max_distance_mm"] = s.max_distance_mm;
      row["dice"] = s.dice;
      row["iterations"] = s.iterations;
      if (!s.beyond_range.empty()) row["beyond_range"] = s.beyond_range;
      if (!s.held_at_range.empty()) row["held_at_range"] = s.held_at_range;
    } else {
      row["skipped"] = s.skipped;
    }
    segments.push_back(row);
  }
  const RigidTransform& root = m.match.pose.root;
  const Eigen::AngleAxisd turn(root.rotation);
  const Json doc{{"format", "posewarp.match"},
                 {"version", 1},
                 {"root",
                  {{"rotation_deg", turn.angle() * 180.0 / M_PI},
                   {"rotation_axis", {turn.axis().x(), turn.axis().y(), turn.axis().z()}},
                   {"translation_mm", {root.translation.x(), root.translation.y(), root.translation.z()}}}},
                 {"segments", segments},
                 {"unnamed_labels", m.unnamed_labels},
                 {"seconds", m.seconds}};
  return doc.dump(2) + "\n";
}

}  // namespace posewarp::api
