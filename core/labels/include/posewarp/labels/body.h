// The body mask and the mesher's class volume (0 outside, 1 soft tissue, 2 + k bone segment k).
#pragma once

#include "posewarp/common/result.h"
#include "posewarp/common/rig_params.h"
#include "posewarp/common/volume.h"
#include "posewarp/labels/label_map.h"

namespace posewarp::labels {

// The mask's knobs are vocabulary (posewarp/common/rig_params.h).
using BodyParams = posewarp::BodyMaskParams;

Status validate(const BodyParams& params);

// 1 inside the body, 0 outside, on the labels' grid: every non-background label, joined with the CT mask.
// `ct` may be null; otherwise it must lie on the same grid as `labels`.
Result<LabelVolume> body_mask(const LabelMap& map, const LabelVolume& labels, const IntensityVolume* ct,
                              const BodyParams& params = {});

// The mesher's input: 0 outside the body, 1 soft tissue (any non-bone voxel of the body), 2 + k for voxels of
// bone segment k, k indexing map.bone_segments().
LabelVolume segment_classes(const LabelMap& map, const LabelVolume& labels, const LabelVolume& body);

}  // namespace posewarp::labels
