// BVH import onto the hand-built chain: known rotations per frame, frame ranges, maps and malformed files.
#include "posewarp/pose/bvh.h"

#include <gtest/gtest.h>

#include <string>
#include <vector>

#include "chain_skeleton.h"
#include "posewarp/pose/forward_kinematics.h"

namespace posewarp::pose {
namespace {

using testing::chain_skeleton;
using testing::rotation_about;
using testing::upper_frame;

// Lines 1 to 20: a three-joint chain standing up BVH's y axis, 10 units per bone. MOTION is line 21, "Frames:"
// line 22, "Frame Time:" line 23, the first frame line 24.
const char* kHierarchy = R"(HIERARCHY
ROOT hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT knee
  {
    OFFSET 0 10 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    JOINT ankle
    {
      OFFSET 0 10 0
      CHANNELS 3 Zrotation Xrotation Yrotation
      End Site
      {
        OFFSET 0 10 0
      }
    }
  }
}
)";

// Values per frame: hips position x y z, hips Z X Y rotation, knee Z X Y, ankle Z X Y.
const std::vector<std::string> kFrames = {
    "0 0 0  0 0 0   0 0 0     0 0 0",
    "0 0 0  0 0 0   0 90 0    0 0 0",
    "1 2 3  0 0 90  0 0 0     30 0 0",
    "0 0 0  0 0 0   10 20 30  0 0 0",
};

std::string bvh_text(const std::vector<std::string>& frames = kFrames, int announced = -1,
                     const std::string& hierarchy = kHierarchy) {
  std::string text = hierarchy +
                     "MOTION\nFrames: " + std::to_string(announced >= 0 ? announced : static_cast<int>(frames.size())) +
                     "\nFrame Time: 0.04\n";
  for (const std::string& frame : frames) text += frame + "\n";
  return text;
}

BvhMap chain_map() {
  BvhMap map;
  map.joints = {{"hips", "root"}, {"knee", "lower"}, {"ankle", "upper"}};
  return map;
}

// BVH y up -> LPS: x stays, -z_bvh is posterior, y_bvh is superior.
Eigen::Matrix3d bvh_to_lps() {
  Eigen::Matrix3d a;
  a << 1, 0, 0, 0, 0, -1, 0, 1, 0;
  return a;
}

const Eigen::Quaterniond& rotation_of(const Pose& pose, const std::string& joint) {
  for (const JointRotation& j : pose.joints) {
    if (j.joint == joint) return j.rotation;
  }
  ADD_FAILURE() << "pose " << pose.name << " lacks joint " << joint;
  static const Eigen::Quaterniond kIdentity = Eigen::Quaterniond::Identity();
  return kIdentity;
}

void expect_rotation(const Eigen::Quaterniond& actual, const Eigen::Matrix3d& expected) {
  EXPECT_LT((actual.toRotationMatrix() - expected).norm(), 1e-9) << "actual\n"
                                                                 << actual.toRotationMatrix() << "\nexpected\n"
                                                                 << expected;
}

void expect_error(const Status& status, StatusCode code, const std::vector<std::string>& fragments) {
  EXPECT_EQ(status.code(), code) << status.to_string();
  for (const std::string& fragment : fragments) {
    EXPECT_NE(status.message().find(fragment), std::string::npos)
        << "message lacks \"" << fragment << "\": " << status.message();
  }
}

TEST(Bvh, ImportsEveryFrameWithItsFrameTime) {
  Result<Animation> animation = import_bvh(bvh_text(), chain_map(), chain_skeleton(), 0, -1);
  ASSERT_TRUE(animation.ok()) << animation.status().to_string();
  ASSERT_EQ(animation->frames.size(), 4u);
  EXPECT_DOUBLE_EQ(animation->frame_time_s, 0.04);
  EXPECT_EQ(animation->frames[3].name, "frame 3");
  for (const Pose& pose : animation->frames) EXPECT_TRUE(validate_pose(pose, chain_skeleton()).ok());
  // Frame 0 is the BVH rest pose: everything at rest.
  expect_rotation(rotation_of(animation->frames[0], "lower"), Eigen::Matrix3d::Identity());
  expect_rotation(rotation_of(animation->frames[0], "upper"), Eigen::Matrix3d::Identity());
  EXPECT_LT(animation->frames[0].root.translation.norm(), 1e-12);
}

TEST(Bvh, MappedJointRotationMatchesTheExpectedLpsRotation) {
  const rig::Skeleton skeleton = chain_skeleton();
  Result<Animation> animation = import_bvh(bvh_text(), chain_map(), skeleton, 0, -1);
  ASSERT_TRUE(animation.ok()) << animation.status().to_string();

  // Frame 1: the knee turns 90 degrees about BVH x, which is LPS x; the "lower" joint's frame is the identity.
  expect_rotation(rotation_of(animation->frames[1], "lower"), rotation_about(Eigen::Vector3d::UnitX(), 90));
  // The bone above the knee pointed up (BVH +y, LPS superior) and now points forward (BVH +z, LPS anterior = -y).
  Result<std::vector<RigidTransform>> t1 = forward_kinematics(skeleton, animation->frames[1]);
  ASSERT_TRUE(t1.ok()) << t1.status().to_string();
  EXPECT_LT(((*t1)[1].apply(Eigen::Vector3d(0, 0, 150)) - Eigen::Vector3d(0, -50, 100)).norm(), 1e-9);

  // Frame 2: the root turns 90 degrees about BVH y (LPS superior, z) and moves by (1, 2, 3) cm in BVH axes; the
  // ankle turns 30 degrees about BVH z (LPS -y), which the "upper" joint's frame sees about its own -x.
  const Pose& frame2 = animation->frames[2];
  EXPECT_LT((frame2.root.rotation - rotation_about(Eigen::Vector3d::UnitZ(), 90)).norm(), 1e-9);
  EXPECT_LT((frame2.root.translation - Eigen::Vector3d(10, -30, 20)).norm(), 1e-9);
  const Eigen::Matrix3d ankle_lps = rotation_about(-Eigen::Vector3d::UnitY(), 30);
  expect_rotation(rotation_of(frame2, "upper"), upper_frame().transpose() * ankle_lps * upper_frame());
  expect_rotation(rotation_of(frame2, "upper"), rotation_about(-Eigen::Vector3d::UnitX(), 30));
  Result<std::vector<RigidTransform>> t2 = forward_kinematics(skeleton, frame2);
  ASSERT_TRUE(t2.ok()) << t2.status().to_string();
  // In LPS the top segment turns relative to the middle one by exactly the BVH rotation carried into LPS.
  EXPECT_LT(((*t2)[1].rotation.transpose() * (*t2)[2].rotation - ankle_lps).norm(), 1e-9);

  // Frame 3: three channels in the order Z X Y compose as Rz * Rx * Ry, then change axes.
  const Eigen::Matrix3d knee_bvh = rotation_about(Eigen::Vector3d::UnitZ(), 10) *
                                   rotation_about(Eigen::Vector3d::UnitX(), 20) *
                                   rotation_about(Eigen::Vector3d::UnitY(), 30);
  expect_rotation(rotation_of(animation->frames[3], "lower"), bvh_to_lps() * knee_bvh * bvh_to_lps().transpose());
}

TEST(Bvh, ChannelOrderDecidesTheProduct) {
  std::string hierarchy = kHierarchy;
  const std::string zxy = "CHANNELS 3 Zrotation Xrotation Yrotation\n    JOINT ankle";
  hierarchy.replace(hierarchy.find(zxy), zxy.size(), "CHANNELS 3 Yrotation Xrotation Zrotation\n    JOINT ankle");
  Result<Animation> animation = import_bvh(bvh_text(kFrames, -1, hierarchy), chain_map(), chain_skeleton(), 3, 3);
  ASSERT_TRUE(animation.ok()) << animation.status().to_string();
  // The knee's values 10 20 30 now mean Y=10, X=20, Z=30: R = Ry * Rx * Rz.
  const Eigen::Matrix3d knee_bvh = rotation_about(Eigen::Vector3d::UnitY(), 10) *
                                   rotation_about(Eigen::Vector3d::UnitX(), 20) *
                                   rotation_about(Eigen::Vector3d::UnitZ(), 30);
  expect_rotation(rotation_of(animation->frames[0], "lower"), bvh_to_lps() * knee_bvh * bvh_to_lps().transpose());
}

TEST(Bvh, ZUpFilesKeepTheirAxes) {
  BvhMap map = chain_map();
  map.up = 'z';
  Result<Animation> animation = import_bvh(bvh_text(), map, chain_skeleton(), 2, 2);
  ASSERT_TRUE(animation.ok()) << animation.status().to_string();
  // With z up the BVH axes are LPS: 30 degrees about BVH z is 30 degrees about LPS z.
  expect_rotation(rotation_of(animation->frames[0], "upper"),
                  upper_frame().transpose() * rotation_about(Eigen::Vector3d::UnitZ(), 30) * upper_frame());
  EXPECT_LT((animation->frames[0].root.translation).norm(), 1e-12);  // the range starts here
}

TEST(Bvh, FrameRangesSelectFramesAndMoveTheRootRelativeToTheFirst) {
  const rig::Skeleton skeleton = chain_skeleton();
  Result<Animation> middle = import_bvh(bvh_text(), chain_map(), skeleton, 1, 2);
  ASSERT_TRUE(middle.ok()) << middle.status().to_string();
  ASSERT_EQ(middle->frames.size(), 2u);
  EXPECT_EQ(middle->frames[0].name, "frame 1");
  expect_rotation(rotation_of(middle->frames[0], "lower"), rotation_about(Eigen::Vector3d::UnitX(), 90));
  EXPECT_LT((middle->frames[1].root.translation - Eigen::Vector3d(10, -30, 20)).norm(), 1e-9);

  Result<Animation> tail = import_bvh(bvh_text(), chain_map(), skeleton, 2, -1);
  ASSERT_TRUE(tail.ok()) << tail.status().to_string();
  ASSERT_EQ(tail->frames.size(), 2u);
  EXPECT_LT(tail->frames[0].root.translation.norm(), 1e-12);
  EXPECT_LT((tail->frames[1].root.translation - Eigen::Vector3d(-10, 30, -20)).norm(), 1e-9);

  Result<Animation> last_only = import_bvh(bvh_text(), chain_map(), skeleton, 3, 3);
  ASSERT_TRUE(last_only.ok());
  EXPECT_EQ(last_only->frames.size(), 1u);

  expect_error(import_bvh(bvh_text(), chain_map(), skeleton, 3, 5).status(), StatusCode::kOutOfRange,
               {"4 frames", "0 to 3"});
  expect_error(import_bvh(bvh_text(), chain_map(), skeleton, 4, -1).status(), StatusCode::kOutOfRange, {"4 frames"});
  expect_error(import_bvh(bvh_text(), chain_map(), skeleton, -1, 2).status(), StatusCode::kInvalidArgument,
               {"first must be >= 0"});
  expect_error(import_bvh(bvh_text(), chain_map(), skeleton, 2, 1).status(), StatusCode::kInvalidArgument,
               {"last >= first"});
}

TEST(Bvh, IgnoredRootLeavesTheRootSegmentInPlace) {
  BvhMap map = chain_map();
  map.joints.erase(map.joints.begin());
  map.ignore = {"hips"};
  Result<Animation> animation = import_bvh(bvh_text(), map, chain_skeleton(), 2, 2);
  ASSERT_TRUE(animation.ok()) << animation.status().to_string();
  EXPECT_EQ(animation->frames[0].root.rotation, Eigen::Matrix3d::Identity());
  EXPECT_EQ(animation->frames[0].root.translation, Eigen::Vector3d::Zero());
}

TEST(Bvh, IgnoredJointsFoldIntoTheNextMappedJoint) {
  // A joint "shin" between knee and ankle that the rig does not have: its rotation must reach "upper".
  const std::string hierarchy = R"(HIERARCHY
ROOT hips
{
  OFFSET 0 0 0
  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation
  JOINT knee
  {
    OFFSET 0 10 0
    CHANNELS 3 Zrotation Xrotation Yrotation
    JOINT shin
    {
      OFFSET 0 5 0
      CHANNELS 3 Zrotation Xrotation Yrotation
      JOINT ankle
      {
        OFFSET 0 5 0
        CHANNELS 3 Zrotation Xrotation Yrotation
        End Site
        {
          OFFSET 0 10 0
        }
      }
    }
  }
}
)";
  BvhMap map = chain_map();
  map.ignore = {"shin"};
  Result<Animation> animation =
      import_bvh(bvh_text({"0 0 0 0 0 0  0 15 0  0 30 0  0 20 0"}, -1, hierarchy), map, chain_skeleton(), 0, -1);
  ASSERT_TRUE(animation.ok()) << animation.status().to_string();
  const Pose& pose = animation->frames[0];
  expect_rotation(rotation_of(pose, "lower"), rotation_about(Eigen::Vector3d::UnitX(), 15));
  expect_rotation(rotation_of(pose, "upper"),
                  upper_frame().transpose() * rotation_about(Eigen::Vector3d::UnitX(), 50) * upper_frame());
}

TEST(Bvh, UnmappedBvhJointIsAnErrorListingTheNames) {
  BvhMap map;
  map.joints = {{"knee", "lower"}};
  expect_error(import_bvh(bvh_text(), map, chain_skeleton(), 0, -1).status(), StatusCode::kInvalidArgument,
               {"BVH joints not in the map: \"hips\", \"ankle\"", "\"ignore\"", "\"root\"", "lower, upper"});
}

TEST(Bvh, MapNamingAMissingRigJointIsAnErrorListingTheNames) {
  BvhMap map = chain_map();
  map.joints[2].second = "wrist";
  expect_error(import_bvh(bvh_text(), map, chain_skeleton(), 0, -1).status(), StatusCode::kInvalidArgument,
               {"\"wrist\" (from \"ankle\")", "the rig's joints are: lower, upper", "\"ignore\""});
}

TEST(Bvh, MapThatContradictsTheRigTreeIsAnError) {
  BvhMap swapped;
  swapped.joints = {{"hips", "root"}, {"knee", "upper"}, {"ankle", "lower"}};
  expect_error(import_bvh(bvh_text(), swapped, chain_skeleton(), 0, -1).status(), StatusCode::kInvalidArgument,
               {"\"knee\"", "\"upper\"", "follows the rig's tree"});
  BvhMap root_to_joint;
  root_to_joint.joints = {{"hips", "lower"}, {"knee", "upper"}, {"ankle", "root"}};
  expect_error(import_bvh(bvh_text(), root_to_joint, chain_skeleton(), 0, -1).status(), StatusCode::kInvalidArgument,
               {"BVH root \"hips\"", "\"root\""});
  BvhMap twice;
  twice.joints = {{"hips", "root"}, {"knee", "lower"}, {"ankle", "lower"}};
  expect_error(import_bvh(bvh_text(), twice, chain_skeleton(), 0, -1).status(), StatusCode::kInvalidArgument,
               {"\"lower\"", "two BVH joints"});
}

TEST(Bvh, MalformedFilesAreErrorsNamingTheLine) {
  const rig::Skeleton skeleton = chain_skeleton();
  std::vector<std::string> frames = kFrames;
  frames[1] = "0 0 0 0 0 0 0 90 0 0 0";  // 11 values instead of 12
  expect_error(import_bvh(bvh_text(frames), chain_map(), skeleton, 0, -1).status(), StatusCode::kInvalidArgument,
               {"line 25", "11 values", "12 channels"});
  frames = kFrames;
  frames[2] = "0 0 0 0 0 0 0 abc 0 0 0 0";
  expect_error(import_bvh(bvh_text(frames), chain_map(), skeleton, 0, -1).status(), StatusCode::kInvalidArgument,
               {"line 26", "\"abc\" is not a number"});
  expect_error(import_bvh(bvh_text(kFrames, 6), chain_map(), skeleton, 0, -1).status(), StatusCode::kInvalidArgument,
               {"truncated", "Frames: 6", "only 4"});
  expect_error(import_bvh(bvh_text(kFrames, 3), chain_map(), skeleton, 0, -1).status(), StatusCode::kInvalidArgument,
               {"line 27", "more frame lines"});

  std::string hierarchy = kHierarchy;
  hierarchy.replace(hierarchy.find("CHANNELS 3 Zrotation Xrotation Yrotation"), 40, "CHANNELS 3 Zrotation Xrotation");
  expect_error(import_bvh(bvh_text(kFrames, -1, hierarchy), chain_map(), skeleton, 0, -1).status(),
               StatusCode::kInvalidArgument, {"line 9", "names only 2"});
  hierarchy = kHierarchy;
  hierarchy.replace(hierarchy.find("Xrotation Yrotation\n    JOINT"), 9, "Wrotation");
  expect_error(import_bvh(bvh_text(kFrames, -1, hierarchy), chain_map(), skeleton, 0, -1).status(),
               StatusCode::kInvalidArgument, {"line 9", "unknown channel \"Wrotation\""});
  hierarchy = kHierarchy;
  hierarchy.erase(hierarchy.rfind('}'));  // the root's block is never closed
  expect_error(import_bvh(bvh_text(kFrames, -1, hierarchy), chain_map(), skeleton, 0, -1).status(),
               StatusCode::kInvalidArgument, {"line 20", "\"hips\"", "} is missing"});
  expect_error(import_bvh("ROOT hips\n", chain_map(), skeleton, 0, -1).status(), StatusCode::kInvalidArgument,
               {"no MOTION"});
  // A finite but absurd value would be an arbitrary rotation (or a move of kilometres).
  frames = kFrames;
  frames[3] = "0 0 0  0 0 0   10 1e308 30  0 0 0";
  expect_error(import_bvh(bvh_text(frames), chain_map(), skeleton, 0, -1).status(), StatusCode::kInvalidArgument,
               {"line 27", "frame 3", "1e308", "[-10000, 10000]"});
  frames[3] = "-20000 0 0  0 0 0   0 0 0  0 0 0";
  expect_error(import_bvh(bvh_text(frames), chain_map(), skeleton, 0, -1).status(), StatusCode::kInvalidArgument,
               {"line 27", "-20000"});
  expect_error(import_bvh(std::string(kHierarchy) + "MOTION\nFrame Time: 0.1\n", chain_map(), skeleton, 0, -1).status(),
               StatusCode::kInvalidArgument, {"line 22", "Frames:"});
}

TEST(BvhMap, ReadsJointsIgnoreUpAndScale) {
  Result<BvhMap> map = bvh_map_from_json(R"({"format": "posewarp.bvh_map", "version": 1, "up": "z",
      "scale_to_mm": 1, "joints": {"hips": "root", "knee": "lower", "ankle": "upper"}, "ignore": ["toe"]})",
                                         "'map'");
  ASSERT_TRUE(map.ok()) << map.status().to_string();
  ASSERT_EQ(map->joints.size(), 3u);
  EXPECT_EQ(map->joints[1], (std::pair<std::string, std::string>("knee", "lower")));
  EXPECT_EQ(map->ignore, std::vector<std::string>{"toe"});
  EXPECT_EQ(map->up, 'z');
  EXPECT_DOUBLE_EQ(map->scale_to_mm, 1.0);

  Result<BvhMap> back = bvh_map_from_json(bvh_map_to_json(*map), "'again'");
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  EXPECT_EQ(back->joints, map->joints);
  EXPECT_EQ(back->ignore, map->ignore);
  EXPECT_EQ(back->up, 'z');

  Result<BvhMap> defaults = bvh_map_from_json(R"({"joints": {}})", "'defaults'");
  ASSERT_TRUE(defaults.ok());
  EXPECT_EQ(defaults->up, 'y');
  EXPECT_DOUBLE_EQ(defaults->scale_to_mm, 10.0);
}

TEST(BvhMap, BadMapsAreErrorsThatSayWhatToWrite) {
  auto status = [](const std::string& text) { return bvh_map_from_json(text, "'m'").status(); };
  expect_error(status(R"({"joints": {"knee": "lower"}, "ignore": ["knee"]})"), StatusCode::kInvalidArgument,
               {"\"knee\"", "both mapped and ignored"});
  expect_error(status(R"({"joints": {"knee": "lower", "knee": "upper"}})"), StatusCode::kInvalidArgument,
               {"\"knee\"", "twice"});
  expect_error(status(R"({"joints": {"knee": "lower", "shin": "lower"}})"), StatusCode::kInvalidArgument,
               {"\"lower\"", "two BVH joints"});
  expect_error(status(R"({"joints": {}, "up": "x"})"), StatusCode::kInvalidArgument, {"\"up\"", "\"y\"", "\"z\""});
  expect_error(status(R"({"joints": {}, "scale_to_mm": -1})"), StatusCode::kInvalidArgument, {"scale_to_mm"});
  expect_error(status(R"({"joints": {"knee": 3}})"), StatusCode::kInvalidArgument, {"\"knee\"", "rig joint"});
  expect_error(status(R"({"joint": {}})"), StatusCode::kInvalidArgument, {"unknown field \"joint\""});
  expect_error(status(R"({"ignore": []})"), StatusCode::kInvalidArgument, {"needs \"joints\""});
  EXPECT_EQ(read_bvh_map("/nonexistent/map.json").status().code(), StatusCode::kNotFound);
}

TEST(Bvh, AcceptsWindowsLineEndingsAndAByteOrderMark) {
  std::string text("\xEF\xBB\xBF");
  for (const char c : bvh_text()) {
    if (c == '\n') text += '\r';
    text += c;
  }
  Result<Animation> animation = import_bvh(text, chain_map(), chain_skeleton(), 0, -1);
  ASSERT_TRUE(animation.ok()) << animation.status().to_string();
  EXPECT_EQ(animation->frames.size(), 4u);
  expect_rotation(rotation_of(animation->frames[1], "lower"), rotation_about(Eigen::Vector3d::UnitX(), 90));
}

TEST(Bvh, ReadingAFileNamesItInErrors) {
  EXPECT_EQ(read_bvh("/nonexistent/clip.bvh", chain_map(), chain_skeleton(), 0, -1).status().code(),
            StatusCode::kNotFound);
}

}  // namespace
}  // namespace posewarp::pose
