// The body mask and the mesher's class volume (0 outside, 1 soft tissue, 2 + k bone segment k).
#pragma once

#include "posewarp/common/result.h"
#include "posewarp/common/volume.h"
#include "posewarp/labels/label_map.h"

namespace posewarp::labels {

struct BodyParams {
  // Join a CT threshold mask to the labelled voxels when a CT is given (segmentations rarely label skin and fat).
  bool use_ct = true;
  float ct_threshold_hu = -500.0f;  // voxels above this are body candidates
  // Keep only the largest 6-connected component of the CT mask (drops the table, blankets, cables).
  bool keep_largest_component = true;
  // Fill enclosed holes slice by slice along the grid axis closest to superior-inferior (bowel gas, airways).
  bool fill_holes = true;
};

Status validate(const BodyParams& params);

// 1 inside the body, 0 outside, on the labels' grid: every non-background label, joined with the CT mask.
// `ct` may be null; otherwise it must lie on the same grid as `labels`.
Result<LabelVolume> body_mask(const LabelMap& map, const LabelVolume& labels, const IntensityVolume* ct,
                              const BodyParams& params = {});

// The mesher's input: 0 outside the body, 1 soft tissue (any non-bone voxel of the body), 2 + k for voxels of
// bone segment k, k indexing map.bone_segments().
LabelVolume segment_classes(const LabelMap& map, const LabelVolume& labels, const LabelVolume& body);

}  // namespace posewarp::labels
