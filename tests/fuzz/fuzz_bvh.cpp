// BVH clips: any bytes give an animation of a four-bone chain rig or an error (the map is the example's,
// data/poses/bar_wave_map.json, so well-formed clips get past the parser into the conversion).
#include <Eigen/Core>

#include <cstddef>
#include <cstdint>
#include <string>

#include "posewarp/pose/bvh.h"

namespace {

posewarp::rig::Skeleton chain() {
  posewarp::rig::Skeleton skeleton;
  for (int s = 0; s < 4; ++s) {
    posewarp::rig::Segment segment;
    segment.name = "bar_bone_" + std::to_string(s + 1);
    segment.centroid_mm = Eigen::Vector3d(0.0, 0.0, 30.0 + 60.0 * s);
    segment.parent_joint = s - 1;
    skeleton.segments.push_back(segment);
    if (s == 0) continue;
    posewarp::rig::Joint joint;
    joint.name = "joint_" + std::to_string(s) + "_" + std::to_string(s + 1);
    joint.parent = s - 1;
    joint.child = s;
    joint.centre_mm = Eigen::Vector3d(0.0, 0.0, 60.0 * s);
    skeleton.joints.push_back(joint);
  }
  return skeleton;
}

}  // namespace

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const posewarp::rig::Skeleton skeleton = chain();
  static const posewarp::pose::BvhMap map =
      posewarp::pose::bvh_map_from_json(
          R"({"format": "posewarp.bvh_map", "version": 1, "up": "y", "scale_to_mm": 10,
              "joints": {"bone2": "joint_1_2", "bone3": "joint_2_3", "bone4": "joint_3_4"}, "ignore": ["bone1"]})",
          "fuzz map")
          .value();
  const std::string text(reinterpret_cast<const char*>(data), size);
  (void)posewarp::pose::import_bvh(text, map, skeleton, 0, -1);
  return 0;
}
