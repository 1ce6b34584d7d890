// Skeleton: rigid bone segments and the joints between them, found automatically from a label volume
// (Sujar et al. 2018 section 3.1, made automatic: contact graph, maximum spanning tree, joint centres).
#pragma once

#include <Eigen/Core>

#include <optional>
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
  int parent_joint = -1;               // index of the joint whose child this segment is; -1 for the root
};

struct Joint {
  std::string name;
  int parent = -1;                     // segment nearer the root
  int child = -1;
  Eigen::Vector3d centre_mm = Eigen::Vector3d::Zero();   // LPS mm
  Eigen::Matrix3d frame = Eigen::Matrix3d::Identity();   // columns x, y, z: the joint's rest axes in LPS
  std::string method;                  // "contact-centroid", "sphere-fit", "rig-spec", "proximity"
  double contact_area_mm2 = 0.0;
  double sphere_radius_mm = 0.0;       // when method is "sphere-fit"
  double sphere_rms_mm = 0.0;
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

struct SkeletonParams {
  // Voxels of two segments closer than this (centre to centre) are in contact; 0 = 3.5 x the largest spacing.
  double contact_distance_mm = 0.0;
  // Sphere fit accepted when rms / radius is below this and the radius below 1.5 x the contact extent.
  double sphere_max_relative_rms = 0.15;
  int sphere_min_points = 20;
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
