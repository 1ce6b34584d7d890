// Skeleton: rigid bone segments and the joints between them (what rig/ finds from a label volume and every later
// stage reads), and a user's corrections to it (RigSpec, read by rig/).
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "posewarp/common/label_map.h"
#include "posewarp/common/volume.h"

namespace posewarp {

struct Segment {
  std::string name;
  std::vector<Label> labels;           // label values that make up this rigid segment
  int64_t voxels = 0;
  Eigen::Vector3d centroid_mm = Eigen::Vector3d::Zero();      // LPS mm
  Eigen::Vector3d principal_axis = Eigen::Vector3d::UnitZ();  // unit, largest spread of its voxels
  double elongation = 1.0;             // sqrt of the largest over the middle spread: > 1.5 for a long bone
  int parent_joint = -1;               // index of the joint whose child this segment is; -1 for the root
};

// Which side of the body a joint is on (from its names, else from where its child lies against the root).
enum class BodySide { kMidline, kLeft, kRight };
std::string_view body_side_name(BodySide side);

// How far a joint turns one way and the other about one of its axes before the bones beyond it meet a bone that
// does not move with them (api::joint_ranges).
struct MotionRange {
  std::string motion;         // "flexion" or "abduction"
  double negative_deg = 0.0;  // the largest angle each way before the bones meet (at most the range's max_deg)
  double positive_deg = 0.0;
  bool negative_stopped = false;  // the bones met within max_deg that way
  bool positive_stopped = false;
};

struct Joint {
  std::string name;
  int parent = -1;                     // segment nearer the root
  int child = -1;
  Eigen::Vector3d centre_mm = Eigen::Vector3d::Zero();   // LPS mm
  // The anatomical frame, a rotation (columns x, y, z in LPS), after the ISB joint coordinate systems (Grood and
  // Suntay 1983; Wu et al. 2002, 2005): x is the flexion axis, mediolateral (the hinge axis where one was fitted):
  // a positive turn about x is flexion (the way `flexion` says the child's far end goes); y is the ab/adduction
  // axis: a positive turn about y moves the child's far end away from the midline (abduction), or, for a midline
  // joint, bends it toward the patient's left; z = x cross y lies along the child's long axis, and a positive turn
  // about (internal_rotation_sign * z) is internal rotation (the child's front turns toward the midline; for a
  // midline joint, toward the patient's left). Angles compose as x, then y, then z (flexion first).
  Eigen::Matrix3d frame = Eigen::Matrix3d::Identity();
  int internal_rotation_sign = 1;      // +1 or -1
  JointKind kind = JointKind::kUnspecified;
  FlexionDirection flexion = FlexionDirection::kAnterior;
  BodySide side = BodySide::kMidline;
  Eigen::Vector3d hinge_axis = Eigen::Vector3d::Zero();  // unit, LPS, toward the patient's left; zero unless fitted
  std::string method;                  // "contact-centroid", "sphere-fit", "cylinder-fit", "rig-spec", "proximity"
  double contact_area_mm2 = 0.0;
  double sphere_radius_mm = 0.0;       // radius of the fitted sphere or cylinder
  double sphere_rms_mm = 0.0;          // rms distance of the fit's inlier points from it
  bool declared = false;               // the label map or the rig spec declared this joint
  // Its range of motion on this study, measured at rig build: flexion, and abduction for balls and planes. Empty in
  // rigs built before it was measured (`rig info` then measures it).
  std::vector<MotionRange> ranges;
};

struct Skeleton {
  std::vector<Segment> segments;       // segment k is mesher class 2 + k
  std::vector<Joint> joints;           // ordered parents before children
  int root = 0;
  std::vector<std::string> missing_segments;  // bone segments of the label map absent from the volume
  std::vector<std::string> notes;             // what the builder decided that a user should know

  int segment_index(const std::string& name) const;  // -1 when absent
  int joint_index(const std::string& name) const;    // -1 when absent
};

// A user's corrections (JSON): group labels into segments, choose the root, add, move, re-parent or remove joints.
// {"segments": {"pelvis": [25, 26, 77, 78]}, "root": "pelvis", "contact_distance_mm": 9,
//  "joints": [{"child": "femur_left", "parent": "pelvis", "name": "hip_left", "centre_mm": [x, y, z]}],
//  "remove_joints": [["hip_left", "hip_right"]]}
struct JointSpec {
  std::string child;
  std::string parent;                  // empty: keep the automatic parent (only rename or move)
  std::string name;                    // empty: keep the automatic name
  std::optional<Eigen::Vector3d> centre_mm;
};

struct RigSpec {
  std::vector<std::pair<std::string, std::vector<Label>>> segments;
  std::string root;
  std::optional<double> contact_distance_mm;
  std::vector<JointSpec> joints;
  std::vector<std::pair<std::string, std::string>> remove_joints;
};

}  // namespace posewarp
