// Motion: a sequence of poses, and how the joints of a BVH motion capture map onto a rig's joints. Their files: pose/.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "posewarp/common/pose.h"

namespace posewarp {

struct Animation {
  std::vector<Pose> frames;
  double frame_time_s = 1.0 / 30.0;  // seconds between frames, > 0
};

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

}  // namespace posewarp
