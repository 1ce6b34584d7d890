// Strict JSON helpers of the pose stage and the three written forms of a rotation.
#include <algorithm>
#include <cctype>
#include <cmath>
#include <fstream>
#include <set>
#include <sstream>
#include <vector>

#include "json_util.h"
#include "posewarp/pose/pose.h"
#include "posewarp/common/input_file.h"
#include "posewarp/common/json.h"

namespace posewarp::pose {

Eigen::Quaterniond rotation_from_angles_deg(double flexion, double abduction, double rotation) {
  constexpr double kRadiansPerDegree = M_PI / 180.0;
  return Eigen::Quaterniond(Eigen::AngleAxisd(flexion * kRadiansPerDegree, Eigen::Vector3d::UnitX()) *
                            Eigen::AngleAxisd(abduction * kRadiansPerDegree, Eigen::Vector3d::UnitY()) *
                            Eigen::AngleAxisd(rotation * kRadiansPerDegree, Eigen::Vector3d::UnitZ()));
}

namespace detail {
namespace {

std::string number_text(double value) {
  std::ostringstream out;
  out.precision(10);
  out << value;
  return out.str();
}

}  // namespace

Result<Json> parse_json(const std::string& text, const std::string& what) {
  return posewarp::parse_json<Json>(text, what);
}

Result<std::string> read_text_file(const std::string& path, std::string_view kind) {
  return read_text_input(path, kind);
}

Status check_fields(const Json& object, std::initializer_list<std::string_view> known, const std::string& where) {
  for (const auto& [key, value] : object.items()) {
    if (std::find(known.begin(), known.end(), key) == known.end()) {
      std::string names;
      for (std::string_view name : known) names += (names.empty() ? "\"" : ", \"") + std::string(name) + "\"";
      return invalid_argument_error(where + " has an unknown field \"" + key + "\"; known fields: " + names);
    }
  }
  return ok_status();
}

Status check_format(const Json& doc, std::string_view format, int version, const std::string& where) {
  if (doc.contains("format")) {
    if (!doc["format"].is_string() || doc["format"].get<std::string>() != format) {
      return invalid_argument_error(where + " has format " + doc["format"].dump() + ", expected \"" +
                                    std::string(format) + "\"");
    }
  }
  if (doc.contains("version")) {
    const Json& v = doc["version"];
    if (!v.is_number_integer() || v.get<int64_t>() < 1) {
      return invalid_argument_error(where + ": \"version\" must be a positive integer (got " + v.dump() + ")");
    }
    if (v.get<int64_t>() > version) {
      return invalid_argument_error(where + " has version " + v.dump() + "; this posewarp reads up to version " +
                                    std::to_string(version) + ". Upgrade posewarp");
    }
  }
  return ok_status();
}

Result<double> finite_number(const Json& value, const std::string& where, std::string_view field) {
  if (!value.is_number()) {
    return invalid_argument_error(where + ": \"" + std::string(field) + "\" must be a number (got " + value.dump() +
                                  ")");
  }
  const double number = value.get<double>();
  if (!std::isfinite(number)) {
    return invalid_argument_error(where + ": \"" + std::string(field) + "\" is " + number_text(number) +
                                  "; write a finite number");
  }
  return number;
}

Status outside_range_error(const std::string& where, std::string_view field, double value, double limit,
                           std::string_view unit, std::string_view hint) {
  return invalid_argument_error(where + ": \"" + std::string(field) + "\" = " + number_text(value) + " is outside [" +
                                number_text(-limit) + ", " + number_text(limit) + "] " + std::string(unit) + "; " +
                                std::string(hint));
}

Result<double> number_within(const Json& value, const std::string& where, std::string_view field, double limit,
                             std::string_view unit, std::string_view hint) {
  POSEWARP_ASSIGN_OR_RETURN(const double number, finite_number(value, where, field));
  if (std::abs(number) > limit) return outside_range_error(where, field, number, limit, unit, hint);
  return number;
}

Result<Eigen::VectorXd> finite_numbers(const Json& value, int size, const std::string& where, std::string_view field) {
  if (!value.is_array() || value.size() != static_cast<size_t>(size)) {
    return invalid_argument_error(where + ": \"" + std::string(field) + "\" must be a list of " + std::to_string(size) +
                                  " numbers (got " + value.dump() + ")");
  }
  Eigen::VectorXd numbers(size);
  for (int i = 0; i < size; ++i) {
    POSEWARP_ASSIGN_OR_RETURN(numbers[i], finite_number(value[static_cast<size_t>(i)], where,
                                                        std::string(field) + "[" + std::to_string(i) + "]"));
  }
  return numbers;
}

Result<Eigen::Quaterniond> rotation_from_json(const Json& object, const std::string& where,
                                              std::optional<Eigen::Vector3d>* angles_deg) {
  if (!object.is_object()) {
    return invalid_argument_error(where + " must be an object (got " + object.dump() + "); " + kRotationForms);
  }
  std::vector<std::string> forms;
  for (const auto& [key, value] : object.items()) {
    if (key != "quaternion" && key != "axis_angle" && key != "angles_deg") {
      return invalid_argument_error(where + " has an unknown field \"" + key + "\"; " + kRotationForms);
    }
    forms.push_back(key);
  }
  if (forms.empty()) return invalid_argument_error(where + " gives no rotation; " + kRotationForms);
  if (forms.size() > 1) {
    return invalid_argument_error(where + " gives its rotation " + std::to_string(forms.size()) + " ways (" +
                                  join(forms) + "); " + kRotationForms);
  }

  if (forms[0] == "quaternion") {
    POSEWARP_ASSIGN_OR_RETURN(const Eigen::VectorXd q, finite_numbers(object["quaternion"], 4, where, "quaternion"));
    const Eigen::Quaterniond rotation(q[0], q[1], q[2], q[3]);
    const double norm = rotation.norm();
    if (std::abs(norm - 1.0) > kUnitQuaternionTolerance) {
      return invalid_argument_error(where + ": \"quaternion\" [w, x, y, z] has length " + number_text(norm) +
                                    ", not 1; divide each component by " + number_text(norm) +
                                    " (a rotation is a unit quaternion)");
    }
    return rotation.normalized();
  }

  if (forms[0] == "axis_angle") {
    const Json& axis_angle = object["axis_angle"];
    const std::string inner = where + ", \"axis_angle\"";
    if (!axis_angle.is_object() || !axis_angle.contains("axis") || !axis_angle.contains("degrees")) {
      return invalid_argument_error(inner + " must be {\"axis\": [x, y, z], \"degrees\": d} (got " + axis_angle.dump() +
                                    ")");
    }
    POSEWARP_RETURN_IF_ERROR(check_fields(axis_angle, {"axis", "degrees"}, inner));
    POSEWARP_ASSIGN_OR_RETURN(const Eigen::VectorXd axis, finite_numbers(axis_angle["axis"], 3, inner, "axis"));
    POSEWARP_ASSIGN_OR_RETURN(const double degrees, number_within(axis_angle["degrees"], inner, "degrees", kMaxAngleDeg,
                                                                  "degrees", kAngleHint));
    if (!(axis.norm() > 1e-12)) {
      return invalid_argument_error(inner + ": \"axis\" is zero; give the direction to turn about, e.g. [1, 0, 0]");
    }
    return Eigen::Quaterniond(Eigen::AngleAxisd(degrees * M_PI / 180.0, Eigen::Vector3d(axis).normalized()));
  }

  const Json& angles = object["angles_deg"];
  const std::string inner = where + ", \"angles_deg\"";
  if (angles_deg == nullptr) {
    return invalid_argument_error(inner + ": anatomical angles belong to joints; give the root's rotation as a "
                                  "\"quaternion\" or an \"axis_angle\" in LPS axes");
  }
  if (!angles.is_object()) {
    return invalid_argument_error(inner + " must be {\"flexion\": d, \"abduction\": d, \"rotation\": d} (got " +
                                  angles.dump() + ")");
  }
  POSEWARP_RETURN_IF_ERROR(check_fields(angles, {"flexion", "abduction", "rotation"}, inner));
  double values[3] = {0.0, 0.0, 0.0};
  const char* names[3] = {"flexion", "abduction", "rotation"};
  for (int i = 0; i < 3; ++i) {
    if (angles.contains(names[i])) {
      POSEWARP_ASSIGN_OR_RETURN(values[i],
                                number_within(angles[names[i]], inner, names[i], kMaxAngleDeg, "degrees", kAngleHint));
    }
  }
  *angles_deg = Eigen::Vector3d(values[0], values[1], values[2]);
  return rotation_from_angles_deg(values[0], values[1], values[2]);
}

Json rotation_to_json(const Eigen::Quaterniond& rotation) {
  return Json{{"quaternion", Json::array({rotation.w(), rotation.x(), rotation.y(), rotation.z()})}};
}

}  // namespace detail
}  // namespace posewarp::pose
