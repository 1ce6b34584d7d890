// Pose JSON, validation, animations and forward kinematics on a hand-built chain with known answers.
#include "posewarp/pose/pose.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <limits>
#include <sstream>

#include "chain_skeleton.h"
#include "posewarp/pose/animation.h"
#include "posewarp/pose/bvh.h"
#include "posewarp/pose/forward_kinematics.h"

namespace posewarp::pose {
namespace {

using testing::chain_skeleton;
using testing::rotation_about;
using testing::upper_frame;

constexpr double kTol = 1e-9;

Pose pose_of(std::vector<JointRotation> joints) {
  Pose pose;
  pose.name = "test";
  pose.joints = std::move(joints);
  return pose;
}

Eigen::Quaterniond quaternion_about(const Eigen::Vector3d& axis, double degrees) {
  return Eigen::Quaterniond(rotation_about(axis, degrees));
}

void expect_near(const Eigen::Vector3d& actual, const Eigen::Vector3d& expected, double tolerance = kTol) {
  EXPECT_LT((actual - expected).norm(), tolerance)
      << "actual " << actual.transpose() << ", expected " << expected.transpose();
}

void expect_same_rotation(const Eigen::Quaterniond& a, const Eigen::Quaterniond& b, double tolerance = 1e-9) {
  EXPECT_LT((a.toRotationMatrix() - b.toRotationMatrix()).norm(), tolerance)
      << "a = " << a.coeffs().transpose() << ", b = " << b.coeffs().transpose();
}

std::vector<RigidTransform> posed(const rig::Skeleton& skeleton, const Pose& pose) {
  Result<std::vector<RigidTransform>> transforms = forward_kinematics(skeleton, pose);
  EXPECT_TRUE(transforms.ok()) << transforms.status().to_string();
  return transforms.ok() ? *transforms : std::vector<RigidTransform>(skeleton.segments.size());
}

// The status of a pose read from `text` and validated against the chain.
Status pose_status(const std::string& text) {
  Result<Pose> pose = pose_from_json(text, "'test.json'");
  if (!pose.ok()) return pose.status();
  return validate_pose(*pose, chain_skeleton());
}

void expect_invalid(const Status& status, const std::vector<std::string>& fragments) {
  EXPECT_EQ(status.code(), StatusCode::kInvalidArgument) << status.to_string();
  for (const std::string& fragment : fragments) {
    EXPECT_NE(status.message().find(fragment), std::string::npos)
        << "message lacks \"" << fragment << "\": " << status.message();
  }
}

// ---- RigidTransform ---------------------------------------------------------------------------------------------

TEST(RigidTransform, ComposesRightToLeftAndInverts) {
  RigidTransform a;
  a.rotation = rotation_about(Eigen::Vector3d::UnitZ(), 90);
  a.translation = Eigen::Vector3d(1, 2, 3);
  RigidTransform b;
  b.rotation = rotation_about(Eigen::Vector3d::UnitX(), 30);
  b.translation = Eigen::Vector3d(-4, 0, 7);
  const Eigen::Vector3d p(0.5, -2.0, 9.0);
  expect_near((a * b).apply(p), a.apply(b.apply(p)));
  expect_near(a.inverse().apply(a.apply(p)), p);
  expect_near((a * a.inverse()).apply(p), p);
  expect_near(RigidTransform::identity().apply(p), p);
  expect_near(a.apply(Eigen::Vector3d(1, 0, 0)), Eigen::Vector3d(1, 3, 3));
}

// ---- forward kinematics -----------------------------------------------------------------------------------------

TEST(ForwardKinematics, IdentityPoseGivesIdentityTransforms) {
  const rig::Skeleton skeleton = chain_skeleton();
  Result<Pose> identity = pose_from_json(R"({"format": "posewarp.pose", "version": 1, "name": "identity",
                                             "joints": {}})",
                                         "'identity'");
  ASSERT_TRUE(identity.ok()) << identity.status().to_string();
  const std::vector<RigidTransform> transforms = posed(skeleton, *identity);
  ASSERT_EQ(transforms.size(), 3u);
  for (const RigidTransform& t : transforms) {
    EXPECT_LT((t.rotation - Eigen::Matrix3d::Identity()).norm(), kTol);
    EXPECT_LT(t.translation.norm(), kTol);
  }
  // Listing a joint with a zero rotation is the same as leaving it out.
  const std::vector<RigidTransform> listed =
      posed(skeleton, pose_of({{"lower", Eigen::Quaterniond::Identity()}, {"upper", Eigen::Quaterniond::Identity()}}));
  for (const RigidTransform& t : listed) EXPECT_LT(t.translation.norm(), kTol);
}

TEST(ForwardKinematics, ChildRotatesAboutItsJointCentre) {
  const rig::Skeleton skeleton = chain_skeleton();
  const std::vector<RigidTransform> t = posed(skeleton, pose_of({{"lower", rotation_from_angles_deg(90, 0, 0)}}));
  // Flexion turns about the frame's x (here LPS x) by +90 degrees: +z goes to -y (anterior).
  expect_near(t[1].apply(Eigen::Vector3d(0, 0, 150)), Eigen::Vector3d(0, -50, 100));
  expect_near(t[1].apply(Eigen::Vector3d(0, 0, 100)), Eigen::Vector3d(0, 0, 100));  // the centre stays put
  expect_near(t[1].apply(Eigen::Vector3d(7, 0, 100)), Eigen::Vector3d(7, 0, 100));  // so does the axis
  // The parent does not move; the grandchild moves with its parent.
  expect_near(t[0].apply(Eigen::Vector3d(3, 4, 50)), Eigen::Vector3d(3, 4, 50));
  expect_near(t[2].apply(Eigen::Vector3d(0, 0, 250)), Eigen::Vector3d(0, -150, 100));
}

TEST(ForwardKinematics, JointRotationIsExpressedInTheJointFrame) {
  const rig::Skeleton skeleton = chain_skeleton();
  const Eigen::Quaterniond local = rotation_from_angles_deg(90, 0, 0);
  const std::vector<RigidTransform> t = posed(skeleton, pose_of({{"upper", local}}));
  // The frame's x axis is LPS y, so flexion turns about LPS y: +z goes to +x.
  const Eigen::Matrix3d world = upper_frame() * local.toRotationMatrix() * upper_frame().transpose();
  EXPECT_LT((t[2].rotation - world).norm(), kTol);
  EXPECT_LT((t[2].rotation - rotation_about(Eigen::Vector3d::UnitY(), 90)).norm(), kTol);
  expect_near(t[2].apply(Eigen::Vector3d(0, 0, 250)), Eigen::Vector3d(50, 0, 200));
  expect_near(t[1].apply(Eigen::Vector3d(0, 0, 150)), Eigen::Vector3d(0, 0, 150));
}

TEST(ForwardKinematics, GrandchildFollowsBothRotations) {
  const rig::Skeleton skeleton = chain_skeleton();
  const Pose pose =
      pose_of({{"lower", rotation_from_angles_deg(90, 0, 0)}, {"upper", rotation_from_angles_deg(90, 0, 0)}});
  const std::vector<RigidTransform> t = posed(skeleton, pose);
  // First about the upper joint (LPS y through z = 200), then about the lower one (LPS x through z = 100).
  const Eigen::Vector3d p(0, 0, 250);
  const Eigen::Vector3d after_upper =
      rotation_about(Eigen::Vector3d::UnitY(), 90) * (p - Eigen::Vector3d(0, 0, 200)) + Eigen::Vector3d(0, 0, 200);
  const Eigen::Vector3d expected =
      rotation_about(Eigen::Vector3d::UnitX(), 90) * (after_upper - Eigen::Vector3d(0, 0, 100)) +
      Eigen::Vector3d(0, 0, 100);
  expect_near(after_upper, Eigen::Vector3d(50, 0, 200));
  expect_near(expected, Eigen::Vector3d(50, -100, 100));
  expect_near(t[2].apply(p), expected);
  // The upper joint's centre moves with the middle segment only.
  expect_near(t[2].apply(Eigen::Vector3d(0, 0, 200)), t[1].apply(Eigen::Vector3d(0, 0, 200)));
}

TEST(ForwardKinematics, RootRotatesAboutTheRootCentroidThenTranslates) {
  const rig::Skeleton skeleton = chain_skeleton();
  Pose pose = pose_of({});
  pose.root.rotation = rotation_about(Eigen::Vector3d::UnitZ(), 90);
  pose.root.translation = Eigen::Vector3d(1, 2, 3);
  const std::vector<RigidTransform> t = posed(skeleton, pose);
  const Eigen::Vector3d centroid = skeleton.segments[0].centroid_mm;
  expect_near(t[0].apply(centroid), centroid + Eigen::Vector3d(1, 2, 3));
  expect_near(t[0].apply(Eigen::Vector3d(10, 0, 50)), Eigen::Vector3d(0, 10, 50) + Eigen::Vector3d(1, 2, 3));
  // Every segment moves rigidly with the root when no joint turns.
  for (const RigidTransform& segment : t) {
    expect_near(segment.apply(Eigen::Vector3d(10, 0, 250)), Eigen::Vector3d(0, 10, 250) + Eigen::Vector3d(1, 2, 3));
  }
}

TEST(ForwardKinematics, DoesNotDependOnTheOrderOfTheJoints) {
  rig::Skeleton skeleton = chain_skeleton();
  const Pose pose =
      pose_of({{"lower", rotation_from_angles_deg(30, 10, -20)}, {"upper", rotation_from_angles_deg(-45, 5, 60)}});
  const std::vector<RigidTransform> ordered = posed(skeleton, pose);
  std::swap(skeleton.joints[0], skeleton.joints[1]);
  skeleton.segments[1].parent_joint = 1;
  skeleton.segments[2].parent_joint = 0;
  const std::vector<RigidTransform> swapped = posed(skeleton, pose);
  for (size_t s = 0; s < 3; ++s) {
    EXPECT_LT((ordered[s].rotation - swapped[s].rotation).norm(), kTol);
    EXPECT_LT((ordered[s].translation - swapped[s].translation).norm(), kTol);
  }
}

TEST(ForwardKinematics, RejectsASkeletonThatIsNotATree) {
  rig::Skeleton skeleton = chain_skeleton();
  skeleton.joints[1].parent = 2;  // "top" hangs from itself: unreachable from the root
  skeleton.joints[1].child = 2;
  expect_invalid(forward_kinematics(skeleton, pose_of({})).status(), {"upper"});
  skeleton = chain_skeleton();
  skeleton.joints.pop_back();  // "top" has no joint to the root
  expect_invalid(forward_kinematics(skeleton, pose_of({})).status(), {"\"top\"", "not connected"});
  skeleton = chain_skeleton();
  skeleton.joints[1].child = 1;  // "middle" is the child of two joints
  skeleton.joints[1].parent = 0;
  expect_invalid(forward_kinematics(skeleton, pose_of({})).status(), {"\"middle\"", "two joints"});
}

TEST(ForwardKinematics, RejectsAnInvalidPose) {
  expect_invalid(forward_kinematics(chain_skeleton(), pose_of({{"elbow", Eigen::Quaterniond::Identity()}})).status(),
                 {"elbow", "lower, upper"});
}

// ---- rotation forms and JSON ------------------------------------------------------------------------------------

TEST(PoseJson, EveryRotationFormGivesTheSameRotation) {
  const std::string text = R"({"joints": {
      "a": {"quaternion": [0.7071067811865476, 0.7071067811865476, 0, 0]},
      "b": {"axis_angle": {"axis": [2, 0, 0], "degrees": 90}},
      "c": {"angles_deg": {"flexion": 90}},
      "d": {"angles_deg": {"abduction": -30}},
      "e": {"axis_angle": {"axis": [0, 1, 0], "degrees": -30}},
      "f": {"angles_deg": {"flexion": 20, "abduction": 30, "rotation": 40}}}})";
  Result<Pose> pose = pose_from_json(text, "'forms'");
  ASSERT_TRUE(pose.ok()) << pose.status().to_string();
  ASSERT_EQ(pose->joints.size(), 6u);
  EXPECT_EQ(pose->joints[0].joint, "a");  // the order of the file is kept
  EXPECT_EQ(pose->joints[5].joint, "f");
  const Eigen::Quaterniond x90 = quaternion_about(Eigen::Vector3d::UnitX(), 90);
  for (int i = 0; i < 3; ++i) expect_same_rotation(pose->joints[static_cast<size_t>(i)].rotation, x90);
  expect_same_rotation(pose->joints[3].rotation, pose->joints[4].rotation);
  // Intrinsic x, then y, then z: R = Rx * Ry * Rz.
  const Eigen::Matrix3d expected = rotation_about(Eigen::Vector3d::UnitX(), 20) *
                                   rotation_about(Eigen::Vector3d::UnitY(), 30) *
                                   rotation_about(Eigen::Vector3d::UnitZ(), 40);
  EXPECT_LT((pose->joints[5].rotation.toRotationMatrix() - expected).norm(), 1e-12);
}

TEST(PoseJson, RootAcceptsTranslationAndRotation) {
  Result<Pose> pose = pose_from_json(R"({"root": {"translation_mm": [1, 2.5, -3],
                                                  "rotation": {"axis_angle": {"axis": [0, 0, 1], "degrees": 30}}}})",
                                     "'root'");
  ASSERT_TRUE(pose.ok()) << pose.status().to_string();
  expect_near(pose->root.translation, Eigen::Vector3d(1, 2.5, -3));
  EXPECT_LT((pose->root.rotation - rotation_about(Eigen::Vector3d::UnitZ(), 30)).norm(), 1e-12);
  EXPECT_TRUE(pose->joints.empty());
}

TEST(PoseJson, RoundTripKeepsEveryJointAndTheRoot) {
  Pose pose;
  pose.name = "round trip";
  pose.joints = {{"upper", rotation_from_angles_deg(12.5, -40, 77)}, {"lower", quaternion_about({1, 2, 3}, 123)}};
  pose.root.rotation = rotation_about(Eigen::Vector3d(0.3, -1, 2), 33);
  pose.root.translation = Eigen::Vector3d(-5.25, 0.125, 1e-3);
  const std::string text = pose_to_json(pose);
  Result<Pose> back = pose_from_json(text, "'round trip'");
  ASSERT_TRUE(back.ok()) << back.status().to_string() << "\n" << text;
  EXPECT_EQ(back->name, pose.name);
  ASSERT_EQ(back->joints.size(), 2u);
  for (size_t j = 0; j < 2; ++j) {
    EXPECT_EQ(back->joints[j].joint, pose.joints[j].joint);
    expect_same_rotation(back->joints[j].rotation, pose.joints[j].rotation, 1e-12);
  }
  EXPECT_LT((back->root.rotation - pose.root.rotation).norm(), 1e-12);
  expect_near(back->root.translation, pose.root.translation, 1e-12);
  EXPECT_TRUE(validate_pose(*back, chain_skeleton()).ok());
}

TEST(PoseJson, UnknownJointIsAnErrorListingTheRigsJoints) {
  expect_invalid(pose_status(R"({"joints": {"lowr": {"angles_deg": {"flexion": 10}}}})"),
                 {"\"lowr\"", "lower, upper", "did you mean \"lower\""});
  expect_invalid(pose_status(R"({"joints": {"elbow_left": {"angles_deg": {"flexion": 10}}}})"),
                 {"\"elbow_left\"", "the rig's joints are: lower, upper"});
}

TEST(PoseJson, NanOrInfiniteAngleIsAnError) {
  // JSON has no NaN: the parser refuses it, and the message says why.
  expect_invalid(pose_status(R"({"joints": {"lower": {"angles_deg": {"flexion": NaN}}}})"), {"not valid JSON", "NaN"});
  // A number too large for a double is refused too.
  expect_invalid(pose_status(R"({"joints": {"lower": {"angles_deg": {"flexion": 1e999}}}})"), {"1e999", "finite"});
  // A pose built in code with a NaN rotation is refused by validation.
  Pose pose = pose_of({{"lower", Eigen::Quaterniond(std::numeric_limits<double>::quiet_NaN(), 0, 0, 0)}});
  expect_invalid(validate_pose(pose, chain_skeleton()), {"\"lower\"", "NaN"});
  pose = pose_of({});
  pose.root.translation.x() = std::numeric_limits<double>::infinity();
  expect_invalid(validate_pose(pose, chain_skeleton()), {"root translation"});
}

// 1e308 degrees is finite, but its rotation is arbitrary: every angle lies within a full turn either way, and the
// root moves at most 2 m, however the pose comes in.
TEST(PoseJson, AnglesAndRootTranslationOutsideTheirRangesAreErrorsNamingTheField) {
  expect_invalid(
      pose_status(R"({"joints": {"lower": {"angles_deg": {"flexion": 1e308}}}})"),
      {"pose 'test.json', joint \"lower\", \"angles_deg\": \"flexion\" = 1e+308 is outside [-360, 360] degrees"});
  expect_invalid(pose_status(R"({"joints": {"lower": {"angles_deg": {"abduction": -361}}}})"),
                 {"\"abduction\" = -361 is outside [-360, 360] degrees"});
  expect_invalid(pose_status(R"({"joints": {"upper": {"angles_deg": {"rotation": 400}}}})"),
                 {"joint \"upper\"", "\"rotation\" = 400"});
  expect_invalid(pose_status(R"({"joints": {"lower": {"axis_angle": {"axis": [1, 0, 0], "degrees": 1e308}}}})"),
                 {"joint \"lower\", \"axis_angle\": \"degrees\" = 1e+308 is outside [-360, 360] degrees"});
  expect_invalid(pose_status(R"({"root": {"rotation": {"axis_angle": {"axis": [0, 0, 1], "degrees": -720}}},
                                 "joints": {}})"),
                 {"root rotation", "\"degrees\" = -720"});
  expect_invalid(pose_status(R"({"root": {"translation_mm": [0, 30000, 0]}, "joints": {}})"),
                 {"root: \"translation_mm[1]\" = 30000 is outside [-2000, 2000] mm"});
  expect_invalid(pose_status(R"({"root": {"translation_mm": [1e300, 0, 0]}, "joints": {}})"),
                 {"\"translation_mm[0]\" = 1e+300"});
  // The limits themselves are accepted.
  EXPECT_TRUE(pose_status(R"({"root": {"translation_mm": [-2000, 2000, 0]},
                              "joints": {"lower": {"angles_deg": {"flexion": 360, "abduction": -360}},
                                         "upper": {"axis_angle": {"axis": [0, 1, 0], "degrees": -360}}}})")
                  .ok());
  // A pose built in code is held to the same ranges.
  Pose coded = pose_of({anatomical_rotation("lower", 1e308)});
  expect_invalid(validate_pose(coded, chain_skeleton()),
                 {"joint \"lower\", \"angles_deg\": \"flexion\" = 1e+308 is outside [-360, 360] degrees"});
  coded = pose_of({anatomical_rotation("lower", 10.0, 0.0, -kMaxAngleDeg - 1.0)});
  expect_invalid(validate_pose(coded, chain_skeleton()), {"\"rotation\" = -361"});
  coded = pose_of({});
  coded.root.translation.z() = -kMaxRootTranslationMm * 15;
  expect_invalid(validate_pose(coded, chain_skeleton()),
                 {"root", "\"translation_mm[2]\" = -30000", "[-2000, 2000] mm"});
  coded.root.translation.z() = kMaxRootTranslationMm;
  EXPECT_TRUE(validate_pose(coded, chain_skeleton()).ok());
}

TEST(Animation, FramesAreHeldToThePoseRanges) {
  Result<Animation> animation = animation_from_json(
      R"({"frames": [{"joints": {}}, {"root": {"translation_mm": [0, 0, 2500]}, "joints": {}}]})", "'a.json'");
  expect_invalid(animation.status(), {"frame 1", "\"translation_mm[2]\" = 2500"});
}

TEST(PoseJson, NonUnitQuaternionIsAnErrorThatSaysToNormalize) {
  expect_invalid(pose_status(R"({"joints": {"lower": {"quaternion": [1, 1, 0, 0]}}})"),
                 {"joint \"lower\"", "length 1.414", "divide each component by 1.414"});
  // Within 1e-3 of unit length it is accepted (and normalized).
  Result<Pose> nearly = pose_from_json(R"({"joints": {"lower": {"quaternion": [1.0005, 0, 0, 0]}}})", "'nearly'");
  ASSERT_TRUE(nearly.ok()) << nearly.status().to_string();
  EXPECT_NEAR(nearly->joints[0].rotation.norm(), 1.0, 1e-15);
  const Pose coded = pose_of({{"upper", Eigen::Quaterniond(2, 0, 0, 0)}});
  expect_invalid(validate_pose(coded, chain_skeleton()), {"\"upper\"", "normalize"});
}

TEST(PoseJson, RotationGivenTwoWaysOrNoneIsAnError) {
  expect_invalid(pose_status(R"({"joints": {"lower": {"quaternion": [1, 0, 0, 0],
                                                       "angles_deg": {"flexion": 5}}}})"),
                 {"joint \"lower\"", "2 ways", "quaternion, angles_deg", "give exactly one of"});
  expect_invalid(pose_status(R"({"joints": {"lower": {}}})"),
                 {"joint \"lower\"", "no rotation", "give exactly one of"});
  expect_invalid(pose_status(R"({"joints": {"lower": {"euler": [1, 2, 3]}}})"),
                 {"joint \"lower\"", "unknown field \"euler\"", "give exactly one of"});
  expect_invalid(pose_status(R"({"joints": {"lower": 90}})"), {"joint \"lower\"", "must be an object"});
}

TEST(PoseJson, MalformedRotationsAreErrorsThatSayWhatToWrite) {
  expect_invalid(pose_status(R"({"joints": {"lower": {"axis_angle": {"axis": [0, 0, 0], "degrees": 10}}}})"),
                 {"joint \"lower\"", "\"axis\" is zero"});
  expect_invalid(pose_status(R"({"joints": {"lower": {"axis_angle": {"axis": [1, 0], "degrees": 10}}}})"),
                 {"joint \"lower\"", "list of 3 numbers"});
  expect_invalid(pose_status(R"({"joints": {"lower": {"axis_angle": {"axis": [1, 0, 0]}}}})"),
                 {"joint \"lower\"", "{\"axis\": [x, y, z], \"degrees\": d}"});
  expect_invalid(pose_status(R"({"joints": {"lower": {"angles_deg": {"flex": 10}}}})"),
                 {"joint \"lower\"", "unknown field \"flex\"", "\"flexion\", \"abduction\", \"rotation\""});
  expect_invalid(pose_status(R"({"joints": {"lower": {"angles_deg": {"flexion": "90"}}}})"),
                 {"joint \"lower\"", "\"flexion\" must be a number"});
  expect_invalid(pose_status(R"({"joints": {"lower": {"quaternion": [1, 0, 0, "x"]}}})"),
                 {"joint \"lower\"", "quaternion[3]"});
}

TEST(PoseJson, JointGivenTwiceIsAnError) {
  expect_invalid(pose_status(R"({"joints": {"lower": {"angles_deg": {"flexion": 10}},
                                            "lower": {"angles_deg": {"flexion": 20}}}})"),
                 {"\"lower\"", "twice"});
  const Pose coded = pose_of({{"lower", Eigen::Quaterniond::Identity()}, {"lower", Eigen::Quaterniond::Identity()}});
  expect_invalid(validate_pose(coded, chain_skeleton()), {"\"lower\"", "twice"});
}

TEST(PoseJson, UnknownFieldsAndWrongFormatAreErrors) {
  expect_invalid(pose_status(R"({"joint": {}})"), {"unknown field \"joint\"", "\"joints\""});
  expect_invalid(pose_status(R"({"root": {"translation": [0, 0, 0]}})"), {"root", "unknown field \"translation\""});
  expect_invalid(pose_status(R"({"format": "posewarp.label_map", "joints": {}})"), {"expected \"posewarp.pose\""});
  expect_invalid(pose_status(R"({"version": 7, "joints": {}})"), {"version 7", "Upgrade"});
  expect_invalid(pose_status(R"([1, 2])"), {"must be a JSON object"});
  expect_invalid(pose_status(R"({"joints": )"), {"not valid JSON"});
}

TEST(PoseJson, ReadingAMissingFileIsNotFound) {
  EXPECT_EQ(read_pose("/nonexistent/pose.json").status().code(), StatusCode::kNotFound);
  EXPECT_EQ(read_animation("/nonexistent/animation.json").status().code(), StatusCode::kNotFound);
}

// ---- animations -------------------------------------------------------------------------------------------------

TEST(Animation, ReadsFramesAndFrameTimeAndRoundTrips) {
  const std::string text = R"({"format": "posewarp.animation", "version": 1, "frame_time_s": 0.25,
      "frames": [{"name": "rest", "joints": {}},
                 {"joints": {"lower": {"angles_deg": {"flexion": 45}}}},
                 {"joints": {"lower": {"angles_deg": {"flexion": 90}}}, "root": {"translation_mm": [0, 0, 10]}}]})";
  Result<Animation> animation = animation_from_json(text, "'steps'");
  ASSERT_TRUE(animation.ok()) << animation.status().to_string();
  EXPECT_DOUBLE_EQ(animation->frame_time_s, 0.25);
  ASSERT_EQ(animation->frames.size(), 3u);
  EXPECT_EQ(animation->frames[0].name, "rest");
  EXPECT_EQ(animation->frames[1].name, "frame 1");
  expect_same_rotation(animation->frames[2].joints[0].rotation, rotation_from_angles_deg(90, 0, 0));
  expect_near(animation->frames[2].root.translation, Eigen::Vector3d(0, 0, 10));
  EXPECT_TRUE(validate_animation(*animation, chain_skeleton()).ok());

  Result<Animation> back = animation_from_json(animation_to_json(*animation), "'again'");
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  ASSERT_EQ(back->frames.size(), 3u);
  EXPECT_DOUBLE_EQ(back->frame_time_s, 0.25);
  EXPECT_EQ(back->frames[1].name, "frame 1");
  expect_same_rotation(back->frames[1].joints[0].rotation, rotation_from_angles_deg(45, 0, 0), 1e-12);
}

TEST(Animation, BadFramesAreErrorsNamingTheFrame) {
  expect_invalid(animation_from_json(R"({"frames": []})", "'a'").status(), {"at least one pose"});
  expect_invalid(animation_from_json(R"({"frame_time_s": 0, "frames": [{}]})", "'a'").status(),
                 {"frame_time_s", "positive"});
  expect_invalid(animation_from_json(R"({"frames": [{}, {"joints": {"lower": {}}}]})", "'a'").status(),
                 {"frame 1", "joint \"lower\"", "no rotation"});
  Result<Animation> unknown =
      animation_from_json(R"({"frames": [{}, {"joints": {"knee": {"quaternion": [1, 0, 0, 0]}}}]})", "'a'");
  ASSERT_TRUE(unknown.ok());
  expect_invalid(validate_animation(*unknown, chain_skeleton()), {"frame 1", "\"knee\"", "lower, upper"});
}

// ---- the example files ------------------------------------------------------------------------------------------

// The joints of the rigs the examples are written for: the bar phantom, the mannequin phantom, and the
// TotalSegmentator sample (its preset's joint names).
std::vector<std::string> joints_for_example(const std::string& file_name) {
  if (file_name.rfind("bar_", 0) == 0) return {"joint_1_2", "joint_2_3", "joint_3_4"};
  if (file_name.rfind("sample_", 0) == 0) {
    return {"hip_left", "hip_right", "sacroiliac_left", "sacroiliac_right", "pubic_symphysis", "lumbosacral", "L4_L5",
            "L3_L4",    "L2_L3",     "L1_L2",           "thoracolumbar"};
  }
  return {"hip_left",       "hip_right",  "knee_left",   "knee_right",    "shoulder_left",
          "shoulder_right", "elbow_left", "elbow_right", "lumbosacral",   "L4_L5",
          "L3_L4",          "L2_L3",      "L1_L2",       "thoracolumbar", "neck"};
}

TEST(ExamplePoses, EveryFileInDataPosesParsesAndFitsItsRig) {
  const std::filesystem::path folder = std::filesystem::path(POSEWARP_SOURCE_DIR) / "data" / "poses";
  ASSERT_TRUE(std::filesystem::is_directory(folder)) << folder;
  int checked = 0;
  for (const auto& entry : std::filesystem::directory_iterator(folder)) {
    const std::filesystem::path path = entry.path();
    const std::string name = path.filename().string();
    const rig::Skeleton rig = testing::named_chain(joints_for_example(name));
    SCOPED_TRACE(name);
    if (path.extension() == ".bvh") {
      const std::filesystem::path map_path = folder / (path.stem().string() + "_map.json");
      Result<BvhMap> map = read_bvh_map(map_path.string());
      ASSERT_TRUE(map.ok()) << map.status().to_string();
      Result<Animation> animation = read_bvh(path.string(), *map, rig, 0, -1);
      ASSERT_TRUE(animation.ok()) << animation.status().to_string();
      EXPECT_FALSE(animation->frames.empty());
      EXPECT_TRUE(validate_animation(*animation, rig).ok());
      ++checked;
      continue;
    }
    if (path.extension() != ".json") continue;
    std::ifstream in(path);
    std::stringstream text;
    text << in.rdbuf();
    if (text.str().find("\"posewarp.animation\"") != std::string::npos) {
      Result<Animation> animation = read_animation(path.string());
      ASSERT_TRUE(animation.ok()) << animation.status().to_string();
      const Status status = validate_animation(*animation, rig);
      EXPECT_TRUE(status.ok()) << status.to_string();
    } else if (text.str().find("\"posewarp.bvh_map\"") != std::string::npos) {
      Result<BvhMap> map = read_bvh_map(path.string());
      EXPECT_TRUE(map.ok()) << map.status().to_string();
    } else {
      Result<Pose> pose = read_pose(path.string());
      ASSERT_TRUE(pose.ok()) << pose.status().to_string();
      const Status status = validate_pose(*pose, rig);
      EXPECT_TRUE(status.ok()) << status.to_string();
      EXPECT_TRUE(forward_kinematics(rig, *pose).ok());
    }
    ++checked;
  }
  EXPECT_GE(checked, 9);
}

TEST(ExamplePoses, IdentityIsTheRestPose) {
  Result<Pose> identity = read_pose(std::string(POSEWARP_SOURCE_DIR) + "/data/poses/identity.json");
  ASSERT_TRUE(identity.ok()) << identity.status().to_string();
  EXPECT_TRUE(identity->joints.empty());
  EXPECT_EQ(identity->name, "identity");
  EXPECT_EQ(identity->root.rotation, Eigen::Matrix3d::Identity());
  EXPECT_EQ(identity->root.translation, Eigen::Vector3d::Zero());
}

}  // namespace
}  // namespace posewarp::pose
