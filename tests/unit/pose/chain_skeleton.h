// Hand-built skeletons with known geometry for the pose tests.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <string>
#include <vector>

#include "posewarp/rig/skeleton.h"

namespace posewarp::pose::testing {

// Three segments stacked along LPS z: "base" (root, z 0..100), "middle" (z 100..200), "top" (z 200..300).
// Joint "lower" (base -> middle) at z = 100 has the identity frame; joint "upper" (middle -> top) at z = 200 has its
// x axis along LPS y and its y axis along -LPS x (a quarter turn about z), so that frame conversions show.
inline Eigen::Matrix3d upper_frame() {
  Eigen::Matrix3d frame;
  frame.col(0) = Eigen::Vector3d::UnitY();
  frame.col(1) = -Eigen::Vector3d::UnitX();
  frame.col(2) = Eigen::Vector3d::UnitZ();
  return frame;
}

inline rig::Skeleton chain_skeleton() {
  rig::Skeleton skeleton;
  const char* names[3] = {"base", "middle", "top"};
  for (int s = 0; s < 3; ++s) {
    rig::Segment segment;
    segment.name = names[s];
    segment.centroid_mm = Eigen::Vector3d(0.0, 0.0, 50.0 + 100.0 * s);
    segment.parent_joint = s - 1;
    skeleton.segments.push_back(segment);
  }
  rig::Joint lower;
  lower.name = "lower";
  lower.parent = 0;
  lower.child = 1;
  lower.centre_mm = Eigen::Vector3d(0.0, 0.0, 100.0);
  rig::Joint upper;
  upper.name = "upper";
  upper.parent = 1;
  upper.child = 2;
  upper.centre_mm = Eigen::Vector3d(0.0, 0.0, 200.0);
  upper.frame = upper_frame();
  skeleton.joints = {lower, upper};
  skeleton.root = 0;
  return skeleton;
}

// A chain of segments "s0", "s1", ... along LPS z, 100 mm apart, joined by the named joints in order (each at the
// top of its parent, identity frame): enough to check that a pose or a BVH map fits a rig's joint names.
inline rig::Skeleton named_chain(const std::vector<std::string>& joint_names) {
  rig::Skeleton skeleton;
  for (size_t s = 0; s <= joint_names.size(); ++s) {
    rig::Segment segment;
    segment.name = std::string("s") + std::to_string(s);
    segment.centroid_mm = Eigen::Vector3d(0.0, 0.0, 50.0 + 100.0 * static_cast<double>(s));
    segment.parent_joint = static_cast<int>(s) - 1;
    skeleton.segments.push_back(segment);
  }
  for (size_t j = 0; j < joint_names.size(); ++j) {
    rig::Joint joint;
    joint.name = joint_names[j];
    joint.parent = static_cast<int>(j);
    joint.child = static_cast<int>(j) + 1;
    joint.centre_mm = Eigen::Vector3d(0.0, 0.0, 100.0 * static_cast<double>(j + 1));
    skeleton.joints.push_back(joint);
  }
  return skeleton;
}

inline Eigen::Matrix3d rotation_about(const Eigen::Vector3d& axis, double degrees) {
  return Eigen::AngleAxisd(degrees * M_PI / 180.0, axis.normalized()).toRotationMatrix();
}

}  // namespace posewarp::pose::testing
