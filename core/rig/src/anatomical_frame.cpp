// Anatomical joint frames: flexion, abduction and internal rotation with the same meaning on both sides.
#include "posewarp/rig/anatomical_frame.h"

#include <Eigen/Geometry>

#include <cctype>
#include <cmath>

namespace posewarp::rig {
namespace {

using Eigen::Vector3d;

// Patient directions in LPS.
const Vector3d kLeft{1.0, 0.0, 0.0};
const Vector3d kAnterior{0.0, -1.0, 0.0};
const Vector3d kPosterior{0.0, 1.0, 0.0};
const Vector3d kSuperior{0.0, 0.0, 1.0};
const Vector3d kInferior{0.0, 0.0, -1.0};

// Below this length a direction projected across the long axis is too short to define an axis.
constexpr double kMinProjected = 0.3;

Vector3d across(const Vector3d& v, const Vector3d& axis) { return v - v.dot(axis) * axis; }

Vector3d direction_of(labels::FlexionDirection flexion) {
  switch (flexion) {
    case labels::FlexionDirection::kAnterior: return kAnterior;
    case labels::FlexionDirection::kPosterior: return kPosterior;
    case labels::FlexionDirection::kSuperior: return kSuperior;
    case labels::FlexionDirection::kInferior: return kInferior;
  }
  return kAnterior;
}

// True when `word` appears in `name` delimited by non-letters ("hip_left", "left femur").
bool has_word(const std::string& name, const std::string& word) {
  for (size_t at = name.find(word); at != std::string::npos; at = name.find(word, at + 1)) {
    const bool start = at == 0 || !std::isalpha(static_cast<unsigned char>(name[at - 1]));
    const size_t end = at + word.size();
    const bool stop = end == name.size() || !std::isalpha(static_cast<unsigned char>(name[end]));
    if (start && stop) return true;
  }
  return false;
}

}  // namespace

BodySide side_of_joint(const std::string& joint_name, const std::string& child_name, const Vector3d& child_centroid,
                       const Vector3d& root_centroid, double midline_mm) {
  for (const std::string* name : {&joint_name, &child_name}) {
    const bool left = has_word(*name, "left"), right = has_word(*name, "right");
    if (left != right) return left ? BodySide::kLeft : BodySide::kRight;
  }
  const double offset = (child_centroid - root_centroid).dot(kLeft);
  if (offset > midline_mm) return BodySide::kLeft;
  if (offset < -midline_mm) return BodySide::kRight;
  return BodySide::kMidline;
}

AnatomicalFrame anatomical_frame(const Vector3d& long_axis, labels::FlexionDirection flexion, BodySide side,
                                 const Vector3d& hinge_axis) {
  AnatomicalFrame result;
  const Vector3d d = long_axis.normalized();

  // Flexion turns about the mediolateral axis (ISB: the proximal segment's medial-lateral axis), signed so that the
  // far end goes toward `flexion`: a turn about f moves d by f x d. A child that points sideways (a truncated femur
  // whose centroid lies toward the trochanter, a clavicle) says nothing about the sign: a limb hanging down, or a
  // foot pointing forward, is assumed.
  const Vector3d toward = direction_of(flexion);
  Vector3d reference = d;
  if (across(d, kLeft).norm() < 0.5) {
    reference = flexion == labels::FlexionDirection::kSuperior || flexion == labels::FlexionDirection::kInferior
                    ? kAnterior
                    : Vector3d(-kSuperior);
    result.degenerate = true;
    result.note = "the child's long axis points sideways; flexion taken as for a limb hanging down";
  }
  Vector3d x = kLeft.cross(reference).dot(toward) >= 0.0 ? kLeft : Vector3d(-kLeft);
  if (std::abs(kLeft.cross(reference).dot(toward)) < 1e-6 * reference.norm()) {
    // The far end already points the way it flexes (a foot declared "anterior"): the sagittal perpendicular.
    const Vector3d other = flexion == labels::FlexionDirection::kAnterior || flexion == labels::FlexionDirection::kPosterior
                               ? kSuperior
                               : kAnterior;
    x = kLeft.cross(reference).dot(other) >= 0.0 ? kLeft : Vector3d(-kLeft);
    result.degenerate = true;
    result.note = "the child's long axis points the way it flexes; flexion taken in the sagittal plane";
  }
  if (hinge_axis.norm() > 0.5) x = hinge_axis.normalized() * (hinge_axis.dot(x) >= 0.0 ? 1.0 : -1.0);
  x.normalize();
  Vector3d z = across(reference, x);
  if (z.norm() < kMinProjected) {
    // A hinge axis along the bone: keep the flexion axis and any perpendicular long axis.
    z = across(kSuperior, x).norm() > kMinProjected ? across(kSuperior, x) : across(kAnterior, x);
    result.degenerate = true;
    result.note = "the hinge axis lies along the child bone";
  }
  z.normalize();
  Vector3d y = z.cross(x);

  // Abduction: a turn about a moves the far end laterally (for midline joints: toward the patient's left).
  const Vector3d lateral = side == BodySide::kRight ? Vector3d(-kLeft) : kLeft;
  const Vector3d l = across(lateral, z);
  if (l.norm() >= kMinProjected) {
    if (y.dot(z.cross(l.normalized())) < 0.0) {
      y = -y;
      z = -z;  // keeps the frame a rotation: x cross (-y) = -z
    }
  } else if (!result.degenerate) {
    result.degenerate = true;
    result.note = "the child's long axis is mediolateral; the abduction sense is a guess";
  }

  // Internal rotation: a turn about +-z carries the child's front toward the midline (midline joints: to the left).
  Vector3d front = across(kAnterior, z);
  if (front.norm() < kMinProjected) front = across(kSuperior, z);
  const Vector3d medial = side == BodySide::kMidline ? kLeft : Vector3d(-lateral);
  const double turn = z.cross(front.normalized()).dot(medial);
  result.internal_rotation_sign = turn >= 0.0 ? 1 : -1;
  if (std::abs(turn) < 0.1 && !result.degenerate) {
    result.degenerate = true;
    result.note = "the child's long axis is mediolateral; the internal rotation sense is a guess";
  }
  result.frame.col(0) = x;
  result.frame.col(1) = y;
  result.frame.col(2) = z;
  return result;
}

Eigen::Matrix3d joint_rotation_from_angles(const Joint& joint, double flexion_deg, double abduction_deg,
                                           double internal_rotation_deg) {
  constexpr double kRadians = M_PI / 180.0;
  const Eigen::Matrix3d local =
      (Eigen::AngleAxisd(flexion_deg * kRadians, Vector3d::UnitX()) *
       Eigen::AngleAxisd(abduction_deg * kRadians, Vector3d::UnitY()) *
       Eigen::AngleAxisd(joint.internal_rotation_sign * internal_rotation_deg * kRadians, Vector3d::UnitZ()))
          .toRotationMatrix();
  return joint.frame * local * joint.frame.transpose();
}

}  // namespace posewarp::rig
