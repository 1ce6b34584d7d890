// Matching a posture: the pose that brings each bone segment of a rig onto the same bone in another scan's labels.
// From the root outwards, each segment's surface voxels are aligned rigidly with the target bone's (ICP with
// nearest neighbours on a grid, pairs beyond three times the median distance left out): the root by a rotation and
// a translation, every other segment by a rotation about its joint's centre alone (its parent is placed already, so
// a child cannot drift off its joint), a hinge about its flexion axis give or take a few degrees (MatchOptions::
// hinge_slack_deg). The pose gives each matched joint its
// anatomical angles.
#pragma once

#include <Eigen/Core>

#include <optional>
#include <string>
#include <vector>

#include "posewarp/common/posture_match.h"
#include "posewarp/common/result.h"
#include "posewarp/common/volume.h"
#include "posewarp/pose/pose.h"
#include "posewarp/rig/skeleton.h"

namespace posewarp::pose {

using posewarp::MatchOptions;
using posewarp::MatchResult;
using posewarp::SegmentMatch;

// A limb joint's range of motion in anatomical angles (degrees: flexion, abduction, internal rotation) from the
// anatomical position: normal adult values (AAOS), rounded outward. With MatchOptions::anatomical_ranges a match keeps
// each limb joint within it: the rest posture's own angles (from limbs-straight: a rest scan is rarely in the
// anatomical position) are taken off, each fitted turn is read in whichever of its two angle triples lies nearer the
// range (an arm raised 170 degrees is abduction 170, not flexion 180, abduction 10, rotation 180) and clamped into it.
struct AnatomicalRange {
  Eigen::Vector3d min_deg, max_deg;
};
// By the joint name's first word: shoulder, elbow, wrist, hip, knee, ankle; nullopt for the others (spine, girdle,
// patella, jaw), which a match leaves unconstrained.
std::optional<AnatomicalRange> anatomical_range(const std::string& joint);

// The pose of `skeleton` (built on `rest`) that matches `target`: `target_labels[k]` are the target's label values
// of segment k (empty where the target lacks that bone; the segment then stays at rest relative to its parent and
// is reported as skipped). INVALID_ARGUMENT when the root segment is missing from either side or `target_labels`
// does not have one entry per segment.
Result<MatchResult> match_posture(const rig::Skeleton& skeleton, const LabelVolume& rest, const LabelVolume& target,
                                  const std::vector<std::vector<Label>>& target_labels,
                                  const MatchOptions& options = {});

// Named standard postures. `limbs-straight` (also `supine-arms-down`) turns each limb (the children of the shoulders,
// elbows, hips and knees) to point straight down the body (LPS -z, the scan's head-to-foot axis), arms along the body
// and legs straight; `arms-up` raises the arms straight over the head instead (through the side: abducted), as chest
// and abdomen CT is scanned, legs straight. A hinge turns about its axis only. A limb's direction is its joint frame's
// long axis (into the child bone); a limb whose bone the scan cuts off near its joint (its centroid within 50 mm) is
// left as it is.
// The pose of `skeleton` in the standard posture `name`; INVALID_ARGUMENT for another name (the message lists the
// postures), or a skeleton with none of the limbs that posture turns.
Result<Pose> standard_posture(const rig::Skeleton& skeleton, const std::string& name);

// Anatomical angles (flexion, abduction, internal rotation, degrees) of a joint rotation in LPS about its centre:
// the inverse of rig::joint_rotation_from_angles (intrinsic x, y, z; abduction within [-90, 90]).
Eigen::Vector3d anatomical_angles_deg(const rig::Joint& joint, const Eigen::Matrix3d& rotation_lps);

}  // namespace posewarp::pose
