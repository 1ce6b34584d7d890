// LabelMap validation, JSON form and census against a label volume.
#include "posewarp/common/json.h"
#include "posewarp/labels/label_map.h"
#include "posewarp/common/atomic_file.h"
#include "posewarp/common/input_file.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cctype>
#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>

namespace posewarp::labels {
namespace {

using json = nlohmann::json;

constexpr std::string_view kFormat = "posewarp.label_map";
constexpr int kVersion = 1;

}  // namespace

Result<LabelMap> label_map_from_json(std::string_view json_text, std::string_view source) {
  const std::string where(source);
  POSEWARP_ASSIGN_OR_RETURN(json doc, parse_json<json>(json_text, "label map " + where));
  try {
    if (!doc.is_object()) return invalid_argument_error("label map " + where + " must be a JSON object");
    if (doc.contains("format") && doc["format"].get<std::string>() != kFormat) {
      return invalid_argument_error("label map " + where + " has format '" + doc["format"].get<std::string>() +
                                    "', expected '" + std::string(kFormat) + "'");
    }
    const int version = doc.value("version", kVersion);
    if (version > kVersion) {
      return invalid_argument_error("label map " + where + " has version " + std::to_string(version) +
                                    "; this posewarp reads up to version " + std::to_string(kVersion) +
                                    ". Upgrade posewarp");
    }
    if (!doc.contains("labels") || !doc["labels"].is_array()) {
      return invalid_argument_error("label map " + where + " needs a \"labels\" array");
    }
    std::vector<LabelEntry> entries;
    for (const json& item : doc["labels"]) {
      if (!item.is_object() || !item.contains("value") || !item["value"].is_number_integer()) {
        return invalid_argument_error("label map " + where + ": every entry of \"labels\" needs an integer \"value\" (" +
                                      item.dump() + ")");
      }
      LabelEntry entry;
      const int64_t value = item["value"].get<int64_t>();
      if (value < std::numeric_limits<Label>::min() || value > std::numeric_limits<Label>::max()) {
        return invalid_argument_error("label map " + where + ": value " + std::to_string(value) + " is out of range");
      }
      entry.value = static_cast<Label>(value);
      entry.name = item.value("name", std::string());
      Result<LabelRole> role = role_from_name(item.value("role", std::string("tissue")));
      if (!role.ok()) return role.status().with_context("label map " + where + ", value " + std::to_string(value));
      entry.role = *role;
      entry.segment = item.value("segment", std::string());
      entries.push_back(std::move(entry));
    }
    std::vector<JointName> joints;
    if (doc.contains("joints")) {
      for (const json& item : doc["joints"]) {
        if (!item.is_object()) {
          return invalid_argument_error("label map " + where + ": each joint must be an object, got " +
                                        item.type_name());
        }
        JointName joint;
        joint.name = item.value("name", std::string());
        if (item.contains("parent") || item.contains("child")) {
          joint.segment_a = item.value("parent", std::string());
          joint.segment_b = item.value("child", std::string());
        } else {
          const json segments = item.value("segments", json::array());
          if (!segments.is_array() || segments.size() != 2) {
            return invalid_argument_error("label map " + where + ": joint '" + joint.name +
                                          "' needs \"parent\" and \"child\" (or \"segments\": [parent, child])");
          }
          joint.segment_a = segments[0].get<std::string>();
          joint.segment_b = segments[1].get<std::string>();
        }
        if (joint.segment_a.empty() || joint.segment_b.empty()) {
          return invalid_argument_error("label map " + where + ": joint '" + joint.name +
                                        "' needs both \"parent\" and \"child\"");
        }
        if (item.contains("kind")) {
          Result<JointKind> kind = joint_kind_from_name(item["kind"].get<std::string>());
          if (!kind.ok()) return kind.status().with_context("label map " + where + ", joint '" + joint.name + "'");
          joint.kind = *kind;
        }
        if (item.contains("flexion")) {
          Result<FlexionDirection> flexion = flexion_direction_from_name(item["flexion"].get<std::string>());
          if (!flexion.ok()) return flexion.status().with_context("label map " + where + ", joint '" + joint.name + "'");
          joint.flexion = *flexion;
        }
        joints.push_back(std::move(joint));
      }
    }
    Result<LabelMap> map = LabelMap::create(doc.value("name", std::string(source)), std::move(entries),
                                            std::move(joints), doc.value("root_segment", std::string()));
    if (!map.ok()) return map.status().with_context("label map " + where);
    return map;
  } catch (const json::exception& error) {
    return invalid_argument_error("label map " + where + " has a field of the wrong type: " + error.what());
  }
}

std::string label_map_to_json(const LabelMap& map) {
  json doc;
  doc["format"] = kFormat;
  doc["version"] = kVersion;
  doc["name"] = map.name();
  if (!map.root_segment().empty()) doc["root_segment"] = map.root_segment();
  json labels = json::array();
  for (const LabelEntry& entry : map.entries()) {
    json item{{"value", entry.value}, {"name", entry.name}, {"role", role_name(entry.role)}};
    if (entry.role == LabelRole::kBone) item["segment"] = entry.segment;
    labels.push_back(std::move(item));
  }
  doc["labels"] = std::move(labels);
  json joints = json::array();
  for (const JointName& joint : map.joint_names()) {
    joints.push_back({{"name", joint.name},
                      {"parent", joint.segment_a},
                      {"child", joint.segment_b},
                      {"kind", joint_kind_name(joint.kind)},
                      {"flexion", flexion_direction_name(joint.flexion)}});
  }
  doc["joints"] = std::move(joints);
  return doc.dump(2) + "\n";
}

Result<LabelMap> read_label_map(const std::string& path) {
  POSEWARP_ASSIGN_OR_RETURN(const std::string text, read_text_input(path, "label map"));
  return label_map_from_json(text, "'" + path + "'");
}

Status write_label_map(const LabelMap& map, const std::string& path) {
  return write_file_atomically(path, label_map_to_json(map), "label map");
}

namespace {

// A name as relabel_by_name compares it: lower case, spaces and hyphens as underscores.
std::string comparable(std::string_view name) {
  std::string out;
  for (char c : name) out += (c == ' ' || c == '-') ? '_' : static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  return out;
}

}  // namespace

Result<LabelMap> relabel_by_name(const LabelMap& map, const std::vector<std::pair<Label, std::string>>& names,
                                 std::vector<std::string>* unknown) {
  std::map<std::string, const LabelEntry*> by_name;
  for (const LabelEntry& e : map.entries()) by_name.emplace(comparable(e.name), &e);
  std::vector<LabelEntry> entries;
  std::set<std::string> segments;
  for (const LabelEntry& e : map.entries()) {
    if (e.value == 0) entries.push_back(e);  // the background keeps 0
  }
  for (const auto& [value, name] : names) {
    if (value == 0) return invalid_argument_error("segment '" + name + "' has the value 0, which is the background");
    const auto known = by_name.find(comparable(name));
    LabelEntry entry;
    if (known != by_name.end()) {
      entry = *known->second;
    } else {
      entry.name = name;
      entry.role = LabelRole::kTissue;
      if (unknown != nullptr) unknown->push_back(name);
    }
    entry.value = value;
    if (entry.role == LabelRole::kBone) segments.insert(entry.segment);
    entries.push_back(entry);
  }
  std::vector<JointName> joints;
  for (const JointName& j : map.joint_names()) {
    if (segments.count(j.segment_a) && segments.count(j.segment_b)) joints.push_back(j);
  }
  const std::string root = segments.count(map.root_segment()) ? map.root_segment() : std::string();
  return LabelMap::create(map.name(), std::move(entries), std::move(joints), root);
}

LabelCensus census(const LabelMap& map, const LabelVolume& volume) {
  LabelCensus result;
  // Dense counting for the usual small label range, sparse for the rest.
  constexpr Label kDense = 1 << 16;
  std::vector<int64_t> dense(kDense, 0);
  for (const Label value : volume.voxels()) {
    if (value >= 0 && value < kDense) {
      ++dense[static_cast<size_t>(value)];
    } else {
      ++result.voxel_counts[value];
    }
  }
  for (Label value = 0; value < kDense; ++value) {
    if (dense[static_cast<size_t>(value)] > 0) result.voxel_counts[value] = dense[static_cast<size_t>(value)];
  }
  for (const auto& [value, count] : result.voxel_counts) {
    if (value != 0 && map.find(value) == nullptr) result.unknown.push_back(value);
  }
  for (const LabelEntry& entry : map.entries()) {
    if (entry.role != LabelRole::kBackground && !result.voxel_counts.count(entry.value)) {
      result.absent.push_back(entry.value);
    }
  }
  for (const std::string& segment : map.bone_segments()) {
    bool present = false;
    for (const Label value : map.labels_of_segment(segment)) present = present || result.voxel_counts.count(value);
    (present ? result.present_bone_segments : result.absent_bone_segments).push_back(segment);
  }
  return result;
}

}  // namespace posewarp::labels
