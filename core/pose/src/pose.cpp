// Pose JSON (read, write) and validation of a pose against a skeleton.
#include "posewarp/pose/pose.h"

#include <algorithm>
#include <cmath>
#include <map>
#include <set>

#include "json_util.h"
#include "posewarp/rig/anatomical_frame.h"

namespace posewarp::pose {
namespace {

using detail::Json;

constexpr std::string_view kFormat = "posewarp.pose";
constexpr int kVersion = 1;

// Edit distance, for "did you mean" hints on misspelt joint names.
size_t edit_distance(const std::string& a, const std::string& b) {
  std::vector<size_t> row(b.size() + 1);
  for (size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (size_t i = 1; i <= a.size(); ++i) {
    size_t diagonal = row[0];
    row[0] = i;
    for (size_t j = 1; j <= b.size(); ++j) {
      const size_t above = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diagonal + (a[i - 1] == b[j - 1] ? 0 : 1)});
      diagonal = above;
    }
  }
  return row[b.size()];
}

bool is_rotation(const Eigen::Matrix3d& r) {
  return r.allFinite() && (r.transpose() * r - Eigen::Matrix3d::Identity()).norm() < 1e-6 && r.determinant() > 0.0;
}

}  // namespace

namespace detail {

Result<Pose> pose_from_object(const Json& doc, const std::string& where) {
  if (!doc.is_object()) return invalid_argument_error(where + " must be a JSON object (got " + doc.dump() + ")");
  POSEWARP_RETURN_IF_ERROR(check_fields(doc, {"format", "version", "name", "root", "joints"}, where));
  POSEWARP_RETURN_IF_ERROR(check_format(doc, kFormat, kVersion, where));
  Pose pose;
  if (doc.contains("name")) {
    if (!doc["name"].is_string()) return invalid_argument_error(where + ": \"name\" must be a string");
    pose.name = doc["name"].get<std::string>();
  }
  if (doc.contains("root")) {
    const Json& root = doc["root"];
    const std::string root_where = where + ", root";
    if (!root.is_object()) {
      return invalid_argument_error(root_where + " must be {\"translation_mm\": [x, y, z], \"rotation\": {...}}");
    }
    POSEWARP_RETURN_IF_ERROR(check_fields(root, {"translation_mm", "rotation"}, root_where));
    if (root.contains("translation_mm")) {
      POSEWARP_ASSIGN_OR_RETURN(const Eigen::VectorXd t,
                                finite_numbers(root["translation_mm"], 3, root_where, "translation_mm"));
      for (int a = 0; a < 3; ++a) {
        if (std::abs(t[a]) > kMaxRootTranslationMm) {
          return outside_range_error(root_where, "translation_mm[" + std::to_string(a) + "]", t[a],
                                     kMaxRootTranslationMm, "mm", kTranslationHint);
        }
      }
      pose.root.translation = t;
    }
    if (root.contains("rotation")) {
      POSEWARP_ASSIGN_OR_RETURN(const Eigen::Quaterniond q,
                                rotation_from_json(root["rotation"], root_where + " rotation"));
      pose.root.rotation = q.toRotationMatrix();
    }
  }
  if (doc.contains("joints")) {
    const Json& joints = doc["joints"];
    if (!joints.is_object()) {
      return invalid_argument_error(where + ": \"joints\" must be an object {\"<joint>\": {<rotation>}, ...} (got " +
                                    joints.dump() + ")");
    }
    for (const auto& [name, rotation] : joints.items()) {
      std::optional<Eigen::Vector3d> angles;
      POSEWARP_ASSIGN_OR_RETURN(const Eigen::Quaterniond q,
                                rotation_from_json(rotation, where + ", joint \"" + name + "\"", &angles));
      pose.joints.push_back({name, q, angles});
    }
  }
  return pose;
}

Json pose_to_object(const Pose& pose) {
  Json doc;
  doc["format"] = kFormat;
  doc["version"] = kVersion;
  doc["name"] = pose.name;
  const bool moved_root = pose.root.rotation != Eigen::Matrix3d::Identity() || !pose.root.translation.isZero(0.0);
  if (moved_root) {
    const Eigen::Vector3d& t = pose.root.translation;
    doc["root"] = Json{{"translation_mm", Json::array({t.x(), t.y(), t.z()})},
                       {"rotation", rotation_to_json(Eigen::Quaterniond(pose.root.rotation))}};
  }
  Json joints = Json::object();
  for (const JointRotation& joint : pose.joints) {
    if (joint.angles_deg) {
      const Eigen::Vector3d& a = *joint.angles_deg;
      joints[joint.joint] = Json{{"angles_deg", Json{{"flexion", a.x()}, {"abduction", a.y()}, {"rotation", a.z()}}}};
    } else {
      joints[joint.joint] = rotation_to_json(joint.rotation);
    }
  }
  doc["joints"] = std::move(joints);
  return doc;
}

}  // namespace detail

JointRotation anatomical_rotation(std::string joint, double flexion_deg, double abduction_deg,
                                  double internal_rotation_deg) {
  JointRotation rotation;
  rotation.joint = std::move(joint);
  rotation.angles_deg = Eigen::Vector3d(flexion_deg, abduction_deg, internal_rotation_deg);
  rotation.rotation = rotation_from_angles_deg(flexion_deg, abduction_deg, internal_rotation_deg);
  return rotation;
}

Eigen::Matrix3d joint_rotation_in_lps(const rig::Joint& joint, const JointRotation& rotation) {
  if (rotation.angles_deg) {
    const Eigen::Vector3d& a = *rotation.angles_deg;
    return rig::joint_rotation_from_angles(joint, a.x(), a.y(), a.z());
  }
  return joint.frame * rotation.rotation.normalized().toRotationMatrix() * joint.frame.transpose();
}

Result<Pose> pose_from_json(const std::string& text, const std::string& source) {
  const std::string where = "pose " + source;
  POSEWARP_ASSIGN_OR_RETURN(const Json doc, detail::parse_json(text, where));
  try {
    return detail::pose_from_object(doc, where);
  } catch (const Json::exception& error) {
    return invalid_argument_error(where + " has a field of the wrong type: " + error.what());
  }
}

Result<Pose> read_pose(const std::string& path) {
  POSEWARP_ASSIGN_OR_RETURN(const std::string text, detail::read_text_file(path, "pose"));
  return pose_from_json(text, "'" + path + "'");
}

std::string pose_to_json(const Pose& pose) {
  return detail::pose_to_object(pose).dump(2) + "\n";
}

Status validate_pose(const Pose& pose, const rig::Skeleton& skeleton) {
  const std::string where = "pose \"" + pose.name + "\"";
  std::set<std::string> seen;
  for (const JointRotation& joint : pose.joints) {
    if (skeleton.joint_index(joint.joint) < 0) {
      std::vector<std::string> known;
      std::string closest;
      size_t closest_distance = 3;  // suggest only near misses
      for (const rig::Joint& rig_joint : skeleton.joints) {
        known.push_back(rig_joint.name);
        const size_t d = edit_distance(joint.joint, rig_joint.name);
        if (d < closest_distance) closest_distance = d, closest = rig_joint.name;
      }
      std::string message = where + " names joint \"" + joint.joint + "\", which the rig does not have";
      if (!closest.empty()) message += " (did you mean \"" + closest + "\"?)";
      message += known.empty() ? "; the rig has no joints" : "; the rig's joints are: " + detail::join(known);
      return invalid_argument_error(message);
    }
    if (!seen.insert(joint.joint).second) {
      return invalid_argument_error(where + " gives joint \"" + joint.joint + "\" twice; give each joint one rotation");
    }
    if (joint.angles_deg && !joint.angles_deg->allFinite()) {
      return invalid_argument_error(where + ", joint \"" + joint.joint +
                                    "\": an anatomical angle is NaN or infinite; give finite degrees");
    }
    if (joint.angles_deg) {
      constexpr const char* kNames[3] = {"flexion", "abduction", "rotation"};
      for (int i = 0; i < 3; ++i) {
        if (std::abs((*joint.angles_deg)[i]) > kMaxAngleDeg) {
          return detail::outside_range_error(where + ", joint \"" + joint.joint + "\", \"angles_deg\"", kNames[i],
                                             (*joint.angles_deg)[i], kMaxAngleDeg, "degrees", detail::kAngleHint);
        }
      }
    }
    const Eigen::Quaterniond& q = joint.rotation;
    if (!q.coeffs().allFinite()) {
      return invalid_argument_error(where + ", joint \"" + joint.joint +
                                    "\": the rotation has a NaN or infinite component; give finite numbers");
    }
    if (std::abs(q.norm() - 1.0) > detail::kUnitQuaternionTolerance) {
      return invalid_argument_error(where + ", joint \"" + joint.joint + "\": the quaternion has length " +
                                    std::to_string(q.norm()) + ", not 1; normalize it");
    }
  }
  if (!is_rotation(pose.root.rotation)) {
    return invalid_argument_error(where + ": the root rotation is not a rotation matrix (orthonormal, determinant +1)");
  }
  if (!pose.root.translation.allFinite()) {
    return invalid_argument_error(where + ": the root translation has a NaN or infinite component");
  }
  for (int a = 0; a < 3; ++a) {
    if (std::abs(pose.root.translation[a]) > kMaxRootTranslationMm) {
      return detail::outside_range_error(where + ", root", "translation_mm[" + std::to_string(a) + "]",
                                         pose.root.translation[a], kMaxRootTranslationMm, "mm",
                                         detail::kTranslationHint);
    }
  }
  return ok_status();
}

}  // namespace posewarp::pose
