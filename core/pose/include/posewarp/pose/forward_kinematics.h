// forward_kinematics: one rigid rest -> posed transform per bone segment from a pose.
#pragma once

#include <vector>

#include "posewarp/common/result.h"
#include "posewarp/pose/pose.h"
#include "posewarp/pose/rigid_transform.h"
#include "posewarp/rig/skeleton.h"

namespace posewarp::pose {

// Returns #segments transforms (index = segment index), each mapping rest LPS mm to posed LPS mm.
//   root segment:          T_root(p) = R (p - c_root) + c_root + t        (Pose::root, c_root its centroid)
//   child c of joint j:    M_j(p)    = F_j R_j F_j^T (p - c_j) + c_j      (c_j centre_mm, F_j frame, R_j the pose's
//                                                                          rotation, identity when not listed)
//                          T_c       = T_parent(j) * M_j                  (first M_j, then the parent's motion)
// The order of evaluation is derived from the tree (root outwards), not taken from the order of the joints.
// INVALID_ARGUMENT when validate_pose fails, or when the skeleton is not a tree rooted at `root` (a segment
// reached by no joint, a segment that is the child of two joints, indices out of range) or a joint frame is not a
// rotation.
Result<std::vector<RigidTransform>> forward_kinematics(const rig::Skeleton& skeleton, const Pose& pose);

}  // namespace posewarp::pose
