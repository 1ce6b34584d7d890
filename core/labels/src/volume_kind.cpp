// Label volumes that look like labels, and CTs that are not label volumes.
#include "posewarp/labels/volume_kind.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <sstream>
#include <unordered_set>
#include <vector>

namespace posewarp::labels {
namespace {

// "0, 1, 2, 5" (at most `most`, then ", ...").
std::string value_list(std::vector<Label> values, size_t most) {
  std::sort(values.begin(), values.end());
  std::ostringstream out;
  for (size_t i = 0; i < values.size() && i < most; ++i) out << (i ? ", " : "") << values[i];
  if (values.size() > most) out << ", ...";
  return out.str();
}

}  // namespace

Status check_labels_look_like_labels(const LabelVolume& labels, const std::string& labels_name,
                                     const std::string& ct_name) {
  std::unordered_set<Label> seen;
  seen.reserve(2 * kMaxDistinctLabels);
  const Label* voxel = labels.data();
  const int64_t count = labels.voxel_count();
  // Neighbouring voxels mostly hold the same label: the set is consulted only when the value changes.
  bool have_last = false;
  Label last = 0;
  for (int64_t v = 0; v < count; ++v) {
    if (have_last && voxel[v] == last) continue;
    last = voxel[v];
    have_last = true;
    if (last < kMinLabelValue) {
      std::string message = labels_name + " holds the value " + std::to_string(last) +
                            ", where label values are structure numbers (none below " +
                            std::to_string(kMinLabelValue) +
                            "): it looks like an intensity volume (CT air is about -1000 HU) given as the labels";
      if (!ct_name.empty()) message += " (and " + ct_name + " given as the CT: are the two swapped?)";
      return invalid_argument_error(message + ". Give the segmentation as the labels");
    }
    if (seen.insert(last).second && static_cast<int>(seen.size()) > kMaxDistinctLabels) {
      std::string message = labels_name + " holds more than " + std::to_string(kMaxDistinctLabels) +
                            " distinct values, where a label volume holds one per structure (TotalSegmentator: "
                            "117): it looks like an intensity volume (CT/MRI) given as the labels";
      if (!ct_name.empty()) message += " (and " + ct_name + " given as the CT: are the two swapped?)";
      return invalid_argument_error(message + ". Give the segmentation as the labels");
    }
  }
  return ok_status();
}

Status check_ct_is_not_labels(const IntensityVolume& ct, const LabelMap& map, const std::string& ct_name,
                              const std::string& labels_name) {
  std::unordered_set<Label> seen;
  const float* voxel = ct.data();
  const int64_t count = ct.voxel_count();
  bool have_last = false;
  float last = 0.0f;
  for (int64_t v = 0; v < count; ++v) {
    const float value = voxel[v];
    if (have_last && value == last) continue;
    last = value;
    have_last = true;
    // A fraction, or a value no label map names (air at -1000 HU, most of any CT): not a label volume.
    if (!(value == std::floor(value)) || std::abs(value) > static_cast<float>(std::numeric_limits<Label>::max() / 2)) {
      return ok_status();
    }
    const Label label = static_cast<Label>(value);
    if (label != 0 && map.find(label) == nullptr) return ok_status();
    if (seen.insert(label).second && static_cast<int>(seen.size()) > kMaxDistinctLabels) return ok_status();
  }
  const bool zero = seen.erase(0) > 0;
  if (seen.empty()) return ok_status();  // all zero: an empty CT, not a label volume
  const std::vector<Label> values(seen.begin(), seen.end());
  return invalid_argument_error(ct_name + " holds only whole values that are 0 or labels the label map '" + map.name() +
                                "' names (" + std::to_string(values.size() + (zero ? 1 : 0)) +
                                " distinct: " + (zero ? "0, " : "") + value_list(values, 8) +
                                "): it looks like a label volume given as the CT (and " + labels_name +
                                " as the labels: are the two swapped?). Give the CT or MRI intensities as the CT, or "
                                "leave the CT out");
}

}  // namespace posewarp::labels
