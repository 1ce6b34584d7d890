// Shared by the pose JSON readers: strict parsing (duplicate keys, unknown fields, finite numbers) and rotations.
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>
#include <nlohmann/json.hpp>

#include <initializer_list>
#include <optional>
#include <string>
#include <string_view>

#include "posewarp/common/result.h"
#include "posewarp/pose/pose.h"

namespace posewarp::pose::detail {

// Ordered, so that joints keep the order the user wrote them in.
using Json = nlohmann::ordered_json;

// Largest |norm - 1| of a quaternion accepted as a rotation.
inline constexpr double kUnitQuaternionTolerance = 1e-3;

// Parses `text`; INVALID_ARGUMENT "<what> is not valid JSON: ..." or "<what>: key "k" appears twice ...".
Result<Json> parse_json(const std::string& text, const std::string& what);

// The whole file as text; NOT_FOUND "cannot open <kind> '<path>' ..." when it cannot be read.
Result<std::string> read_text_file(const std::string& path, std::string_view kind);

// INVALID_ARGUMENT naming the first key of `object` that is not in `known`, and listing the known ones.
Status check_fields(const Json& object, std::initializer_list<std::string_view> known, const std::string& where);

// "format" (when present) must equal `format`; "version" (when present) an integer from 1 to `version`.
Status check_format(const Json& doc, std::string_view format, int version, const std::string& where);

// A finite number, or INVALID_ARGUMENT "<where>: <field> must be a finite number ...".
Result<double> finite_number(const Json& value, const std::string& where, std::string_view field);
// A finite number within [-limit, limit], or INVALID_ARGUMENT
// "<where>: "<field>" = <value> is outside [-limit, limit] <unit>; <hint>".
Result<double> number_within(const Json& value, const std::string& where, std::string_view field, double limit,
                             std::string_view unit, std::string_view hint);
// The message of a number outside [-limit, limit], shared by the JSON readers and validate_pose.
Status outside_range_error(const std::string& where, std::string_view field, double value, double limit,
                           std::string_view unit, std::string_view hint);
// The hints of the two ranges of pose.h.
inline constexpr const char* kAngleHint = "give an angle within a full turn either way";
inline constexpr const char* kTranslationHint =
    "a body is about 2 m long; a larger move is not a re-pose (move the body less)";
// `size` finite numbers.
Result<Eigen::VectorXd> finite_numbers(const Json& value, int size, const std::string& where, std::string_view field);

// Reads an object holding exactly one of "quaternion", "axis_angle", "angles_deg" (see pose.h); `where` names the
// joint or the root for the messages. The quaternion of the result is normalized (after the unit check).
// When `angles_deg` is given and the object uses "angles_deg", the angles are stored there too; without it the form
// is refused (the root takes no anatomical angles).
Result<Eigen::Quaterniond> rotation_from_json(const Json& object, const std::string& where,
                                              std::optional<Eigen::Vector3d>* angles_deg = nullptr);
// {"quaternion": [w, x, y, z]}
Json rotation_to_json(const Eigen::Quaterniond& rotation);

// A pose object (see pose.h); `where` is e.g. "pose 'knee.json'". The joints are not checked against a rig.
Result<Pose> pose_from_object(const Json& doc, const std::string& where);
Json pose_to_object(const Pose& pose);

// The hint every rotation message ends with.
inline constexpr const char* kRotationForms =
    "give exactly one of \"quaternion\": [w, x, y, z], \"axis_angle\": {\"axis\": [x, y, z], \"degrees\": d} or "
    "\"angles_deg\": {\"flexion\": d, \"abduction\": d, \"rotation\": d}";

// a, b and c joined with ", ".
std::string join(const auto& names) {
  std::string joined;
  for (const auto& name : names) {
    if (!joined.empty()) joined += ", ";
    joined += name;
  }
  return joined;
}

}  // namespace posewarp::pose::detail
