// BVH map JSON: which BVH joint drives which rig joint.
#include "posewarp/pose/bvh_map.h"

#include <cmath>
#include <map>
#include <set>

#include "json_util.h"

namespace posewarp::pose {
namespace {

using detail::Json;

constexpr std::string_view kFormat = "posewarp.bvh_map";
constexpr int kVersion = 1;

}  // namespace

Result<BvhMap> bvh_map_from_json(const std::string& text, const std::string& source) {
  const std::string where = "BVH map " + source;
  POSEWARP_ASSIGN_OR_RETURN(const Json doc, detail::parse_json(text, where));
  try {
    if (!doc.is_object()) return invalid_argument_error(where + " must be a JSON object");
    POSEWARP_RETURN_IF_ERROR(
        detail::check_fields(doc, {"format", "version", "joints", "ignore", "up", "scale_to_mm"}, where));
    POSEWARP_RETURN_IF_ERROR(detail::check_format(doc, kFormat, kVersion, where));
    BvhMap map;
    if (!doc.contains("joints") || !doc["joints"].is_object()) {
      return invalid_argument_error(where + " needs \"joints\": {\"<BVH joint>\": \"<rig joint>\", ...}");
    }
    std::map<std::string, std::string> driver_of;  // rig joint -> BVH joint
    for (const auto& [bvh_joint, rig_joint] : doc["joints"].items()) {
      if (!rig_joint.is_string() || rig_joint.get<std::string>().empty()) {
        return invalid_argument_error(
            where + ": BVH joint \"" + bvh_joint +
            "\" must map to the name of a rig joint (a string), or \"root\" for the BVH root (got " + rig_joint.dump() +
            ")");
      }
      const std::string target = rig_joint.get<std::string>();
      const auto [it, inserted] = driver_of.emplace(target, bvh_joint);
      if (!inserted) {
        return invalid_argument_error(where + ": rig joint \"" + target + "\" is driven by two BVH joints (\"" +
                                      it->second + "\" and \"" + bvh_joint + "\"); map one and ignore the other");
      }
      map.joints.emplace_back(bvh_joint, target);
    }
    if (doc.contains("ignore")) {
      const Json& ignore = doc["ignore"];
      if (!ignore.is_array()) {
        return invalid_argument_error(where + ": \"ignore\" must be a list of BVH joint names (got " + ignore.dump() +
                                      ")");
      }
      std::set<std::string> ignored;
      for (const Json& name : ignore) {
        if (!name.is_string()) {
          return invalid_argument_error(where + ": \"ignore\" holds " + name.dump() + "; list BVH joint names only");
        }
        const std::string bvh_joint = name.get<std::string>();
        if (doc["joints"].contains(bvh_joint)) {
          return invalid_argument_error(
              where + ": BVH joint \"" + bvh_joint +
              "\" is both mapped and ignored; remove it from one of \"joints\" and \"ignore\"");
        }
        if (ignored.insert(bvh_joint).second) map.ignore.push_back(bvh_joint);
      }
    }
    if (doc.contains("up")) {
      const Json& up = doc["up"];
      if (!up.is_string() || (up.get<std::string>() != "y" && up.get<std::string>() != "z")) {
        return invalid_argument_error(
            where + ": \"up\" must be \"y\" (y up, facing +z) or \"z\" (z up, facing -y); got " + up.dump());
      }
      map.up = up.get<std::string>()[0];
    }
    if (doc.contains("scale_to_mm")) {
      POSEWARP_ASSIGN_OR_RETURN(map.scale_to_mm, detail::finite_number(doc["scale_to_mm"], where, "scale_to_mm"));
      if (!(map.scale_to_mm > 0.0)) {
        return invalid_argument_error(where + ": \"scale_to_mm\" must be positive (10 when the BVH is in centimetres)");
      }
    }
    return map;
  } catch (const Json::exception& error) {
    return invalid_argument_error(where + " has a field of the wrong type: " + error.what());
  }
}

Result<BvhMap> read_bvh_map(const std::string& path) {
  POSEWARP_ASSIGN_OR_RETURN(const std::string text, detail::read_text_file(path, "BVH map"));
  return bvh_map_from_json(text, "'" + path + "'");
}

std::string bvh_map_to_json(const BvhMap& map) {
  Json doc;
  doc["format"] = kFormat;
  doc["version"] = kVersion;
  doc["up"] = std::string(1, map.up);
  doc["scale_to_mm"] = map.scale_to_mm;
  Json joints = Json::object();
  for (const auto& [bvh_joint, rig_joint] : map.joints) joints[bvh_joint] = rig_joint;
  doc["joints"] = std::move(joints);
  doc["ignore"] = map.ignore;
  return doc.dump(2) + "\n";
}

}  // namespace posewarp::pose
