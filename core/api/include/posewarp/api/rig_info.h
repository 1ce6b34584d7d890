// A rig's skeleton as clients show and send it (`posewarp rig info`, GetRig and GetRigAssets, BVH retargeting's
// joint names): names and numbers, in the api's own types.
#pragma once

#include <Eigen/Core>

#include <string>
#include <vector>

#include "posewarp/api/joint_range.h"
#include "posewarp/api/rig.h"
#include "posewarp/common/volume.h"

namespace posewarp::api {

struct SegmentInfo {
  std::string name;
  std::vector<Label> labels;  // the label values that make up this rigid segment
  int64_t voxels = 0;
  Eigen::Vector3d centroid_mm = Eigen::Vector3d::Zero();  // LPS
};

struct JointInfo {
  std::string name;
  std::string parent, child;  // segment names
  Eigen::Vector3d centre_mm = Eigen::Vector3d::Zero();
  std::string method;  // how the centre was found: "contact-centroid", "sphere-fit", "cylinder-fit", "rig-spec", ...
  // Why the centre is where it is, in a sentence: the fit and its figures, the rig spec, or why the joint turns about
  // the middle of where its bones nearly touch (its declared kind, or why the declared kind's fit was refused).
  std::string placed_because;
  std::string kind;    // "ball", "hinge", ... or "unspecified"
  std::string side;    // "left", "right" or "midline"
  bool declared = false;  // the label map or the rig spec declared it
  double contact_area_mm2 = 0.0;
  // Columns: the flexion axis, the abduction axis, the child's long axis (LPS); a positive turn about each is
  // flexion, abduction and (times internal_rotation_sign) internal rotation.
  Eigen::Matrix3d frame = Eigen::Matrix3d::Identity();
  int internal_rotation_sign = 1;
  std::string flexion_moves_child;  // which way flexion moves the child's far end ("anterior", ...)
  double fit_radius_mm = 0.0;       // of the fitted sphere or cylinder (sphere-fit, cylinder-fit)
  double fit_rms_mm = 0.0;
  Eigen::Vector3d hinge_axis = Eigen::Vector3d::Zero();  // zero unless a cylinder was fitted
  std::vector<MotionRange> ranges;  // measured at build; empty in rigs built before that (joint_ranges measures it)
};

struct SkeletonInfo {
  std::string root;  // the root segment's name
  std::vector<SegmentInfo> segments;
  std::vector<JointInfo> joints;  // parents before children
  std::vector<std::string> missing_segments;  // bone segments of the label map absent from the volume
  std::vector<std::string> notes;             // what the builder decided that a user should know
};

SkeletonInfo describe_skeleton(const Rig& rig);

// The role of each of the rig's surfaces, in their order: "bone" (a bone segment's label), "skin" (label 0) or
// "tissue".
std::vector<std::string> surface_roles(const Rig& rig);

}  // namespace posewarp::api
