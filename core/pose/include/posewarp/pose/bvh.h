// import_bvh: a Biovision Hierarchy (BVH) motion clip as an Animation of a rig, through a BvhMap.
#pragma once

#include <string>

#include "posewarp/common/result.h"
#include "posewarp/pose/animation.h"
#include "posewarp/pose/bvh_map.h"
#include "posewarp/rig/skeleton.h"

namespace posewarp::pose {

// Reads HIERARCHY (one ROOT, nested JOINT and End Site blocks, OFFSET, CHANNELS with position and rotation channels
// in any order) and MOTION ("Frames:", "Frame Time:", one line of numbers per frame), then keeps frames
// [first, last] (0-based, inclusive; last = -1 means to the end).
//
// Conventions. A BVH joint's local rotation in a frame is the product of its rotation channels in channel order,
// in degrees (Zrotation Xrotation Yrotation -> L = Rz * Rx * Ry), relative to its parent in BVH's world-aligned
// rest axes; its world rotation is G = G_parent * L, and BVH rest (all channels zero) is the identity. For a BVH
// joint k mapped to rig joint j, with a the nearest ancestor of k that is mapped (or the BVH root), A the axis
// change of BvhMap::up and F_j the joint's frame:
//   R_lps = A (G_a^T G_k) A^T,   R_j = F_j^T R_lps F_j,
// so the rotations of ignored joints between a and k are folded into j. The BVH root mapped to "root" gives
// Pose::root rotation A G_root A^T and translation scale_to_mm * A (p - p_first), p the root's position channels.
// Position channels of other joints, OFFSETs and End Sites do not move the rig (its bone lengths are the CT's).
//
// Map entries for BVH joints the file does not have are allowed, so that one map serves a family of clips; their
// rig joints must still exist.
//
// Errors, all INVALID_ARGUMENT unless noted: a malformed file (the message names the line: wrong number of
// values on a frame line, truncated motion, a word where a number belongs, a frame value that is not finite or
// beyond +-10000, unknown channels, unbalanced braces); the root translation of a frame is checked by
// validate_pose (kMaxRootTranslationMm) when the animation is posed;
// BVH joints neither mapped nor ignored, or rig joints the skeleton lacks (each message lists the names and says
// what to add to the map); a mapping that contradicts the rig's tree (the mapped ancestor of a BVH joint must drive
// the nearest mapped ancestor joint of its rig joint); first < 0 or last < first; OUT_OF_RANGE when the range
// runs past the file's frames.
Result<Animation> import_bvh(const std::string& bvh_text, const BvhMap& map, const rig::Skeleton& skeleton, int first,
                             int last);
// NOT_FOUND when the file cannot be opened; otherwise as import_bvh (messages name the file).
Result<Animation> read_bvh(const std::string& path, const BvhMap& map, const rig::Skeleton& skeleton, int first,
                           int last);

}  // namespace posewarp::pose
