// Placing one joint of the automatic skeleton (skeleton.cpp's last step): its centre from the articular geometry
// (a sphere fitted to a ball, a cylinder to a hinge's convex side, else the contact centroid), checked for sanity,
// then its anatomical frame. Private to the rig stage.
#pragma once

#include <Eigen/Core>

#include <map>
#include <utility>
#include <vector>

#include "posewarp/common/image_geometry.h"
#include "posewarp/labels/label_map.h"
#include "posewarp/rig/skeleton.h"

namespace posewarp::rig::detail {

// Contact of segment a with segment b: the voxels of a that lie within the contact distance of b.
struct Contact {
  int64_t count = 0;
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  std::vector<Index3> voxels;
  std::vector<float> distance_mm;  // per voxel: to the nearest voxel of b (centre to centre)
};
using Contacts = std::map<std::pair<int, int>, Contact>;  // (a, b) -> a's voxels near b

inline Eigen::Vector3d physical(const ImageGeometry& g, int64_t i, int64_t j, int64_t k) {
  const Vec3 p = g.index_to_physical({static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)});
  return {p[0], p[1], p[2]};
}

// What placing a joint needs from the skeleton builder.
struct JointPlacement {
  const ImageGeometry& g;
  const labels::LabelMap& map;
  const RigSpec& spec;
  const SkeletonParams& params;
  Skeleton& skeleton;  // its notes take what placing the joint found
  const std::vector<int16_t>& segment_at;
  const std::vector<std::vector<Index3>>& surface;
  const Contacts& contacts;
  double max_spacing;
  double max_offset;
};

// The joint between parent segment s and child c, whose contact area is `area` (mm^2).
Joint place_joint(const JointPlacement& at, int s, int c, double area);

}  // namespace posewarp::rig::detail
