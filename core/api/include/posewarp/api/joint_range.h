// How far each joint of a rig turns before its bones meet another bone: what `rig info` reports so that a pose that
// would drive one bone into its neighbour is known before posing (the joint's range of motion on this study).
#pragma once

#include <string>
#include <vector>

#include "posewarp/api/rig.h"
#include "posewarp/common/result.h"

namespace posewarp::api {

using posewarp::MotionRange;

struct JointRange {
  std::string joint;
  std::vector<MotionRange> motions;  // flexion for every joint, abduction too for balls and planes
};

struct RangeParams {
  double step_deg = 5.0;
  double max_deg = 150.0;
  double overlap_ml = 1.0;     // bone meeting bone: more than this much of the moving bones inside another bone
  int64_t max_points = 30000;  // the moving bones' voxels are sampled on a coarser lattice beyond this many
};

// For each joint: the bone voxels of its child and everything beyond it, turned about the joint centre in steps
// (flexion, then abduction, each way, the other joints at rest), until more than overlap_ml of them lands in a bone
// that does not move with them. INVALID_ARGUMENT for parameters out of range.
Result<std::vector<JointRange>> joint_ranges(const Rig& rig, const RangeParams& params = {});

}  // namespace posewarp::api
