// RigidTransform arithmetic.
#include "posewarp/common/rigid_transform.h"

namespace posewarp {

Eigen::Vector3d RigidTransform::apply(const Eigen::Vector3d& p) const {
  return rotation * p + translation;
}

RigidTransform RigidTransform::inverse() const {
  RigidTransform inverted;
  inverted.rotation = rotation.transpose();
  inverted.translation = -(inverted.rotation * translation);
  return inverted;
}

RigidTransform RigidTransform::operator*(const RigidTransform& other) const {
  RigidTransform composed;
  composed.rotation = rotation * other.rotation;
  composed.translation = rotation * other.translation + translation;
  return composed;
}

RigidTransform RigidTransform::identity() {
  return RigidTransform();
}

RigidTransform RigidTransform::about(const Eigen::Matrix3d& rotation, const Eigen::Vector3d& centre_mm) {
  RigidTransform t;
  t.rotation = rotation;
  t.translation = centre_mm - rotation * centre_mm;
  return t;
}

}  // namespace posewarp
