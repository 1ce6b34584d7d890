// What a volume is for: a label volume must look like labels, and the CT must not be a label volume (the two given
// the wrong way round). Checked before any expensive work, so a swap costs a pass over the voxels, not a rig build.
#pragma once

#include <string>

#include "posewarp/common/status.h"
#include "posewarp/common/volume.h"
#include "posewarp/labels/label_map.h"

namespace posewarp::labels {

// Most distinct values a label volume holds: one per structure (TotalSegmentator v2 has 117 classes); a CT or an
// MRI holds thousands.
inline constexpr int kMaxDistinctLabels = 1000;
// Lowest value a label volume holds: labels are structure numbers, while air in a CT lies near -1000 HU.
inline constexpr Label kMinLabelValue = -100;

// OK when `labels` holds at most kMaxDistinctLabels distinct values, none below kMinLabelValue. Otherwise INVALID_ARGUMENT: "<labels_name>
// holds more than 1000 distinct values ...; it looks like an intensity volume (CT/MRI) given as the labels", naming
// `ct_name` too when it is not empty (the two may be swapped). Names are used as given, e.g. "the labels
// 'seg.nii.gz'". One pass over the voxels that stops at the 1001st distinct value. (A floating-point file with
// fractional values is already refused by io::read_label_volume.)
Status check_labels_look_like_labels(const LabelVolume& labels, const std::string& labels_name,
                                     const std::string& ct_name = {});

// OK when `ct` is not a label volume. INVALID_ARGUMENT when every voxel is a whole number that is 0 or a value
// `map` names, with at least one such non-zero value (and so at most kMaxDistinctLabels distinct values): the
// labels given as the CT. The message names `ct_name` and `labels_name` and the values found. Stops at the first
// voxel that no label volume would hold (a fraction, a value the map does not name: -1000 HU air), so a real CT
// costs next to nothing.
Status check_ct_is_not_labels(const IntensityVolume& ct, const LabelMap& map, const std::string& ct_name,
                              const std::string& labels_name);

}  // namespace posewarp::labels
