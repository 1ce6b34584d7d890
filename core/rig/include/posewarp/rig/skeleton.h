// The skeleton found automatically from a label volume (Sujar et al. 2018 section 3.1, made automatic: contact graph,
// maximum spanning tree, joint centres), and the rig spec read from JSON.
#pragma once

#include <Eigen/Core>

#include <optional>
#include <string_view>
#include <string>
#include <vector>

#include "posewarp/common/progress.h"
#include "posewarp/common/result.h"
#include "posewarp/common/volume.h"
#include "posewarp/common/rig_params.h"
#include "posewarp/common/skeleton.h"
#include "posewarp/labels/label_map.h"

namespace posewarp::rig {

// The skeleton, the rig spec and the skeleton's knobs are vocabulary (posewarp/common/skeleton.h, rig_params.h).
using posewarp::BodySide;
using posewarp::body_side_name;
using posewarp::Joint;
using posewarp::JointSpec;
using posewarp::kMaxContactDistanceMm;
using posewarp::MotionRange;
using posewarp::RigSpec;
using posewarp::Segment;
using posewarp::Skeleton;
using posewarp::SkeletonParams;

Result<RigSpec> rig_spec_from_json(const std::string& text, const std::string& source);
Result<RigSpec> read_rig_spec(const std::string& path);

Status validate(const SkeletonParams& params);

// Builds the skeleton of the bone segments present in `labels`. FAILED_PRECONDITION when fewer than two bone
// segments are present; INVALID_ARGUMENT when the spec names segments or labels the volume does not hold.
Result<Skeleton> build_skeleton(const LabelVolume& labels, const labels::LabelMap& map, const RigSpec& spec,
                                const SkeletonParams& params, const ProgressHooks& hooks);

// Mesher classes for a skeleton: 0 outside `body`, 1 soft tissue, 2 + k for voxels of segment k. Where two
// segments touch (26-neighbourhood), the touching voxels of both become soft tissue, so no mesh vertex is shared by two
// bones (a shared vertex could not follow both).
LabelVolume skeleton_classes(const Skeleton& skeleton, const LabelVolume& labels, const LabelVolume& body);

}  // namespace posewarp::rig
