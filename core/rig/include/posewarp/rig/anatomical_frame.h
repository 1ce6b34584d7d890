// Anatomical joint frames from the patient's axes (LPS) and the child bone: which way flexion, abduction and
// internal rotation turn, the same on both sides (after the ISB joint coordinate systems: Grood and Suntay 1983 for
// the knee; Wu et al. 2002 for hip, ankle and spine; Wu et al. 2005 for shoulder, elbow and wrist).
#pragma once

#include <Eigen/Core>

#include <string>

#include "posewarp/labels/label_map.h"
#include "posewarp/rig/skeleton.h"

namespace posewarp::rig {

struct AnatomicalFrame {
  Eigen::Matrix3d frame = Eigen::Matrix3d::Identity();  // a rotation; columns x (flexion), y (abduction), z
  int internal_rotation_sign = 1;                        // internal rotation is positive about sign * z
  bool degenerate = false;                               // an axis had to be guessed (see the note)
  std::string note;
};

// `long_axis`: unit, from the joint centre into the child (the child's principal axis, LPS). `hinge_axis`: a fitted
// hinge axis (unit) or zero. The flexion axis is the hinge axis where there is one, else the mediolateral direction
// across the child; its sign makes a positive turn move the child's far end toward `flexion`.
AnatomicalFrame anatomical_frame(const Eigen::Vector3d& long_axis, labels::FlexionDirection flexion, BodySide side,
                                 const Eigen::Vector3d& hinge_axis);

// The side a joint is on: "left"/"right" in the joint's or the child's name, else where the child's centroid lies
// against the root's along the patient's left-right axis (more than `midline_mm` off: that side).
BodySide side_of_joint(const std::string& joint_name, const std::string& child_name, const Eigen::Vector3d& child_centroid,
                       const Eigen::Vector3d& root_centroid, double midline_mm = 40.0);

// The rotation (LPS, about the joint centre) that anatomical angles in degrees give at this joint: flexion about the
// frame's x, then abduction about y, then internal rotation about sign * z (intrinsic, flexion first).
Eigen::Matrix3d joint_rotation_from_angles(const Joint& joint, double flexion_deg, double abduction_deg,
                                           double internal_rotation_deg);

}  // namespace posewarp::rig
