// RigidTransform: a rotation and a translation in LPS millimetres, the rest -> posed motion of one bone segment
// (vocabulary: a pose's root, forward kinematics' answer, the api's per-segment motion).
#pragma once

#include <Eigen/Core>

namespace posewarp {

// p' = rotation * p + translation, with p and p' in LPS mm. `rotation` is 3 x 3 orthonormal with determinant +1.
struct RigidTransform {
  Eigen::Matrix3d rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d translation = Eigen::Vector3d::Zero();

  Eigen::Vector3d apply(const Eigen::Vector3d& p) const;
  // The transform that undoes this one: rotation^T, -rotation^T * translation.
  RigidTransform inverse() const;
  // Composition, `this` after `other`: (a * b).apply(p) == a.apply(b.apply(p)).
  RigidTransform operator*(const RigidTransform& other) const;
  static RigidTransform identity();
  // Rotation by `rotation` (3 x 3) about the point `centre_mm`: p' = rotation * (p - centre) + centre.
  static RigidTransform about(const Eigen::Matrix3d& rotation, const Eigen::Vector3d& centre_mm);
};

}  // namespace posewarp
