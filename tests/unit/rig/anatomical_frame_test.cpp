#include "posewarp/rig/anatomical_frame.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <tuple>

#include "posewarp/phantom/phantom.h"
#include "posewarp/rig/skeleton.h"

namespace posewarp::rig {
namespace {

using Eigen::Vector3d;
using labels::FlexionDirection;

// LPS: x patient left, y posterior, z superior.
const Vector3d kLeft{1, 0, 0}, kAnterior{0, -1, 0}, kSuperior{0, 0, 1};

Joint joint_with(const Vector3d& long_axis, FlexionDirection flexion, BodySide side,
                 const Vector3d& hinge = Vector3d::Zero()) {
  const AnatomicalFrame frame = anatomical_frame(long_axis, flexion, side, hinge);
  Joint joint;
  joint.frame = frame.frame;
  joint.internal_rotation_sign = frame.internal_rotation_sign;
  return joint;
}

// Where a point of the child goes when the joint turns by the given angles about the origin.
Vector3d moved(const Joint& joint, const Vector3d& p, double flexion, double abduction, double internal) {
  return joint_rotation_from_angles(joint, flexion, abduction, internal) * p - p;
}

struct Case {
  const char* name;
  Vector3d long_axis;
  FlexionDirection flexion;
  Vector3d flexion_motion;  // where flexion moves the far end
};

TEST(AnatomicalFrame, EveryAngleMeansTheSameMotionOnBothSides) {
  const std::vector<Case> cases{
      {"hip", -kSuperior, FlexionDirection::kAnterior, kAnterior},
      {"knee", -kSuperior, FlexionDirection::kPosterior, -kAnterior},
      {"shoulder", -kSuperior, FlexionDirection::kAnterior, kAnterior},
      {"elbow", -kSuperior, FlexionDirection::kAnterior, kAnterior},
      {"ankle", kAnterior, FlexionDirection::kSuperior, kSuperior},
      {"wrist", Vector3d(0.1, 0.0, -1.0).normalized(), FlexionDirection::kAnterior, kAnterior},
  };
  for (const Case& c : cases) {
    for (const BodySide side : {BodySide::kLeft, BodySide::kRight}) {
      SCOPED_TRACE(std::string(c.name) + " " + std::string(body_side_name(side)));
      const Joint joint = joint_with(c.long_axis, c.flexion, side);
      EXPECT_NEAR(joint.frame.determinant(), 1.0, 1e-12);
      const Vector3d far_end = 300.0 * c.long_axis;
      const Vector3d lateral = side == BodySide::kLeft ? kLeft : Vector3d(-kLeft);
      // Flexion: the far end goes the anatomical way.
      EXPECT_GT(moved(joint, far_end, 30, 0, 0).normalized().dot(c.flexion_motion), 0.95);
      // Abduction: away from the midline.
      EXPECT_GT(moved(joint, far_end, 0, 30, 0).normalized().dot(lateral), 0.9);
      // Internal rotation: the front of the child turns toward the midline.
      const Vector3d front = far_end + 30.0 * (c.long_axis.dot(kAnterior) > 0.9 ? kSuperior : kAnterior);
      const Vector3d turn = moved(joint, front, 0, 0, 20);
      EXPECT_GT(turn.dot(-lateral), 0.5 * turn.norm());  // z is the long axis across the mediolateral axis
    }
  }
}

TEST(AnatomicalFrame, MidlineJointsFlexForwardAndBendAndTurnToTheLeft) {
  for (const Vector3d& up : {Vector3d(kSuperior), Vector3d(0.0, 0.3, 1.0).normalized()}) {
    const Joint joint = joint_with(up, FlexionDirection::kAnterior, BodySide::kMidline);
    const Vector3d top = 200.0 * up;
    EXPECT_GT(moved(joint, top, 20, 0, 0).normalized().dot(kAnterior), 0.9);
    EXPECT_GT(moved(joint, top, 0, 20, 0).normalized().dot(kLeft), 0.95);
    const Vector3d front = top + 30.0 * kAnterior;
    EXPECT_GT(moved(joint, front, 0, 0, 20).dot(kLeft), 0.0);
  }
}

TEST(AnatomicalFrame, AFittedHingeAxisIsTheFlexionAxis) {
  const Vector3d hinge = Vector3d(1.0, 0.15, -0.05).normalized();  // a knee axis turned a little
  for (const BodySide side : {BodySide::kLeft, BodySide::kRight}) {
    const Joint joint = joint_with(-kSuperior, FlexionDirection::kPosterior, side, hinge);
    EXPECT_NEAR(std::abs(joint.frame.col(0).dot(hinge)), 1.0, 1e-12);
    EXPECT_GT(moved(joint, -300.0 * kSuperior, 30, 0, 0).dot(-kAnterior), 0.0);
  }
}

TEST(AnatomicalFrame, SideComesFromNamesThenFromPosition) {
  const Vector3d root(0, 0, 900);
  EXPECT_EQ(side_of_joint("hip_left", "femur_left", Vector3d(-90, 0, 700), root), BodySide::kLeft);
  EXPECT_EQ(side_of_joint("j", "humerus_right", Vector3d(200, 0, 700), root), BodySide::kRight);
  EXPECT_EQ(side_of_joint("j", "leftover", Vector3d(200, 0, 700), root), BodySide::kLeft);  // not the word "left"
  EXPECT_EQ(side_of_joint("j", "b", Vector3d(-200, 0, 700), root), BodySide::kRight);
  EXPECT_EQ(side_of_joint("j", "b", Vector3d(10, 0, 700), root), BodySide::kMidline);
}

// On a rig of the mannequin: every anatomical angle moves each limb the expected way, on both sides.
TEST(AnatomicalFrame, MannequinLimbsMoveTheAnatomicalWayOnBothSides) {
  phantom::MannequinParams params;
  params.spacing_mm = 4.0;
  const double a = 0.3;  // an oblique grid: the frames come from the patient's axes, not the grid's
  params.direction = {std::cos(a), 0, std::sin(a), 0, 1, 0, -std::sin(a), 0, std::cos(a)};
  Result<phantom::Phantom> m = phantom::make_mannequin(params);
  ASSERT_TRUE(m.ok());
  Result<Skeleton> skeleton = build_skeleton(m->labels, m->label_map, {}, {}, {});
  ASSERT_TRUE(skeleton.ok()) << skeleton.status().to_string();
  const std::vector<std::pair<std::string, Vector3d>> flexion_moves{
      {"hip", kAnterior}, {"knee", -kAnterior}, {"shoulder", kAnterior}, {"elbow", kAnterior}};
  for (const auto& [kind, expected] : flexion_moves) {
    for (const std::string side : {"left", "right"}) {
      const std::string name = kind + "_" + side;
      SCOPED_TRACE(name);
      const int j = skeleton->joint_index(name);
      ASSERT_GE(j, 0);
      const Joint& joint = skeleton->joints[static_cast<size_t>(j)];
      EXPECT_EQ(body_side_name(joint.side), side);
      const Vector3d far_end = skeleton->segments[static_cast<size_t>(joint.child)].centroid_mm - joint.centre_mm;
      const Vector3d lateral = side == "left" ? kLeft : Vector3d(-kLeft);
      EXPECT_GT(moved(joint, far_end, 45, 0, 0).normalized().dot(expected), 0.9);
      EXPECT_GT(moved(joint, far_end, 0, 45, 0).normalized().dot(lateral), 0.9);
      const Vector3d turn = moved(joint, far_end + 20.0 * kAnterior, 0, 0, 30);
      EXPECT_GT(turn.dot(-lateral), 0.9 * turn.norm());
    }
  }
  for (const char* name : {"L4_L5", "thoracolumbar", "neck"}) {
    SCOPED_TRACE(name);
    const Joint& joint = skeleton->joints[static_cast<size_t>(skeleton->joint_index(name))];
    EXPECT_EQ(joint.side, BodySide::kMidline);
    const Vector3d up = skeleton->segments[static_cast<size_t>(joint.child)].centroid_mm - joint.centre_mm;
    EXPECT_GT(moved(joint, up, 20, 0, 0).normalized().dot(kAnterior), 0.9);
    EXPECT_GT(moved(joint, up, 0, 20, 0).normalized().dot(kLeft), 0.9);
  }
}

}  // namespace
}  // namespace posewarp::rig

namespace posewarp::rig {
namespace {

// On the anatomical body phantom (oblique grid, 8 mm slices): knee, elbow, hip, shoulder and ankle on both sides.
TEST(AnatomicalFrame, BodyPhantomLimbsMoveTheAnatomicalWayOnBothSides) {
  phantom::BodyParams params;
  params.spacing_mm = {4.0, 4.0, 8.0};
  Result<phantom::Phantom> body = phantom::make_body(params);
  ASSERT_TRUE(body.ok());
  Result<Skeleton> skeleton = build_skeleton(body->labels, body->label_map, {}, {}, {});
  ASSERT_TRUE(skeleton.ok()) << skeleton.status().to_string();
  const Eigen::Vector3d left(1, 0, 0), anterior(0, -1, 0), superior(0, 0, 1);
  // Where flexion takes a point of the child 150 mm from the joint along the way the limb lies at rest.
  const std::vector<std::tuple<std::string, Eigen::Vector3d, Eigen::Vector3d>> cases{
      {"hip", -superior, anterior}, {"knee", -superior, -anterior}, {"shoulder", -superior, anterior},
      {"elbow", -superior, anterior}, {"ankle", anterior, superior}};
  for (const auto& [kind, lies, flexes] : cases) {
    for (const std::string side : {"left", "right"}) {
      const std::string name = kind + "_" + side;
      SCOPED_TRACE(name);
      const int j = skeleton->joint_index(name);
      ASSERT_GE(j, 0);
      const Joint& joint = skeleton->joints[static_cast<size_t>(j)];
      const Eigen::Vector3d far_end = 150.0 * lies;
      const Eigen::Vector3d lateral = side == "left" ? left : Eigen::Vector3d(-left);
      EXPECT_GT(moved(joint, far_end, 30, 0, 0).normalized().dot(flexes), 0.9);
      if (kind != "ankle") {
        EXPECT_GT(moved(joint, far_end, 0, 30, 0).normalized().dot(lateral), 0.9);
        const Eigen::Vector3d turn = moved(joint, far_end + 20.0 * anterior, 0, 0, 30);
        EXPECT_GT(turn.dot(-lateral), 0.5 * turn.norm());
      }
    }
  }
}

}  // namespace
}  // namespace posewarp::rig
