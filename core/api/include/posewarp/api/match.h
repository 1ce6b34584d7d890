// Matching a posture through the facade: the pose that brings a rig's bones onto the same bones in another scan's
// labels, found by name (pose/match.h does the fitting), and its report as JSON.
#pragma once

#include <string>
#include <vector>

#include "posewarp/api/rig.h"
#include "posewarp/common/label_map.h"
#include "posewarp/common/posture_match.h"
#include "posewarp/common/result.h"

namespace posewarp::api {

using posewarp::MatchOptions;
using posewarp::MatchResult;
using posewarp::SegmentMatch;

struct PostureMatch {
  MatchResult match;
  // The rig's bone labels whose names `target_map` does not have (their segments match without them, or are
  // skipped when none of their labels is named).
  std::vector<std::string> unnamed_labels;
  double seconds = 0.0;
};

// The pose of `rig` that matches `target`, a label volume whose values `target_map` names: each segment's labels are
// looked up in the target by their names in the rig's map (the same values when both maps are the same preset).
// Bones missing from the target are skipped and named; INVALID_ARGUMENT when the root segment is missing.
Result<PostureMatch> match_posture(const Rig& rig, const LabelVolume& target, const LabelMap& target_map,
                                   const MatchOptions& options = {});

// A named standard posture of the rig (pose/match.h: "limbs-straight" or "supine-arms-down": arms along the body,
// legs straight; "arms-up": arms straight over the head), so that bodies scanned in other postures can be compared in
// one.
Result<Pose> standard_posture(const Rig& rig, const std::string& name);

// The report: each segment's joint, anatomical angles, residual (mean and largest surface distance, Dice) and
// iterations, or why it was skipped; where an anatomical range held a joint back; the root's motion; the labels the
// target's map lacks; the time.
std::string posture_match_to_json(const PostureMatch& match);

}  // namespace posewarp::api
