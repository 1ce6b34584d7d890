// Skeleton: rigid bone segments and the joints between them, found automatically from a label volume
// (Sujar et al. 2018 section 3.1, made automatic: contact graph, maximum spanning tree, joint centres).
#pragma once

#include <Eigen/Core>

#include <optional>
#include <string_view>
#include <string>
#include <vector>

#include "posewarp/common/progress.h"
#include "posewarp/common/result.h"
#include "posewarp/common/volume.h"
#include "posewarp/labels/label_map.h"

namespace posewarp::rig {

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
  labels::JointKind kind = labels::JointKind::kUnspecified;
  labels::FlexionDirection flexion = labels::FlexionDirection::kAnterior;
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

Result<RigSpec> rig_spec_from_json(const std::string& text, const std::string& source);
Result<RigSpec> read_rig_spec(const std::string& path);

// The largest contact distance accepted (SkeletonParams, rig spec): far above any joint space, small enough to keep
// the contact search bounded (it visits a ball of this radius around every surface voxel).
inline constexpr double kMaxContactDistanceMm = 50.0;

struct SkeletonParams {
  // Voxels of two segments closer than this (centre to centre) are in contact; 0 = 3.5 x the largest spacing.
  double contact_distance_mm = 0.0;
  // Sphere and cylinder fits are accepted when rms / radius is below this (after trimming outliers such as the
  // femoral neck or the shaft).
  double sphere_max_relative_rms = 0.15;
  int sphere_min_points = 20;
  // A joint centre further than this from the voxels where its two bones meet (and inside neither) is refused:
  // the contact centroid is used and a note says so. 0 = max(10 mm, 2 x the largest spacing).
  double max_centre_offset_mm = 0.0;
};

Status validate(const SkeletonParams& params);

// Builds the skeleton of the bone segments present in `labels`. FAILED_PRECONDITION when fewer than two bone
// segments are present; INVALID_ARGUMENT when the spec names segments or labels the volume does not hold.
Result<Skeleton> build_skeleton(const LabelVolume& labels, const labels::LabelMap& map, const RigSpec& spec,
                                const SkeletonParams& params, const ProgressHooks& hooks);

// Mesher classes for a skeleton: 0 outside `body`, 1 soft tissue, 2 + k for voxels of segment k. Where two
// segments touch (26-neighbourhood), the touching voxels of both become soft tissue, so no mesh vertex is shared by two
// bones (a shared vertex could not follow both).
LabelVolume skeleton_classes(const Skeleton& skeleton, const LabelVolume& labels, const LabelVolume& body);

}  // namespace posewarp::rig
