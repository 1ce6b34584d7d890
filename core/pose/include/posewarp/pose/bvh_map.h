// BvhMap: which BVH joint drives which rig joint, and how BVH axes and units become LPS millimetres.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "posewarp/common/animation.h"
#include "posewarp/common/result.h"

namespace posewarp::pose {

using posewarp::BvhMap;  // posewarp/common/animation.h
using posewarp::kBvhRootTarget;

// BVH map JSON, version 1 (only "joints" required; unknown fields and duplicate keys are errors):
//   {"format": "posewarp.bvh_map", "version": 1, "up": "y", "scale_to_mm": 10,
//    "joints": {"LeftUpLeg": "hip_left", "LeftLeg": "knee_left", "Hips": "root"},
//    "ignore": ["LeftFoot", "LeftToeBase"]}
// A BVH joint may be mapped or ignored, not both, and each rig joint may be driven by one BVH joint only.
// Mapping the BVH root to "root" makes its rotation (relative to BVH rest) turn the body about the root segment's
// centroid and its position channels (relative to the first imported frame) move it; ignoring the BVH root keeps
// the rig's root segment where it is. Only the BVH root may be mapped to "root".
Result<BvhMap> bvh_map_from_json(const std::string& text, const std::string& source);
// NOT_FOUND when the file cannot be opened; otherwise as bvh_map_from_json.
Result<BvhMap> read_bvh_map(const std::string& path);
std::string bvh_map_to_json(const BvhMap& map);

}  // namespace posewarp::pose
