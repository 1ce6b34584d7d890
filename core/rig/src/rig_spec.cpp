// Rig spec JSON: a user's corrections to the automatic skeleton.
#include <nlohmann/json.hpp>

#include <cmath>
#include <fstream>
#include <limits>
#include <map>
#include <sstream>

#include "posewarp/common/json.h"
#include "posewarp/common/input_file.h"
#include "posewarp/rig/skeleton.h"

namespace posewarp::rig {

Result<RigSpec> rig_spec_from_json(const std::string& text, const std::string& source) {
  using json = nlohmann::json;
  POSEWARP_ASSIGN_OR_RETURN(const json doc, parse_json<json>(text, "rig spec " + source));
  RigSpec spec;
  try {
    if (!doc.is_object()) return invalid_argument_error("rig spec " + source + " must be a JSON object");
    for (const auto& [key, value] : doc.items()) {
      if (key != "segments" && key != "root" && key != "joints" && key != "remove_joints" &&
          key != "contact_distance_mm" && key != "format" && key != "version") {
        return invalid_argument_error("rig spec " + source + " has an unknown field \"" + key +
                                      "\"; known: segments, root, contact_distance_mm, joints, remove_joints");
      }
    }
    if (doc.contains("segments")) {
      std::map<Label, std::string> owner;  // a label in two segments would silently belong to the last
      for (const auto& [name, labels] : doc["segments"].items()) {
        if (!labels.is_array() || labels.empty()) {
          return invalid_argument_error("rig spec " + source + ": segment \"" + name + "\" needs a list of labels");
        }
        // Whole numbers in Label's range only: get<Label>() of 3.3e120 is undefined, and of 25.7 silently 25 (a
        // soft-tissue label would become a bone).
        std::vector<Label> values;
        for (const json& value : labels) {
          const bool whole = value.is_number_integer() || (value.is_number_float() && std::isfinite(value.get<double>()) &&
                                                           std::floor(value.get<double>()) == value.get<double>());
          const double v = value.is_number() ? value.get<double>() : -1.0;
          if (!whole || v < 0.0 || v > static_cast<double>(std::numeric_limits<Label>::max())) {
            return invalid_argument_error("rig spec " + source + ": segment \"" + name + "\" lists " + value.dump() +
                                          ", which is not a label value (a whole number from 0 to " +
                                          std::to_string(std::numeric_limits<Label>::max()) + ")");
          }
          const auto [listed, fresh] = owner.emplace(static_cast<Label>(v), name);
          if (!fresh) {
            return invalid_argument_error("rig spec " + source + ": label " + value.dump() + " is listed in segment \"" +
                                          listed->second + "\" and in segment \"" + name +
                                          "\"; a label belongs to one segment");
          }
          values.push_back(static_cast<Label>(v));
        }
        spec.segments.emplace_back(name, std::move(values));
      }
    }
    spec.root = doc.value("root", std::string());
    if (doc.contains("contact_distance_mm")) {
      const double d = doc["contact_distance_mm"].get<double>();
      if (!(d > 0.0) || d > kMaxContactDistanceMm) {
        return invalid_argument_error("rig spec " + source + ": contact_distance_mm must lie in (0, " +
                                      std::to_string(static_cast<int>(kMaxContactDistanceMm)) +
                                      "] mm (joint spaces are a few mm; a larger distance joins bones that do not "
                                      "touch and makes the contact search unbounded)");
      }
      spec.contact_distance_mm = d;
    }
    if (doc.contains("joints")) {
      for (const json& item : doc["joints"]) {
        JointSpec joint;
        joint.child = item.value("child", std::string());
        if (joint.child.empty()) {
          return invalid_argument_error("rig spec " + source + ": every joint needs a \"child\" segment (" +
                                        item.dump() + ")");
        }
        joint.parent = item.value("parent", std::string());
        joint.name = item.value("name", std::string());
        if (item.contains("centre_mm")) {
          const auto c = item["centre_mm"].get<std::vector<double>>();
          if (c.size() != 3 || !std::isfinite(c[0]) || !std::isfinite(c[1]) || !std::isfinite(c[2]) ||
              std::abs(c[0]) > 1e5 || std::abs(c[1]) > 1e5 || std::abs(c[2]) > 1e5) {
            return invalid_argument_error("rig spec " + source + ": centre_mm needs 3 finite numbers within 100 m "
                                          "of the scanner's origin (LPS mm)");
          }
          joint.centre_mm = Eigen::Vector3d(c[0], c[1], c[2]);
        }
        spec.joints.push_back(joint);
      }
    }
    if (doc.contains("remove_joints")) {
      for (const json& pair : doc["remove_joints"]) {
        const auto names = pair.get<std::vector<std::string>>();
        if (names.size() != 2) {
          return invalid_argument_error("rig spec " + source + ": remove_joints entries are [segment, segment]");
        }
        spec.remove_joints.emplace_back(names[0], names[1]);
      }
    }
  } catch (const json::exception& error) {
    return invalid_argument_error("rig spec " + source + " has a field of the wrong type: " + error.what());
  }
  return spec;
}

Result<RigSpec> read_rig_spec(const std::string& path) {
  POSEWARP_ASSIGN_OR_RETURN(const std::string text, read_text_input(path, "rig spec"));
  return rig_spec_from_json(text, "'" + path + "'");
}

}  // namespace posewarp::rig
