// BvhMap: which BVH joint drives which rig joint, and how BVH axes and units become LPS millimetres.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "posewarp/common/result.h"

namespace posewarp::pose {

// The rig-side name that makes the BVH root joint drive the pose's root transform (rotation and translation).
inline constexpr const char* kBvhRootTarget = "root";

struct BvhMap {
  std::vector<std::pair<std::string, std::string>> joints;  // (BVH joint, rig joint or "root"), in file order
  std::vector<std::string> ignore;                          // BVH joints whose motion is dropped
  // BVH axes -> LPS, both right-handed, the character standing in the anatomical position at BVH rest:
  //   'y' (y up, the character faces +z, its left is +x; CMU, Mixamo, most exporters):
  //        x_lps = x_bvh, y_lps = -z_bvh, z_lps = y_bvh
  //   'z' (z up, the character faces -y, its left is +x; Blender's front view): x_lps = x_bvh, y_lps = y_bvh,
  //        z_lps = z_bvh
  char up = 'y';
  double scale_to_mm = 10.0;  // BVH length unit -> mm (10 for the usual centimetres); > 0
};

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
