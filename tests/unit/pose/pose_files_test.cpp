#include "posewarp/pose/forward_kinematics.h"

#include <gtest/gtest.h>

#include "posewarp/io/volume_io.h"
#include "posewarp/labels/presets.h"
#include "posewarp/phantom/phantom.h"
#include "posewarp/pose/pose.h"

namespace posewarp::pose {
namespace {

// The example poses in data/poses do what data/poses/README.md says they do.
const Eigen::Vector3d kLeft{1, 0, 0}, kPosterior{0, 1, 0}, kSuperior{0, 0, 1};

std::string pose_file(const std::string& name) { return std::string(POSEWARP_SOURCE_DIR) + "/data/poses/" + name; }

// How the centroid of `segment` moves under the pose.
Eigen::Vector3d centroid_motion(const rig::Skeleton& skeleton, const Pose& pose, const std::string& segment) {
  Result<std::vector<RigidTransform>> transforms = forward_kinematics(skeleton, pose);
  EXPECT_TRUE(transforms.ok()) << transforms.status().to_string();
  const int s = skeleton.segment_index(segment);
  EXPECT_GE(s, 0) << segment;
  if (!transforms.ok() || s < 0) return Eigen::Vector3d::Zero();
  const Eigen::Vector3d c = skeleton.segments[static_cast<size_t>(s)].centroid_mm;
  return (*transforms)[static_cast<size_t>(s)].apply(c) - c;
}

rig::Skeleton mannequin_skeleton() {
  phantom::MannequinParams params;
  params.spacing_mm = 5.0;
  Result<phantom::Phantom> m = phantom::make_mannequin(params);
  EXPECT_TRUE(m.ok());
  Result<rig::Skeleton> skeleton = rig::build_skeleton(m->labels, m->label_map, {}, {}, {});
  EXPECT_TRUE(skeleton.ok()) << skeleton.status().to_string();
  return std::move(skeleton).value();
}

TEST(PoseFiles, KneeBentSwingsTheLeftHeelBack) {
  const rig::Skeleton skeleton = mannequin_skeleton();
  Result<Pose> pose = read_pose(pose_file("knee_bent.json"));
  ASSERT_TRUE(pose.ok()) << pose.status().to_string();
  const Eigen::Vector3d shank = centroid_motion(skeleton, *pose, "tibia_left");
  EXPECT_GT(shank.dot(kPosterior), 100.0);  // the shank swings behind the thigh
  EXPECT_GT(shank.dot(kSuperior), 100.0);
  EXPECT_LT(centroid_motion(skeleton, *pose, "tibia_right").norm(), 1e-9);
}

TEST(PoseFiles, ArmRaisedTakesTheRightArmSidewaysAwayFromTheBody) {
  const rig::Skeleton skeleton = mannequin_skeleton();
  Result<Pose> pose = read_pose(pose_file("arm_raised.json"));
  ASSERT_TRUE(pose.ok()) << pose.status().to_string();
  const Eigen::Vector3d arm = centroid_motion(skeleton, *pose, "humerus_right");
  EXPECT_LT(arm.dot(kLeft), -100.0);  // toward the patient's right
  EXPECT_GT(arm.dot(kSuperior), 100.0);
  EXPECT_LT(std::abs(arm.dot(kPosterior)), 10.0);
}

TEST(PoseFiles, BarBendSwingsTheDistalBonesAnterior) {
  Result<phantom::Phantom> bar = phantom::make_bar({});
  ASSERT_TRUE(bar.ok());
  Result<rig::Skeleton> skeleton = rig::build_skeleton(bar->labels, bar->label_map, {}, {}, {});
  ASSERT_TRUE(skeleton.ok());
  Result<Pose> pose = read_pose(pose_file("bar_bend_90.json"));
  ASSERT_TRUE(pose.ok());
  EXPECT_LT(centroid_motion(*skeleton, *pose, "bar_bone_4").dot(kPosterior), -50.0);
}

TEST(PoseFiles, SampleHipFlexionTakesTheLeftThighForward) {
  Result<LabelVolume> seg = io::read_label_volume(std::string(POSEWARP_SAMPLE_DIR) + "/seg_total.nii.gz");
  ASSERT_TRUE(seg.ok());
  Result<rig::Skeleton> skeleton = rig::build_skeleton(*seg, labels::totalsegmentator_v2_preset(), {}, {}, {});
  ASSERT_TRUE(skeleton.ok());
  Result<Pose> pose = read_pose(pose_file("sample_hip_flexion.json"));
  ASSERT_TRUE(pose.ok());
  const Eigen::Vector3d thigh = centroid_motion(*skeleton, *pose, "femur_left");
  EXPECT_LT(thigh.dot(kPosterior), -5.0);  // forward
  // The scan holds only the top of the femur (its centroid lies toward the trochanter), yet flexion turns about the
  // mediolateral axis: a point of the shaft 100 mm below the hip swings forward and up, not sideways.
  const rig::Joint& hip = skeleton->joints[static_cast<size_t>(skeleton->joint_index("hip_left"))];
  EXPECT_GT(std::abs(hip.frame.col(0).dot(kLeft)), 0.99);
  Result<std::vector<RigidTransform>> transforms = forward_kinematics(*skeleton, *pose);
  ASSERT_TRUE(transforms.ok());
  const Eigen::Vector3d shaft = hip.centre_mm - 100.0 * kSuperior;
  const Eigen::Vector3d moved = (*transforms)[static_cast<size_t>(hip.child)].apply(shaft) - shaft;
  EXPECT_NEAR(moved.dot(-kPosterior), 100.0 * std::sin(30.0 * M_PI / 180.0), 1.0);
  EXPECT_NEAR(moved.dot(kLeft), 0.0, 1.0);
}

}  // namespace
}  // namespace posewarp::pose
