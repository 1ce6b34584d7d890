// A pose as data: one rotation per joint, each in the joint's own frame, plus a root transform. Vocabulary shared by
// the pose stage (which reads, validates and applies it: posewarp/pose/pose.h) and the api's requests.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <optional>
#include <string>
#include <vector>

#include "posewarp/common/rigid_transform.h"

namespace posewarp {

// The rotation of a joint's child segment relative to its parent, expressed in the joint's rest frame F
// (rig::Joint::frame, columns x, y, z in LPS: x the flexion axis, y the abduction axis, z along the child's long
// axis). In LPS the child turns by F * R * F^T about the joint centre. Must be a unit quaternion (within 1e-3).
struct JointRotation {
  std::string joint;
  Eigen::Quaterniond rotation = Eigen::Quaterniond::Identity();
  // Anatomical angles in degrees (flexion, abduction, internal rotation), when the pose gave them: they are turned
  // into a rotation with the joint's own signs (rig::joint_rotation_from_angles) and `rotation` is not used.
  std::optional<Eigen::Vector3d> angles_deg;
};

struct Pose {
  std::string name;
  std::vector<JointRotation> joints;  // joints not listed stay at rest
  // Not the root segment's transform itself: `root.rotation` R turns the body about the root segment's centroid c
  // (rig::Segment::centroid_mm), then `root.translation` t (LPS mm) moves it: T_root(p) = R (p - c) + c + t.
  // A pose is written without knowing the rig, so c is only applied by forward_kinematics.
  RigidTransform root;
};

}  // namespace posewarp
