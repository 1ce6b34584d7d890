// A posture match as data: how a rig's pose was fitted to another scan's bones (pose/match.h computes it, the api
// and the CLI report it).
#pragma once

#include <Eigen/Core>

#include <string>
#include <vector>

#include "posewarp/common/pose.h"

namespace posewarp {

struct MatchOptions {
  int max_iterations = 60;       // ICP iterations per segment
  int max_points = 3000;         // surface voxels of a segment that take part (evenly subsampled)
  // A hinge turns about its flexion axis, give or take `hinge_slack_deg` of abduction and rotation: an axis fitted
  // on one scan is a few degrees off the true one, and a turn about it alone cannot follow a bone turned about the
  // true axis (2.3 degrees off at a knee bent 60 degrees put the foot 18 mm away). false: hinges turn every way.
  bool constrain_hinges = true;
  double hinge_slack_deg = 5.0;
  // The limbs' joints (shoulders, elbows, wrists, hips, knees, ankles) turn within anatomy's ranges of motion
  // (pose/match.h); false lets them turn any way the target's bones ask.
  bool anatomical_ranges = true;
};

// How one bone segment was matched.
struct SegmentMatch {
  std::string segment;
  std::string joint;  // the joint it turns about ("" for the root)
  bool matched = false;
  double volume_ml = 0.0;  // the segment's bone in the rig
  std::string skipped;     // why not (the segment is missing from the rig's or the target's labels)
  Eigen::Vector3d angles_deg = Eigen::Vector3d::Zero();  // the joint's flexion, abduction, internal rotation
  // After the match: the distance of the segment's surface voxels to the target bone's (mean and largest), and the
  // Dice overlap of the moved segment with the target bone on the target's grid.
  double mean_distance_mm = 0.0, max_distance_mm = 0.0, dice = 0.0;
  int iterations = 0;
  // Where the angles found go past the joint's range of motion measured on the rig's own study (where the bones
  // beyond it meet another bone, the other joints at rest; by more than its 5-degree step): e.g. "flexion 82.0 past
  // 70 (bones meet)". Empty when within, or when the rig has no ranges. Reported, not enforced: those ranges are
  // narrower than anatomy's.
  std::string beyond_range;
  // Where the joint's range (anatomy's, or a hinge's slack about its axis) held the bone back from where the target's
  // bone lies: e.g. "flexion 171.3 held at 150.0". Empty when the fit lies within it.
  std::string held_at_range;
};

struct MatchResult {
  Pose pose;
  std::vector<SegmentMatch> segments;  // the skeleton's segment order
};

}  // namespace posewarp
