// LabelMap: validation, lookups and the names of its roles, joint kinds and flexion directions.
#include "posewarp/common/label_map.h"

#include <algorithm>
#include <set>

namespace posewarp {

std::string_view role_name(LabelRole role) {
  switch (role) {
    case LabelRole::kBackground: return "background";
    case LabelRole::kBone: return "bone";
    case LabelRole::kTissue: return "tissue";
    case LabelRole::kIgnore: return "ignore";
  }
  return "tissue";
}

Result<LabelRole> role_from_name(std::string_view name) {
  if (name == "background") return LabelRole::kBackground;
  if (name == "bone") return LabelRole::kBone;
  if (name == "tissue") return LabelRole::kTissue;
  if (name == "ignore") return LabelRole::kIgnore;
  return invalid_argument_error("unknown label role '" + std::string(name) +
                                "'; use one of background, bone, tissue, ignore");
}

std::string_view joint_kind_name(JointKind kind) {
  switch (kind) {
    case JointKind::kUnspecified: return "unspecified";
    case JointKind::kBall: return "ball";
    case JointKind::kHinge: return "hinge";
    case JointKind::kPlane: return "plane";
  }
  return "unspecified";
}

Result<JointKind> joint_kind_from_name(std::string_view name) {
  if (name == "unspecified") return JointKind::kUnspecified;
  if (name == "ball") return JointKind::kBall;
  if (name == "hinge") return JointKind::kHinge;
  if (name == "plane") return JointKind::kPlane;
  return invalid_argument_error("unknown joint kind '" + std::string(name) +
                                "'; use one of ball (hip, shoulder), hinge (knee, elbow, ankle), plane, unspecified");
}

std::string_view flexion_direction_name(FlexionDirection direction) {
  switch (direction) {
    case FlexionDirection::kAnterior: return "anterior";
    case FlexionDirection::kPosterior: return "posterior";
    case FlexionDirection::kSuperior: return "superior";
    case FlexionDirection::kInferior: return "inferior";
  }
  return "anterior";
}

Result<FlexionDirection> flexion_direction_from_name(std::string_view name) {
  if (name == "anterior") return FlexionDirection::kAnterior;
  if (name == "posterior") return FlexionDirection::kPosterior;
  if (name == "superior") return FlexionDirection::kSuperior;
  if (name == "inferior") return FlexionDirection::kInferior;
  return invalid_argument_error("unknown flexion direction '" + std::string(name) +
                                "'; use the way flexion moves the child's far end: anterior (hip, shoulder, elbow, "
                                "spine), posterior (knee), superior (ankle dorsiflexion) or inferior");
}

Result<LabelMap> LabelMap::create(std::string name, std::vector<LabelEntry> entries,
                                  std::vector<JointName> joint_names, std::string root_segment) {
  LabelMap map;
  map.name_ = std::move(name);
  for (size_t i = 0; i < entries.size(); ++i) {
    LabelEntry& entry = entries[i];
    if (entry.name.empty()) {
      return invalid_argument_error("label " + std::to_string(entry.value) + " has no name; give every label a name");
    }
    if (entry.value == 0 && entry.role != LabelRole::kBackground) {
      return invalid_argument_error("label 0 ('" + entry.name + "') must have role background: 0 is outside the body");
    }
    if (entry.role == LabelRole::kBone && entry.segment.empty()) entry.segment = entry.name;
    if (entry.role != LabelRole::kBone) entry.segment.clear();
    auto [it, inserted] = map.index_.emplace(entry.value, i);
    if (!inserted) {
      return invalid_argument_error("label value " + std::to_string(entry.value) + " is listed twice ('" +
                                    entries[it->second].name + "' and '" + entry.name +
                                    "'); each value may appear once");
    }
  }
  map.entries_ = std::move(entries);
  const std::vector<std::string> segments = map.bone_segments();
  const std::set<std::string> known(segments.begin(), segments.end());
  for (const JointName& joint : joint_names) {
    for (const std::string* segment : {&joint.segment_a, &joint.segment_b}) {
      if (!known.count(*segment)) {
        return invalid_argument_error("joint name '" + joint.name + "' refers to segment '" + *segment +
                                      "', which no bone label of the map belongs to");
      }
    }
    if (joint.segment_a == joint.segment_b) {
      return invalid_argument_error("joint '" + joint.name + "' joins segment '" + joint.segment_a + "' to itself");
    }
  }
  if (!root_segment.empty() && !known.count(root_segment)) {
    return invalid_argument_error("root segment '" + root_segment + "' is not a bone segment of the label map");
  }
  map.joint_names_ = std::move(joint_names);
  map.root_segment_ = std::move(root_segment);
  return map;
}

const LabelEntry* LabelMap::find(Label value) const {
  auto it = index_.find(value);
  return it == index_.end() ? nullptr : &entries_[it->second];
}

LabelRole LabelMap::role_of(Label value) const {
  if (const LabelEntry* entry = find(value)) return entry->role;
  return value == 0 ? LabelRole::kBackground : LabelRole::kTissue;
}

std::vector<std::string> LabelMap::bone_segments() const {
  std::vector<std::string> segments;
  for (const LabelEntry& entry : entries_) {
    if (entry.role == LabelRole::kBone &&
        std::find(segments.begin(), segments.end(), entry.segment) == segments.end()) {
      segments.push_back(entry.segment);
    }
  }
  return segments;
}

std::vector<Label> LabelMap::labels_of_segment(std::string_view segment) const {
  std::vector<Label> values;
  for (const LabelEntry& entry : entries_) {
    if (entry.role == LabelRole::kBone && entry.segment == segment) values.push_back(entry.value);
  }
  return values;
}

const JointName* LabelMap::declared_joint(std::string_view segment_a, std::string_view segment_b) const {
  for (const JointName& joint : joint_names_) {
    if ((joint.segment_a == segment_a && joint.segment_b == segment_b) ||
        (joint.segment_a == segment_b && joint.segment_b == segment_a)) {
      return &joint;
    }
  }
  return nullptr;
}

std::optional<std::string> LabelMap::joint_name(std::string_view segment_a, std::string_view segment_b) const {
  for (const JointName& joint : joint_names_) {
    if ((joint.segment_a == segment_a && joint.segment_b == segment_b) ||
        (joint.segment_a == segment_b && joint.segment_b == segment_a)) {
      return joint.name;
    }
  }
  return std::nullopt;
}

}  // namespace posewarp
