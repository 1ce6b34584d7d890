// Skeleton lookups and the names of body sides.
#include "posewarp/common/skeleton.h"

namespace posewarp {

std::string_view body_side_name(BodySide side) {
  switch (side) {
    case BodySide::kMidline: return "midline";
    case BodySide::kLeft: return "left";
    case BodySide::kRight: return "right";
  }
  return "midline";
}

int Skeleton::segment_index(const std::string& name) const {
  for (size_t k = 0; k < segments.size(); ++k) {
    if (segments[k].name == name) return static_cast<int>(k);
  }
  return -1;
}

int Skeleton::joint_index(const std::string& name) const {
  for (size_t j = 0; j < joints.size(); ++j) {
    if (joints[j].name == name) return static_cast<int>(j);
  }
  return -1;
}

}  // namespace posewarp
