// Forward kinematics over the skeleton's tree, root outwards.
#include "posewarp/pose/forward_kinematics.h"

#include <deque>
#include <map>

namespace posewarp::pose {
namespace {

bool is_rotation(const Eigen::Matrix3d& r) {
  return r.allFinite() && (r.transpose() * r - Eigen::Matrix3d::Identity()).norm() < 1e-6 && r.determinant() > 0.0;
}

}  // namespace

Result<std::vector<RigidTransform>> forward_kinematics(const rig::Skeleton& skeleton, const Pose& pose) {
  POSEWARP_RETURN_IF_ERROR(validate_pose(pose, skeleton));
  const int segment_count = static_cast<int>(skeleton.segments.size());
  if (segment_count == 0) return invalid_argument_error("the skeleton has no segments; nothing to pose");
  if (skeleton.root < 0 || skeleton.root >= segment_count) {
    return invalid_argument_error("the skeleton's root index " + std::to_string(skeleton.root) + " is not one of its " +
                                  std::to_string(segment_count) + " segments");
  }
  auto segment_name = [&](int s) { return "\"" + skeleton.segments[static_cast<size_t>(s)].name + "\""; };

  // The tree as the joints describe it: each non-root segment is the child of exactly one joint.
  std::vector<int> joint_of_child(static_cast<size_t>(segment_count), -1);
  std::vector<std::vector<int>> joints_from(static_cast<size_t>(segment_count));
  for (size_t j = 0; j < skeleton.joints.size(); ++j) {
    const rig::Joint& joint = skeleton.joints[j];
    if (joint.parent < 0 || joint.parent >= segment_count || joint.child < 0 || joint.child >= segment_count ||
        joint.parent == joint.child) {
      return invalid_argument_error("joint \"" + joint.name + "\" links segments " + std::to_string(joint.parent) +
                                    " and " + std::to_string(joint.child) + ", which is not a pair of the skeleton's " +
                                    std::to_string(segment_count) + " segments");
    }
    if (joint.child == skeleton.root) {
      return invalid_argument_error("joint \"" + joint.name + "\" has the root segment " + segment_name(joint.child) +
                                    " as its child; the root has no parent joint");
    }
    int& owner = joint_of_child[static_cast<size_t>(joint.child)];
    if (owner >= 0) {
      return invalid_argument_error("segment " + segment_name(joint.child) + " is the child of two joints (\"" +
                                    skeleton.joints[static_cast<size_t>(owner)].name + "\" and \"" + joint.name +
                                    "\"); a skeleton is a tree");
    }
    owner = static_cast<int>(j);
    if (!is_rotation(joint.frame)) {
      return invalid_argument_error("joint \"" + joint.name + "\" has a frame that is not a rotation matrix");
    }
    joints_from[static_cast<size_t>(joint.parent)].push_back(static_cast<int>(j));
  }

  std::map<std::string, const JointRotation*> rotation_of;
  for (const JointRotation& joint : pose.joints) rotation_of[joint.joint] = &joint;

  const rig::Segment& root = skeleton.segments[static_cast<size_t>(skeleton.root)];
  std::vector<RigidTransform> transforms(static_cast<size_t>(segment_count));
  std::vector<bool> reached(static_cast<size_t>(segment_count), false);
  transforms[static_cast<size_t>(skeleton.root)] = RigidTransform::about(pose.root.rotation, root.centroid_mm);
  transforms[static_cast<size_t>(skeleton.root)].translation += pose.root.translation;
  reached[static_cast<size_t>(skeleton.root)] = true;

  // Breadth first from the root: a parent's transform is always known before its children's.
  std::deque<int> queue{skeleton.root};
  while (!queue.empty()) {
    const int s = queue.front();
    queue.pop_front();
    for (const int j : joints_from[static_cast<size_t>(s)]) {
      const rig::Joint& joint = skeleton.joints[static_cast<size_t>(j)];
      const auto it = rotation_of.find(joint.name);
      const Eigen::Matrix3d world =
          it == rotation_of.end() ? Eigen::Matrix3d::Identity() : joint_rotation_in_lps(joint, *it->second);
      transforms[static_cast<size_t>(joint.child)] =
          transforms[static_cast<size_t>(s)] * RigidTransform::about(world, joint.centre_mm);
      reached[static_cast<size_t>(joint.child)] = true;
      queue.push_back(joint.child);
    }
  }
  std::vector<std::string> unreached;
  for (int s = 0; s < segment_count; ++s) {
    if (!reached[static_cast<size_t>(s)]) unreached.push_back(segment_name(s));
  }
  if (!unreached.empty()) {
    std::string names;
    for (const std::string& name : unreached) names += (names.empty() ? "" : ", ") + name;
    return invalid_argument_error("segments " + names + " are not connected to the root segment " +
                                  segment_name(skeleton.root) +
                                  " by joints; every segment needs a path of joints to "
                                  "the root");
  }
  return transforms;
}

}  // namespace posewarp::pose
