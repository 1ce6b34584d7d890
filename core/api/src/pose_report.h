// The quality report's parts that PoseEngine fills as a pose goes (pose_report.cpp): the mesh, the warp's figures and
// the labels.
#pragma once

#include <string>
#include <utility>
#include <vector>

#include "engine_state.h"
#include "posewarp/resample/tet_warp.h"
#include "posewarp/rig/skeleton.h"
#include "posewarp/skinning/skinning.h"

namespace posewarp::api::internal {

// Step 3 of a pose: mesh quality (inversions, volume change, bone rigidity), joints past their range and the soft
// tissue and skin around each moved joint, into result.report. Its phases go to hooks.on_phase.
void report_mesh(const PoseEngine::Prepared& p, const Pose& pose, const skinning::SegmentTransforms& segments,
                 const std::vector<std::string>& names, const ProgressHooks& hooks, PoseResult& result);

// The warp's figures in the report.
void report_warp(const resample::TetWarp& warp, const std::vector<std::string>& names, PoseResult& result);

// The label report, which needs only the posed labels: counts before and after, names, each bone's voxel deviation.
void report_labels(const PoseEngine::Prepared& p, const resample::TetWarp& warp, const LabelVolume& posed,
                   const std::vector<std::pair<double, double>>& deviation, const std::vector<std::string>& names,
                   QualityReport& qr);

// The segments' names, in the skeleton's order (the report's rows).
std::vector<std::string> segment_names(const rig::Skeleton& skeleton);

}  // namespace posewarp::api::internal
