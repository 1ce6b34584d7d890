// Pose: one rotation per joint, each in the joint's own frame, plus a root transform; its JSON form and validation
// against a skeleton (Sujar et al. 2018 section 3.5: the skeleton is posed, the tet mesh follows by skinning).
#pragma once

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <optional>
#include <string>
#include <vector>

#include "posewarp/common/pose.h"
#include "posewarp/common/result.h"
#include "posewarp/pose/rigid_transform.h"
#include "posewarp/rig/skeleton.h"

namespace posewarp::pose {

// A pose as data (posewarp/common/pose.h), under the names the stage has always used.
using posewarp::JointRotation;
using posewarp::Pose;

// The ranges every way into a pose checks (pose JSON, animation JSON, BVH, validate_pose for poses built in C++),
// with the same message. An angle beyond a full turn either way is a mistake, never a rotation (1e308 degrees is
// finite, but its rotation is arbitrary); a body is about 2 m long, so moving it further is not a re-pose (it only
// grows the output grid).
inline constexpr double kMaxAngleDeg = 360.0;
inline constexpr double kMaxRootTranslationMm = 2000.0;

// A joint rotation given by anatomical angles in degrees.
JointRotation anatomical_rotation(std::string joint, double flexion_deg, double abduction_deg = 0.0,
                                  double internal_rotation_deg = 0.0);

// The rotation in LPS (about the joint centre) that `rotation` gives at `joint`.
Eigen::Matrix3d joint_rotation_in_lps(const rig::Joint& joint, const JointRotation& rotation);

// Pose JSON, version 1 (every field but "joints" optional; unknown fields are errors, so are duplicate keys):
//   {"format": "posewarp.pose", "version": 1, "name": "knee bent",
//    "root": {"translation_mm": [0, 0, 0], "rotation": {"axis_angle": {"axis": [0, 0, 1], "degrees": 30}}},
//    "joints": {
//      "knee_left":  {"angles_deg": {"flexion": 90, "abduction": 0, "rotation": 0}},
//      "hip_right":  {"axis_angle": {"axis": [1, 0, 0], "degrees": -20}},
//      "elbow_left": {"quaternion": [1, 0, 0, 0]}}}
// A rotation is given exactly one of three ways:
//   "quaternion": [w, x, y, z]   unit within 1e-3 (an error otherwise, never normalized silently);
//   "axis_angle": {"axis": [x, y, z], "degrees": d}   axis non-zero, any length; right-hand rule;
//   "angles_deg": {"flexion": a, "abduction": b, "rotation": c}   each optional (default 0), anatomical: positive
//       flexion is flexion (hip and shoulder forward, knee bending the heel back, elbow bringing the hand forward and
//       up, ankle dorsiflexion, spine and neck bending forward), positive abduction moves the child away from the
//       midline (midline joints: bends toward the patient's left), positive rotation is internal rotation (midline
//       joints: turns toward the patient's left), the same on both sides. Intrinsic, flexion first:
//       R = Rx(a) * Ry(b) * Rz(s c), s the joint's internal rotation sign (rig::Joint::internal_rotation_sign).
//       The root rotation takes no angles_deg.
// Joint rotations are in the joint's frame (see JointRotation). The root rotation uses the same forms in LPS axes
// (x patient left, y posterior, z superior) and turns about the root segment's centroid; "translation_mm" is in
// LPS mm. Numbers must be finite; JSON has no NaN or Infinity. Every angle ("degrees", each of "angles_deg") lies
// within [-kMaxAngleDeg, kMaxAngleDeg], every component of "translation_mm" within [-kMaxRootTranslationMm,
// kMaxRootTranslationMm]; INVALID_ARGUMENT otherwise, e.g.
//   pose 'x.json', joint "knee_left", "angles_deg": "flexion" = 1e+308 is outside [-360, 360] degrees; ...
Result<Pose> pose_from_json(const std::string& text, const std::string& source);
// NOT_FOUND when the file cannot be opened; otherwise as pose_from_json.
Result<Pose> read_pose(const std::string& path);
// Writes every rotation as a quaternion [w, x, y, z]; pose_from_json reads it back.
std::string pose_to_json(const Pose& pose);

// INVALID_ARGUMENT for a joint the skeleton lacks (the message lists the rig's joints), a joint given twice, a
// quaternion that is not unit within 1e-3 or not finite, anatomical angles (angles_deg) outside [-kMaxAngleDeg,
// kMaxAngleDeg], a root rotation that is not a rotation, a root translation component that is not finite or
// outside [-kMaxRootTranslationMm, kMaxRootTranslationMm].
Status validate_pose(const Pose& pose, const rig::Skeleton& skeleton);

// R = Rx(flexion) * Ry(abduction) * Rz(rotation), angles in degrees, in a frame (no anatomical signs).
Eigen::Quaterniond rotation_from_angles_deg(double flexion, double abduction, double rotation);

}  // namespace posewarp::pose
