#include "posewarp/rig/skeleton.h"

#include <gtest/gtest.h>

#include <Eigen/Dense>

#include "posewarp/io/volume_io.h"
#include "posewarp/labels/presets.h"
#include "posewarp/phantom/phantom.h"

namespace posewarp::rig {
namespace {

const Joint* joint_between(const Skeleton& s, const std::string& a, const std::string& b) {
  for (const Joint& joint : s.joints) {
    const std::string& p = s.segments[static_cast<size_t>(joint.parent)].name;
    const std::string& c = s.segments[static_cast<size_t>(joint.child)].name;
    if ((p == a && c == b) || (p == b && c == a)) return &joint;
  }
  return nullptr;
}

void expect_every_true_joint_found(const phantom::Phantom& p, double spacing) {
  Result<Skeleton> skeleton = build_skeleton(p.labels, p.label_map, {}, {}, {});
  ASSERT_TRUE(skeleton.ok()) << skeleton.status().to_string();
  EXPECT_EQ(skeleton->joints.size(), p.joints.size());
  EXPECT_EQ(skeleton->segments[static_cast<size_t>(skeleton->root)].name, p.root_segment);
  for (const phantom::JointTruth& truth : p.joints) {
    SCOPED_TRACE(truth.name);
    const Joint* joint = joint_between(*skeleton, truth.parent_segment, truth.child_segment);
    ASSERT_NE(joint, nullptr);
    EXPECT_EQ(joint->name, truth.name);
    EXPECT_EQ(skeleton->segments[static_cast<size_t>(joint->parent)].name, truth.parent_segment);
    const double error = (joint->centre_mm - Eigen::Vector3d(truth.centre_mm[0], truth.centre_mm[1], truth.centre_mm[2])).norm();
    EXPECT_LT(error, spacing) << "found by " << joint->method;
    if (truth.kind == "ball") {
      EXPECT_EQ(joint->method, "sphere-fit");
    }
    // Frames are rotations.
    EXPECT_NEAR((joint->frame.transpose() * joint->frame - Eigen::Matrix3d::Identity()).norm(), 0.0, 1e-9);
    EXPECT_NEAR(joint->frame.determinant(), 1.0, 1e-9);
  }
}

TEST(Skeleton, FindsEveryJointOfTheBarWithinOneVoxel) {
  Result<phantom::Phantom> bar = phantom::make_bar({});
  ASSERT_TRUE(bar.ok());
  expect_every_true_joint_found(*bar, 2.0);
}

TEST(Skeleton, FindsEveryJointOfTheMannequinWithinOneVoxel) {
  phantom::MannequinParams params;
  params.spacing_mm = 4.0;
  Result<phantom::Phantom> m = phantom::make_mannequin(params);
  ASSERT_TRUE(m.ok());
  expect_every_true_joint_found(*m, 4.0);
}

TEST(Skeleton, FindsEveryJointOfAnObliqueFineMannequinWithinOneVoxel) {
  phantom::MannequinParams params;
  params.spacing_mm = 3.0;
  const double a = 0.35;
  params.direction = {std::cos(a), -std::sin(a), 0, std::sin(a), std::cos(a), 0, 0, 0, 1};
  Result<phantom::Phantom> m = phantom::make_mannequin(params);
  ASSERT_TRUE(m.ok());
  expect_every_true_joint_found(*m, 3.0);
}

TEST(Skeleton, RealSampleHasHipsSacroiliacJointsAndTheLumbarChain) {
  Result<LabelVolume> seg = io::read_label_volume(std::string(POSEWARP_SAMPLE_DIR) + "/seg_total.nii.gz");
  ASSERT_TRUE(seg.ok());
  Result<Skeleton> skeleton = build_skeleton(*seg, labels::totalsegmentator_v2_preset(), {}, {}, {});
  ASSERT_TRUE(skeleton.ok()) << skeleton.status().to_string();
  EXPECT_EQ(skeleton->segments[static_cast<size_t>(skeleton->root)].name, "sacrum");
  const std::vector<std::pair<std::string, std::pair<std::string, std::string>>> expected{
      {"hip_left", {"hip_left", "femur_left"}},     {"hip_right", {"hip_right", "femur_right"}},
      {"sacroiliac_left", {"sacrum", "hip_left"}},  {"sacroiliac_right", {"sacrum", "hip_right"}},
      {"lumbosacral", {"sacrum", "vertebrae_L5"}},  {"L4_L5", {"vertebrae_L5", "vertebrae_L4"}},
      {"L3_L4", {"vertebrae_L4", "vertebrae_L3"}},  {"L2_L3", {"vertebrae_L3", "vertebrae_L2"}},
      {"L1_L2", {"vertebrae_L2", "vertebrae_L1"}},  {"thoracolumbar", {"vertebrae_L1", "thorax"}}};
  for (const auto& [name, pair] : expected) {
    SCOPED_TRACE(name);
    const int j = skeleton->joint_index(name);
    ASSERT_GE(j, 0);
    const Joint& joint = skeleton->joints[static_cast<size_t>(j)];
    EXPECT_EQ(skeleton->segments[static_cast<size_t>(joint.parent)].name, pair.first);
    EXPECT_EQ(skeleton->segments[static_cast<size_t>(joint.child)].name, pair.second);
  }
  // Femoral heads are balls: the hip centres come from sphere fits, about 25 mm in radius.
  for (const char* hip : {"hip_left", "hip_right"}) {
    const Joint& joint = skeleton->joints[static_cast<size_t>(skeleton->joint_index(hip))];
    EXPECT_EQ(joint.method, "sphere-fit") << hip;
    EXPECT_GT(joint.sphere_radius_mm, 15.0) << hip;
    EXPECT_LT(joint.sphere_radius_mm, 35.0) << hip;
  }
  EXPECT_FALSE(skeleton->missing_segments.empty());  // the preset's skull, humeri, ... are out of view
}

TEST(Skeleton, RigSpecMovesRenamesAndRegroups) {
  Result<phantom::Phantom> bar = phantom::make_bar({});
  ASSERT_TRUE(bar.ok());
  Result<RigSpec> spec = rig_spec_from_json(
      R"({"segments": {"proximal": [10, 11]}, "root": "proximal",
          "joints": [{"child": "bar_bone_3", "name": "elbow", "centre_mm": [1, 2, 3]}]})", "inline");
  ASSERT_TRUE(spec.ok()) << spec.status().to_string();
  Result<Skeleton> skeleton = build_skeleton(bar->labels, bar->label_map, *spec, {}, {});
  ASSERT_TRUE(skeleton.ok()) << skeleton.status().to_string();
  EXPECT_EQ(skeleton->segments.size(), 3u);
  EXPECT_EQ(skeleton->segments[static_cast<size_t>(skeleton->root)].name, "proximal");
  const int elbow = skeleton->joint_index("elbow");
  ASSERT_GE(elbow, 0);
  EXPECT_EQ(skeleton->joints[static_cast<size_t>(elbow)].centre_mm, Eigen::Vector3d(1, 2, 3));
  EXPECT_EQ(skeleton->joints[static_cast<size_t>(elbow)].method, "rig-spec");
}

TEST(Skeleton, RigSpecCanAddAJointBetweenSegmentsThatDoNotTouch) {
  Result<phantom::Phantom> bar = phantom::make_bar({});
  ASSERT_TRUE(bar.ok());
  Result<RigSpec> spec = rig_spec_from_json(
      R"({"joints": [{"parent": "bar_bone_1", "child": "bar_bone_3", "centre_mm": [0, 0, 100]}],
          "remove_joints": [["bar_bone_2", "bar_bone_3"]]})", "inline");
  ASSERT_TRUE(spec.ok());
  Result<Skeleton> skeleton = build_skeleton(bar->labels, bar->label_map, *spec, {}, {});
  ASSERT_TRUE(skeleton.ok()) << skeleton.status().to_string();
  const Joint* joint = joint_between(*skeleton, "bar_bone_1", "bar_bone_3");
  ASSERT_NE(joint, nullptr);
  EXPECT_EQ(joint->method, "rig-spec");
  EXPECT_EQ(joint_between(*skeleton, "bar_bone_2", "bar_bone_3"), nullptr);
}

TEST(Skeleton, NoBoneLabelsIsAClearError) {
  ImageGeometry g;
  g.size = {8, 8, 8};
  LabelVolume empty(g, 0);
  Result<Skeleton> skeleton = build_skeleton(empty, labels::totalsegmentator_v2_preset(), {}, {}, {});
  EXPECT_EQ(skeleton.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(skeleton.status().message().find("no bone labels"), std::string::npos);
}

TEST(Skeleton, OneBoneOnlyIsAClearError) {
  ImageGeometry g;
  g.size = {8, 8, 8};
  LabelVolume labels(g, 0);
  labels.at(3, 3, 3) = 75;  // femur_left
  labels.at(4, 3, 3) = 5;   // liver
  Result<Skeleton> skeleton = build_skeleton(labels, labels::totalsegmentator_v2_preset(), {}, {}, {});
  EXPECT_EQ(skeleton.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(skeleton.status().message().find("femur_left"), std::string::npos);
}

TEST(Skeleton, SpecNamingAbsentLabelsOrSegmentsIsAnError) {
  Result<phantom::Phantom> bar = phantom::make_bar({});
  ASSERT_TRUE(bar.ok());
  Result<RigSpec> absent_label = rig_spec_from_json(R"({"segments": {"x": [99]}})", "inline");
  ASSERT_TRUE(absent_label.ok());
  Result<Skeleton> s1 = build_skeleton(bar->labels, bar->label_map, *absent_label, {}, {});
  EXPECT_EQ(s1.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s1.status().message().find("label 99"), std::string::npos);
  Result<RigSpec> absent_segment = rig_spec_from_json(R"({"joints": [{"child": "tibia", "parent": "bar_bone_1"}]})", "inline");
  ASSERT_TRUE(absent_segment.ok());
  Result<Skeleton> s2 = build_skeleton(bar->labels, bar->label_map, *absent_segment, {}, {});
  EXPECT_EQ(s2.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s2.status().message().find("tibia"), std::string::npos);
  EXPECT_EQ(rig_spec_from_json(R"({"jionts": []})", "typo.json").status().code(), StatusCode::kInvalidArgument);
}

// A label in two segments silently belonged to the last one.
TEST(Skeleton, SpecListingALabelInTwoSegmentsIsRefused) {
  const Status twice = rig_spec_from_json(R"({"segments": {"a": [1, 2], "b": [2]}})", "'twice.json'").status();
  EXPECT_EQ(twice.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(twice.message().find("label 2 is listed in segment \"a\" and in segment \"b\""), std::string::npos)
      << twice.to_string();
  EXPECT_NE(twice.message().find("twice.json"), std::string::npos);
}

}  // namespace
}  // namespace posewarp::rig

namespace posewarp::rig {
namespace {

TEST(Skeleton, ALabelMapNamingOnlyAbsentBonesIsAClearError) {
  ImageGeometry g;
  g.size = {8, 8, 8};
  LabelVolume labels(g, 0);
  labels.at(2, 2, 2) = 1;
  labels.at(5, 5, 5) = 2;
  Result<labels::LabelMap> map = labels::label_map_from_json(
      R"({"name": "wrong map", "labels": [{"value": 50, "name": "femur", "role": "bone"},
                                          {"value": 51, "name": "tibia", "role": "bone"}]})", "inline");
  ASSERT_TRUE(map.ok());
  Result<Skeleton> skeleton = build_skeleton(labels, *map, {}, {}, {});
  EXPECT_EQ(skeleton.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(skeleton.status().message().find("wrong map"), std::string::npos);
  EXPECT_NE(skeleton.status().message().find("names 2 bone labels"), std::string::npos);
}

}  // namespace
}  // namespace posewarp::rig

namespace posewarp::rig {
namespace {

// A thorax block, a clavicle on top of it and a scapula lying flat against it: the scapula's contact with the
// thorax is by far the largest, so contact area alone would hang the scapula (and the arm) off the ribs.
struct Girdle {
  LabelVolume labels;
  Girdle() {
    ImageGeometry g;
    g.size = {40, 30, 30};
    g.spacing = {2.0, 2.0, 2.0};
    labels = LabelVolume(g, 1);
    auto fill = [&](int i0, int i1, int j0, int j1, int k0, int k1, Label value) {
      for (int k = k0; k < k1; ++k)
        for (int j = j0; j < j1; ++j)
          for (int i = i0; i < i1; ++i) labels.at(i, j, k) = value;
    };
    fill(2, 20, 2, 20, 2, 20, 10);   // thorax
    fill(21, 24, 2, 20, 2, 20, 12);  // scapula: a plate one voxel off the thorax's side
    fill(2, 26, 8, 12, 21, 24, 11);  // clavicle: over the thorax, reaching over the scapula's top
  }
};

labels::LabelMap girdle_map(bool declare) {
  std::vector<labels::LabelEntry> entries{{0, "background", labels::LabelRole::kBackground, ""},
                                          {1, "soft", labels::LabelRole::kTissue, ""},
                                          {10, "thorax", labels::LabelRole::kBone, "thorax"},
                                          {11, "clavicula_left", labels::LabelRole::kBone, "clavicula_left"},
                                          {12, "scapula_left", labels::LabelRole::kBone, "scapula_left"}};
  std::vector<labels::JointName> joints;
  if (declare) {
    joints = {{"sternoclavicular_left", "thorax", "clavicula_left", labels::JointKind::kPlane},
              {"acromioclavicular_left", "clavicula_left", "scapula_left", labels::JointKind::kPlane},
              {"scapulothoracic_left", "thorax", "scapula_left", labels::JointKind::kPlane}};
  }
  return labels::LabelMap::create("girdle", entries, joints, "thorax").value();
}

TEST(Skeleton, DeclaredJointsGiveTheAnatomicalTreeWhereContactAreaWouldNot) {
  const Girdle girdle;
  Result<Skeleton> by_area = build_skeleton(girdle.labels, girdle_map(false), {}, {}, {});
  ASSERT_TRUE(by_area.ok()) << by_area.status().to_string();
  EXPECT_NE(joint_between(*by_area, "thorax", "scapula_left"), nullptr);  // the largest contact wins

  Result<Skeleton> declared = build_skeleton(girdle.labels, girdle_map(true), {}, {}, {});
  ASSERT_TRUE(declared.ok()) << declared.status().to_string();
  const Joint* ac = joint_between(*declared, "clavicula_left", "scapula_left");
  ASSERT_NE(ac, nullptr);
  EXPECT_EQ(ac->name, "acromioclavicular_left");
  EXPECT_EQ(declared->segments[static_cast<size_t>(ac->parent)].name, "clavicula_left");
  EXPECT_TRUE(ac->declared);
  EXPECT_EQ(joint_between(*declared, "thorax", "scapula_left"), nullptr);  // the alternative closes a loop
  EXPECT_NE(joint_between(*declared, "thorax", "clavicula_left"), nullptr);
}

TEST(Skeleton, DeclaredJointsRoundTripThroughLabelMapJson) {
  const labels::LabelMap map = girdle_map(true);
  Result<labels::LabelMap> back = labels::label_map_from_json(labels::label_map_to_json(map), "inline");
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  ASSERT_EQ(back->joint_names().size(), 3u);
  EXPECT_EQ(back->joint_names()[1].segment_a, "clavicula_left");
  EXPECT_EQ(back->joint_names()[1].kind, labels::JointKind::kPlane);
  Result<labels::LabelMap> old_form = labels::label_map_from_json(
      R"({"labels": [{"value": 1, "name": "a", "role": "bone"}, {"value": 2, "name": "b", "role": "bone"}],
          "joints": [{"name": "ab", "segments": ["a", "b"]}]})", "old");
  ASSERT_TRUE(old_form.ok()) << old_form.status().to_string();
  EXPECT_EQ(old_form->joint_names()[0].kind, labels::JointKind::kUnspecified);
  EXPECT_EQ(labels::label_map_from_json(
                R"({"labels": [{"value": 1, "name": "a", "role": "bone"}, {"value": 2, "name": "b", "role": "bone"}],
                    "joints": [{"name": "ab", "parent": "a", "child": "b", "kind": "saddle"}]})", "bad")
                .status()
                .code(),
            StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace posewarp::rig

namespace posewarp::rig {
namespace {

// The anatomical body phantom (a shallow glenoid, condyles, a talar dome, a clavicle -> scapula chain, ribs under
// the scapula, an oblique grid with thick slices): the tree is the anatomical one, ball and hinge centres lie within
// one voxel (the largest spacing) of the truth and hinge axes within 5 degrees.
void expect_anatomical_joints(const Vec3& spacing) {
  phantom::BodyParams params;
  params.spacing_mm = spacing;
  Result<phantom::Phantom> body = phantom::make_body(params);
  ASSERT_TRUE(body.ok()) << body.status().to_string();
  Result<Skeleton> skeleton = build_skeleton(body->labels, body->label_map, {}, {}, {});
  ASSERT_TRUE(skeleton.ok()) << skeleton.status().to_string();
  const double voxel = std::max({spacing[0], spacing[1], spacing[2]});
  EXPECT_EQ(skeleton->joints.size(), body->joints.size());
  for (const phantom::JointTruth& truth : body->joints) {
    SCOPED_TRACE(truth.name);
    const Joint* joint = joint_between(*skeleton, truth.parent_segment, truth.child_segment);
    ASSERT_NE(joint, nullptr);
    EXPECT_EQ(skeleton->segments[static_cast<size_t>(joint->parent)].name, truth.parent_segment);
    const double error =
        (joint->centre_mm - Eigen::Vector3d(truth.centre_mm[0], truth.centre_mm[1], truth.centre_mm[2])).norm();
    if (truth.kind == "ball") {
      EXPECT_EQ(joint->method, "sphere-fit");
      EXPECT_LT(error, voxel);
    } else if (truth.kind == "hinge") {
      EXPECT_EQ(joint->method, "cylinder-fit");
      EXPECT_LT(error, voxel);
      const Eigen::Vector3d axis(truth.axis[0], truth.axis[1], truth.axis[2]);
      EXPECT_GT(std::abs(joint->hinge_axis.dot(axis)), std::cos(5.0 * M_PI / 180.0));
      EXPECT_GT(std::abs(joint->frame.col(0).dot(axis)), std::cos(5.0 * M_PI / 180.0));  // the flexion axis
    } else if (truth.name.rfind("sternoclavicular", 0) == 0) {
      // The clavicle lies along the first rib: the joint is found at its medial end, a little lateral of the truth.
      EXPECT_LT(error, 1.5 * voxel);
    } else {
      EXPECT_LT(error, voxel);
    }
  }
}

TEST(Skeleton, FindsTheBodyPhantomsJointsOnItsDefaultObliqueAnisotropicGrid) {
  expect_anatomical_joints({2.5, 2.5, 5.0});
}

TEST(Skeleton, FindsTheBodyPhantomsJointsOnEightMillimetreSlices) { expect_anatomical_joints({4.0, 4.0, 8.0}); }

}  // namespace
}  // namespace posewarp::rig

namespace posewarp::rig {
namespace {

// Found by fuzzing the label map reader, which shared the flaw: a number too large for a double aborted.
TEST(RigSpec, NumbersPastADoubleAreAnErrorNotACrash) {
  EXPECT_EQ(rig_spec_from_json(R"({"contact_distance_mm": 1e999})", "huge").status().code(),
            StatusCode::kInvalidArgument);
  EXPECT_EQ(rig_spec_from_json("7E99999", "huge").status().code(), StatusCode::kInvalidArgument);
  // Found by fuzzing: a label value far past an int converted with undefined behaviour; a fractional one was
  // truncated into another label.
  for (const char* text : {R"({"segments": {"pelvis": [3333333333333333333333333333333333, 26]}})",
                           R"({"segments": {"pelvis": [25.7]}})", R"({"segments": {"pelvis": [-1]}})",
                           R"({"segments": {"pelvis": ["25"]}})",
                           R"({"joints": [{"child": "a", "centre_mm": [1e300, 0, 0]}]})"}) {
    const Status status = rig_spec_from_json(text, "crafted").status();
    EXPECT_EQ(status.code(), StatusCode::kInvalidArgument) << text;
  }
  EXPECT_TRUE(rig_spec_from_json(R"({"segments": {"pelvis": [25, 26.0]}})", "whole").ok());
}

}  // namespace
}  // namespace posewarp::rig
