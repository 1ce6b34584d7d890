// Built-in label maps.
#pragma once

#include <string>
#include <string_view>
#include <vector>

#include "posewarp/common/result.h"
#include "posewarp/labels/label_map.h"

namespace posewarp::labels {

// TotalSegmentator v2 "total" task (117 classes, Wasserthal et al. 2023). Each lumbar and cervical vertebra is
// its own segment; thoracic vertebrae, ribs, sternum and costal cartilages form the rigid "thorax"; sacrum and
// S1 form "sacrum"; each hip bone, femur, humerus, scapula and clavicle is its own segment; the skull is one.
// Organs, muscles and vessels are soft tissue. The preferred root is the sacrum.
LabelMap totalsegmentator_v2_preset();

// Names accepted by preset_by_name().
std::vector<std::string> preset_names();
// "totalsegmentator" (alias "totalsegmentator_v2").
Result<LabelMap> preset_by_name(std::string_view name);

}  // namespace posewarp::labels
