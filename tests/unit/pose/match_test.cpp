// Posture matching on a hand-built chain (tests/unit/pose/chain_skeleton.h): three bones with a knob each (so that
// no turn about a long axis looks the same), posed with a known root motion and known angles at a ball joint and a
// hinge, drawn onto a grid by the posed transforms; the match finds the angles and the root motion back.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>

#include "chain_skeleton.h"
#include "posewarp/pose/forward_kinematics.h"
#include "posewarp/pose/match.h"
#include "posewarp/rig/anatomical_frame.h"

namespace posewarp::pose {
namespace {

using Eigen::Vector3d;

// The rest labels: segment s (label s + 1) a 24 x 16 mm bar from z = 100 s + 12 to 100 s + 88 with a 10 mm knob on its
// +x side and another on its +y side at different heights; 2 mm voxels. `hanging`: the same turned half a turn about
// LPS x (hanging_chain's bones, pointing down as limbs do).
LabelVolume rest_bones(bool hanging = false) {
  ImageGeometry g;
  g.size = {110, 110, 170};
  g.spacing = {2.0, 2.0, 2.0};
  g.origin = {-110.0, -110.0, hanging ? -318.0 : -20.0};
  LabelVolume v(g, 0);
  for (int64_t k = 0; k < g.size[2]; ++k) {
    for (int64_t j = 0; j < g.size[1]; ++j) {
      for (int64_t i = 0; i < g.size[0]; ++i) {
        Vec3 p = g.index_to_physical({static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)});
        if (hanging) p = {p[0], -p[1], -p[2]};
        for (int s = 0; s < 3; ++s) {
          const double z = p[2] - 100.0 * s;
          const bool bar = std::abs(p[0]) <= 12 && std::abs(p[1]) <= 8 && z >= 12 && z <= 88;
          const bool knob_x = p[0] > 12 && p[0] <= 22 && std::abs(p[1]) <= 5 && z >= 60 && z <= 75;
          const bool knob_y = p[1] > 8 && p[1] <= 18 && std::abs(p[0]) <= 5 && z >= 25 && z <= 35;
          if (bar || knob_x || knob_y) v.at(i, j, k) = s + 1;
        }
      }
    }
  }
  return v;
}

// `rest` posed by `transforms` (one per segment) onto the same grid: each voxel the segment whose rest voxel it
// comes from.
LabelVolume drawn(const LabelVolume& rest, const std::vector<RigidTransform>& transforms) {
  const ImageGeometry& g = rest.geometry();
  LabelVolume out(g, 0);
  for (int64_t k = 0; k < g.size[2]; ++k) {
    for (int64_t j = 0; j < g.size[1]; ++j) {
      for (int64_t i = 0; i < g.size[0]; ++i) {
        const Vec3 x = g.index_to_physical({static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)});
        for (size_t s = 0; s < transforms.size(); ++s) {
          const Vector3d back = transforms[s].inverse().apply(Vector3d(x[0], x[1], x[2]));
          const Vec3 at = g.physical_to_index({back.x(), back.y(), back.z()});
          const int64_t ri = std::lround(at[0]), rj = std::lround(at[1]), rk = std::lround(at[2]);
          if (ri < 0 || rj < 0 || rk < 0 || ri >= g.size[0] || rj >= g.size[1] || rk >= g.size[2]) continue;
          if (rest.at(ri, rj, rk) == static_cast<Label>(s + 1)) out.at(i, j, k) = static_cast<Label>(s + 1);
        }
      }
    }
  }
  return out;
}

rig::Skeleton labelled_chain() {
  rig::Skeleton skeleton = testing::chain_skeleton();
  for (size_t s = 0; s < 3; ++s) skeleton.segments[s].labels = {static_cast<Label>(s + 1)};
  skeleton.joints[1].kind = JointKind::kHinge;  // "upper" turns about its x axis (LPS y) only
  return skeleton;
}

// labelled_chain turned half a turn about LPS x, hanging down from its root as an arm does: a shoulder (ball) and an
// elbow (hinge), whose names give them anatomical ranges.
rig::Skeleton hanging_chain() {
  rig::Skeleton skeleton = labelled_chain();
  const Eigen::Matrix3d half = Eigen::AngleAxisd(M_PI, Vector3d::UnitX()).toRotationMatrix();
  for (rig::Segment& s : skeleton.segments) s.centroid_mm = half * s.centroid_mm;
  for (rig::Joint& j : skeleton.joints) j.centre_mm = half * j.centre_mm, j.frame = half * j.frame;
  skeleton.joints[0].name = "shoulder_left";
  skeleton.joints[1].name = "elbow_left";
  return skeleton;
}

// An elbow bent backwards 40 degrees (past anatomy's 10) is held at 10 and the hold is named; asked to go beyond
// anatomy, the match finds the 40. The shoulder, within its range, is found either way.
TEST(MatchPosture, KeepsALimbJointWithinItsAnatomicalRangeUnlessAsked) {
  const rig::Skeleton skeleton = hanging_chain();
  const LabelVolume rest = rest_bones(true);
  Pose truth;
  truth.joints = {anatomical_rotation("shoulder_left", 30.0, 20.0, 0.0), anatomical_rotation("elbow_left", -40.0)};
  Result<std::vector<RigidTransform>> transforms = forward_kinematics(skeleton, truth);
  ASSERT_TRUE(transforms.ok()) << transforms.status().to_string();
  const LabelVolume target = drawn(rest, *transforms);
  for (const bool ranges : {true, false}) {
    MatchOptions options;
    options.anatomical_ranges = ranges;
    Result<MatchResult> match = match_posture(skeleton, rest, target, {{1}, {2}, {3}}, options);
    ASSERT_TRUE(match.ok()) << match.status().to_string();
    ASSERT_EQ(match->pose.joints.size(), 2u);
    const Vector3d shoulder = *match->pose.joints[0].angles_deg, elbow = *match->pose.joints[1].angles_deg;
    EXPECT_NEAR(shoulder.x(), 30.0, 2.0);
    EXPECT_NEAR(shoulder.y(), 20.0, 2.0);
    EXPECT_TRUE(match->segments[1].held_at_range.empty()) << match->segments[1].held_at_range;
    if (ranges) {
      EXPECT_NEAR(elbow.x(), -10.0, 1e-6);
      EXPECT_NE(match->segments[2].held_at_range.find("flexion -"), std::string::npos);
      EXPECT_NE(match->segments[2].held_at_range.find("held at -10.0"), std::string::npos)
          << match->segments[2].held_at_range;
      EXPECT_LT(match->segments[2].dice, 0.9);  // the target's forearm is where anatomy does not reach
    } else {
      EXPECT_NEAR(elbow.x(), -40.0, 2.0);
      EXPECT_TRUE(match->segments[2].held_at_range.empty());
      EXPECT_GT(match->segments[2].dice, 0.9);
    }
  }
  EXPECT_FALSE(anatomical_range("patellofemoral_left").has_value());
  ASSERT_TRUE(anatomical_range("knee_right").has_value());
  EXPECT_EQ(anatomical_range("knee_right")->max_deg.x(), 150.0);
}

TEST(MatchPosture, FindsTheRootMotionAndTheJointAnglesOfAPoseBack) {
  rig::Skeleton skeleton = labelled_chain();
  // "lower" measured on its study to flex 10 back and 20 forward before its bones meet: the 35 found is past it.
  skeleton.joints[0].ranges = {{"flexion", 10.0, 20.0, true, true}, {"abduction", 30.0, 30.0, false, false}};
  const LabelVolume rest = rest_bones();
  Pose truth;
  truth.root.rotation =
      Eigen::AngleAxisd(12.0 * M_PI / 180.0, Vector3d(0.3, -0.5, 1.0).normalized()).toRotationMatrix();
  truth.root.translation = Vector3d(6.0, -8.0, 5.0);
  truth.joints = {anatomical_rotation("lower", 35.0, -20.0, 15.0), anatomical_rotation("upper", 50.0)};
  Result<std::vector<RigidTransform>> transforms = forward_kinematics(skeleton, truth);
  ASSERT_TRUE(transforms.ok()) << transforms.status().to_string();
  const LabelVolume target = drawn(rest, *transforms);

  Result<MatchResult> match = match_posture(skeleton, rest, target, {{1}, {2}, {3}});
  ASSERT_TRUE(match.ok()) << match.status().to_string();
  const Eigen::AngleAxisd root_error(match->pose.root.rotation * truth.root.rotation.transpose());
  EXPECT_LT(root_error.angle() * 180.0 / M_PI, 1.0);
  EXPECT_LT((match->pose.root.translation - truth.root.translation).norm(), 2.0);  // a voxel
  ASSERT_EQ(match->pose.joints.size(), 2u);
  const Vector3d lower = *match->pose.joints[0].angles_deg, upper = *match->pose.joints[1].angles_deg;
  EXPECT_NEAR(lower.x(), 35.0, 2.0);
  EXPECT_NEAR(lower.y(), -20.0, 2.0);
  EXPECT_NEAR(lower.z(), 15.0, 2.0);
  EXPECT_NEAR(upper.x(), 50.0, 2.0);
  EXPECT_NEAR(upper.y(), 0.0, 1.0);  // a hinge, within its slack
  EXPECT_NE(match->segments[1].beyond_range.find("flexion 35."), std::string::npos) << match->segments[1].beyond_range;
  EXPECT_NE(match->segments[1].beyond_range.find("past 20 (bones meet)"), std::string::npos);
  EXPECT_EQ(match->segments[1].beyond_range.find("abduction"), std::string::npos);  // -20 lies within 30 either way
  EXPECT_TRUE(match->segments[2].beyond_range.empty());  // "upper" has no measured range
  EXPECT_NEAR(upper.z(), 0.0, 1.0);
  for (const SegmentMatch& s : match->segments) {
    std::printf("%-7s angles %7.2f %7.2f %7.2f  mean %.2f mm  max %.2f mm  Dice %.3f  %d iterations\n",
                s.segment.c_str(), s.angles_deg.x(), s.angles_deg.y(), s.angles_deg.z(), s.mean_distance_mm,
                s.max_distance_mm, s.dice, s.iterations);
    EXPECT_TRUE(s.matched) << s.segment;
    EXPECT_GT(s.dice, 0.9) << s.segment;
    EXPECT_LT(s.mean_distance_mm, 1.5) << s.segment;  // three quarters of a voxel: a turned bone is redrawn in voxels
  }
  // Posed by what the match found, every bone lands where the target has it.
  Result<std::vector<RigidTransform>> found = forward_kinematics(skeleton, match->pose);
  ASSERT_TRUE(found.ok());
  for (size_t s = 0; s < 3; ++s) {
    const Vector3d tip(0.0, 0.0, 100.0 * static_cast<double>(s) + 88.0);
    EXPECT_LT(((*found)[s].apply(tip) - (*transforms)[s].apply(tip)).norm(), 2.0) << skeleton.segments[s].name;
  }
}

TEST(MatchPosture, ABoneMissingFromTheTargetIsSkippedAndNamedAndAMissingRootRefused) {
  const rig::Skeleton skeleton = labelled_chain();
  const LabelVolume rest = rest_bones();
  Result<MatchResult> match = match_posture(skeleton, rest, rest, {{1}, {2}, {}});
  ASSERT_TRUE(match.ok()) << match.status().to_string();
  EXPECT_FALSE(match->segments[2].matched);
  EXPECT_NE(match->segments[2].skipped.find("target's labels have no voxels"), std::string::npos);
  ASSERT_EQ(match->pose.joints.size(), 1u);
  EXPECT_LT(match->pose.joints[0].angles_deg->norm(), 0.5);  // the same scan: at rest
  Result<MatchResult> rootless = match_posture(skeleton, rest, rest, {{7}, {2}, {3}});
  ASSERT_FALSE(rootless.ok());
  EXPECT_NE(rootless.status().message().find("root segment 'base' is missing from the target's"), std::string::npos)
      << rootless.status().message();
  EXPECT_FALSE(match_posture(skeleton, rest, rest, {{1}, {2}}).ok());
}

TEST(MatchPosture, AnatomicalAnglesInvertTheJointRotation) {
  const rig::Skeleton skeleton = labelled_chain();
  rig::Joint joint = skeleton.joints[1];
  for (int sign : {1, -1}) {
    joint.internal_rotation_sign = sign;
    const Eigen::Vector3d angles = anatomical_angles_deg(joint, rig::joint_rotation_from_angles(joint, -30, 25, 70));
    EXPECT_NEAR(angles.x(), -30, 1e-9);
    EXPECT_NEAR(angles.y(), 25, 1e-9);
    EXPECT_NEAR(angles.z(), 70, 1e-9);
  }
}

// A joint frame whose long axis (z) runs from the joint into its child's centroid, x along LPS x (mediolateral).
Eigen::Matrix3d frame_along(const Vector3d& from_centre_to_child) {
  Eigen::Matrix3d frame;
  frame.col(2) = from_centre_to_child.normalized();
  frame.col(1) = frame.col(2).cross(Vector3d::UnitX()).normalized();
  frame.col(0) = frame.col(1).cross(frame.col(2));
  return frame;
}

// A leg bent forward (thigh 30 degrees, shin 70 degrees from straight down, in the sagittal plane) comes out straight:
// the thigh through its ball joint, the shin through its hinge; a skeleton without limbs and an unknown posture are
// refused.
TEST(StandardPosture, LimbsStraightTurnsABentLegStraightDown) {
  rig::Skeleton skeleton;
  const auto tilted = [](double degrees, double length) {
    const double r = degrees * M_PI / 180.0;
    return Vector3d(0.0, -length * std::sin(r), -length * std::cos(r));  // forward is LPS -y
  };
  const Vector3d hip(100.0, 0.0, -50.0), knee = hip + tilted(30.0, 400.0);
  for (const char* name : {"pelvis", "femur_left", "tibia_left"}) {
    rig::Segment segment;
    segment.name = name;
    skeleton.segments.push_back(segment);
  }
  skeleton.segments[1].centroid_mm = hip + tilted(30.0, 200.0);
  skeleton.segments[2].centroid_mm = knee + tilted(70.0, 180.0);
  rig::Joint hip_joint;
  hip_joint.name = "hip_left";
  hip_joint.parent = 0, hip_joint.child = 1, hip_joint.centre_mm = hip;
  hip_joint.kind = JointKind::kBall;
  hip_joint.frame = frame_along(skeleton.segments[1].centroid_mm - hip);
  rig::Joint knee_joint;
  knee_joint.name = "knee_left";
  knee_joint.parent = 1, knee_joint.child = 2, knee_joint.centre_mm = knee;
  knee_joint.kind = JointKind::kHinge;  // its flexion axis: the frame's x, LPS x (mediolateral)
  knee_joint.frame = frame_along(skeleton.segments[2].centroid_mm - knee);
  skeleton.joints = {hip_joint, knee_joint};
  Result<Pose> pose = standard_posture(skeleton, "limbs-straight");
  ASSERT_TRUE(pose.ok()) << pose.status().to_string();
  ASSERT_EQ(pose->joints.size(), 2u);
  Result<std::vector<RigidTransform>> t = forward_kinematics(skeleton, *pose);
  ASSERT_TRUE(t.ok()) << t.status().to_string();
  const Vector3d knee_now = (*t)[1].apply(knee);
  const Vector3d thigh = ((*t)[1].apply(skeleton.segments[1].centroid_mm) - hip).normalized();
  const Vector3d shin = ((*t)[2].apply(skeleton.segments[2].centroid_mm) - knee_now).normalized();
  EXPECT_NEAR(thigh.z(), -1.0, 1e-9) << thigh.transpose();
  EXPECT_NEAR(shin.z(), -1.0, 1e-9) << shin.transpose();
  EXPECT_NEAR(std::abs(pose->joints[1].angles_deg->x()), 40.0, 1e-6);  // the shin's bend beyond the thigh's
  EXPECT_FALSE(standard_posture(skeleton, "t-pose").ok());
  Result<Pose> same = standard_posture(skeleton, "supine-arms-down");
  ASSERT_TRUE(same.ok());
  EXPECT_NEAR(*same->joints[1].angles_deg->data(), *pose->joints[1].angles_deg->data(), 1e-12);
  rig::Skeleton spine = testing::chain_skeleton();
  Result<Pose> nothing = standard_posture(spine, "limbs-straight");
  ASSERT_FALSE(nothing.ok());
  EXPECT_NE(nothing.status().message().find("no shoulder, elbow, hip or knee"), std::string::npos);
}

// An arm hanging at the side (a ball shoulder, a hinge elbow bent 30 degrees forward) raised straight over the head
// through the side: the turn is about the front-to-back axis, read as abduction 180 (not flexion 180 and rotation 180);
// the legs' posture is not asked for, so a skeleton without them is fine.
TEST(StandardPosture, ArmsUpRaisesAnArmOverTheHeadThroughTheSide) {
  rig::Skeleton skeleton;
  for (const char* name : {"thorax", "humerus_left", "forearm_left"}) {
    rig::Segment segment;
    segment.name = name;
    skeleton.segments.push_back(segment);
  }
  const Vector3d shoulder(180.0, 0.0, 0.0), elbow(180.0, 0.0, -300.0);
  skeleton.segments[0].centroid_mm = Vector3d(0.0, 0.0, -200.0);
  skeleton.segments[1].centroid_mm = Vector3d(180.0, 0.0, -150.0);
  skeleton.segments[2].centroid_mm = elbow + Vector3d(0.0, -120.0 * std::sin(M_PI / 6), -120.0 * std::cos(M_PI / 6));
  skeleton.root = 0;
  rig::Joint s;
  s.name = "shoulder_left", s.parent = 0, s.child = 1, s.centre_mm = shoulder, s.kind = JointKind::kBall;
  s.frame = frame_along(skeleton.segments[1].centroid_mm - shoulder);
  rig::Joint e;
  e.name = "elbow_left", e.parent = 1, e.child = 2, e.centre_mm = elbow, e.kind = JointKind::kHinge;
  e.frame = frame_along(skeleton.segments[2].centroid_mm - elbow);
  skeleton.joints = {s, e};
  Result<Pose> pose = standard_posture(skeleton, "arms-up");
  ASSERT_TRUE(pose.ok()) << pose.status().to_string();
  ASSERT_EQ(pose->joints.size(), 2u);
  Result<std::vector<RigidTransform>> t = forward_kinematics(skeleton, *pose);
  ASSERT_TRUE(t.ok()) << t.status().to_string();
  const Vector3d elbow_now = (*t)[1].apply(elbow);
  EXPECT_NEAR(((*t)[1].apply(skeleton.segments[1].centroid_mm) - shoulder).normalized().z(), 1.0, 1e-9);
  EXPECT_NEAR(((*t)[2].apply(skeleton.segments[2].centroid_mm) - elbow_now).normalized().z(), 1.0, 1e-9);
  const Eigen::AngleAxisd turn((*t)[1].rotation);
  EXPECT_NEAR(std::abs(turn.axis().y()), 1.0, 1e-9);  // through the side
  const Vector3d angles = *pose->joints[0].angles_deg;
  EXPECT_NEAR(std::abs(angles.y()), 180.0, 1e-6) << angles.transpose();
  EXPECT_NEAR(angles.x(), 0.0, 1e-6);
  EXPECT_NEAR(angles.z(), 0.0, 1e-6);
}

}  // namespace
}  // namespace posewarp::pose
