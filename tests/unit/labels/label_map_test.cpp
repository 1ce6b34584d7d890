#include "posewarp/labels/label_map.h"

#include <gtest/gtest.h>

#include <set>

#include "posewarp/labels/presets.h"
#include "test_support.h"

namespace posewarp::labels {
namespace {

using posewarp::testing::ScratchDir;
using posewarp::testing::write_bytes;

TEST(TotalSegmentatorPreset, NamesAll117ClassesWithBonesGroupedIntoSegments) {
  const LabelMap map = totalsegmentator_v2_preset();
  EXPECT_EQ(map.entries().size(), 118u);  // 117 classes and background
  EXPECT_EQ(map.find(75)->name, "femur_left");
  EXPECT_EQ(map.find(75)->role, LabelRole::kBone);
  EXPECT_EQ(map.find(5)->name, "liver");
  EXPECT_EQ(map.find(5)->role, LabelRole::kTissue);
  EXPECT_EQ(map.find(26)->segment, "sacrum");   // S1 is part of the sacrum
  EXPECT_EQ(map.find(33)->segment, "thorax");   // T11
  EXPECT_EQ(map.find(110)->segment, "thorax");  // rib_right_7
  EXPECT_EQ(map.find(27)->segment, "vertebrae_L5");
  EXPECT_EQ(map.labels_of_segment("sacrum"), (std::vector<Label>{25, 26}));
  EXPECT_EQ(map.root_segment(), "sacrum");
  EXPECT_EQ(map.joint_name("femur_left", "hip_left"), "hip_left");
  EXPECT_EQ(map.joint_name("vertebrae_L5", "sacrum"), "lumbosacral");
  EXPECT_FALSE(map.joint_name("femur_left", "skull").has_value());
  const std::vector<std::string> segments = map.bone_segments();
  EXPECT_EQ(std::set<std::string>(segments.begin(), segments.end()).size(), segments.size());
  EXPECT_EQ(segments.size(), 25u);
}

TEST(LabelMap, JsonRoundTripKeepsEverything) {
  const LabelMap map = totalsegmentator_v2_preset();
  Result<LabelMap> back = label_map_from_json(label_map_to_json(map), "round trip");
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  ASSERT_EQ(back->entries().size(), map.entries().size());
  for (size_t i = 0; i < map.entries().size(); ++i) {
    EXPECT_EQ(back->entries()[i].value, map.entries()[i].value);
    EXPECT_EQ(back->entries()[i].name, map.entries()[i].name);
    EXPECT_EQ(back->entries()[i].role, map.entries()[i].role);
    EXPECT_EQ(back->entries()[i].segment, map.entries()[i].segment);
  }
  EXPECT_EQ(back->joint_names().size(), map.joint_names().size());
  EXPECT_EQ(back->root_segment(), "sacrum");
}

TEST(LabelMap, BoneWithoutSegmentIsItsOwnSegment) {
  Result<LabelMap> map = label_map_from_json(
      R"({"labels": [{"value": 3, "name": "tibia", "role": "bone"}, {"value": 1, "name": "muscle"}]})", "inline");
  ASSERT_TRUE(map.ok()) << map.status().to_string();
  EXPECT_EQ(map->find(3)->segment, "tibia");
  EXPECT_EQ(map->find(1)->role, LabelRole::kTissue);
  EXPECT_EQ(map->role_of(99), LabelRole::kTissue);
  EXPECT_EQ(map->role_of(0), LabelRole::kBackground);
}

TEST(LabelMap, DuplicatedValuesAreReportedWithBothNames) {
  Result<LabelMap> map = label_map_from_json(
      R"({"labels": [{"value": 3, "name": "tibia", "role": "bone"}, {"value": 3, "name": "fibula", "role": "bone"}]})",
      "dup.json");
  ASSERT_FALSE(map.ok());
  EXPECT_EQ(map.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(map.status().message().find("tibia"), std::string::npos);
  EXPECT_NE(map.status().message().find("fibula"), std::string::npos);
  EXPECT_NE(map.status().message().find("dup.json"), std::string::npos);
}

TEST(LabelMap, MalformedMapsGiveClearErrors) {
  const std::vector<std::pair<std::string, std::string>> cases{
      {"{not json", "not valid JSON"},
      {R"({"labels": [{"value": 1, "name": "x", "role": "cartilage"}]})", "unknown label role"},
      {R"({"labels": [{"name": "x"}]})", "integer \"value\""},
      {R"({"labels": [{"value": 0, "name": "body", "role": "tissue"}]})", "must have role background"},
      {R"({"labels": [{"value": 1, "name": "", "role": "bone"}]})", "has no name"},
      {R"({"version": 7, "labels": []})", "Upgrade posewarp"},
      {R"({"labels": [{"value": 1, "name": "a", "role": "bone"}], "joints": [{"name": "j", "segments": ["a", "b"]}]})",
       "segment 'b'"},
      {R"({"labels": [{"value": 1, "name": "a", "role": "bone"}], "root_segment": "pelvis"})", "root segment"},
      {R"({"labels": {"value": 1}})", "\"labels\" array"},
      {R"({"name": "a", "name": "b", "labels": []})", "\"name\" appears twice"},  // the strict reader of every input
  };
  for (const auto& [text, expected] : cases) {
    Result<LabelMap> map = label_map_from_json(text, "case");
    ASSERT_FALSE(map.ok()) << text;
    EXPECT_EQ(map.status().code(), StatusCode::kInvalidArgument) << text;
    EXPECT_NE(map.status().message().find(expected), std::string::npos) << map.status().message();
  }
}

TEST(LabelMap, FilesAreReadAndWritten) {
  ScratchDir dir;
  ASSERT_TRUE(write_label_map(totalsegmentator_v2_preset(), dir.file("ts.json")).ok());
  Result<LabelMap> back = read_label_map(dir.file("ts.json"));
  ASSERT_TRUE(back.ok());
  EXPECT_EQ(back->entries().size(), 118u);
  EXPECT_EQ(read_label_map(dir.file("missing.json")).status().code(), StatusCode::kNotFound);
}

TEST(Census, ReportsUnknownAndAbsentLabelsAndSegments) {
  Result<LabelMap> map = label_map_from_json(
      R"({"labels": [{"value": 1, "name": "muscle"}, {"value": 2, "name": "femur", "role": "bone"},
                     {"value": 3, "name": "tibia", "role": "bone"}, {"value": 4, "name": "fat"}]})",
      "inline");
  ASSERT_TRUE(map.ok());
  ImageGeometry g;
  g.size = {4, 1, 1};
  LabelVolume volume(g, 0);
  volume.data()[1] = 1;
  volume.data()[2] = 2;
  volume.data()[3] = 9;
  const LabelCensus c = census(*map, volume);
  EXPECT_EQ(c.voxel_counts.at(0), 1);
  EXPECT_EQ(c.voxel_counts.at(2), 1);
  EXPECT_EQ(c.unknown, (std::vector<Label>{9}));
  EXPECT_EQ(c.absent, (std::vector<Label>{3, 4}));
  EXPECT_EQ(c.present_bone_segments, (std::vector<std::string>{"femur"}));
  EXPECT_EQ(c.absent_bone_segments, (std::vector<std::string>{"tibia"}));
}

}  // namespace
}  // namespace posewarp::labels

namespace posewarp::labels {
namespace {

// Found by fuzzing (tests/fuzz): a number too large for a double escaped as an exception and aborted.
TEST(LabelMapJson, NumbersPastADoubleAreAnErrorNotACrash) {
  for (const char* text : {"66666666E66666666666666666666", R"({"labels": [{"value": 1e999, "name": "x"}]})"}) {
    const Status status = label_map_from_json(text, "huge").status();
    EXPECT_EQ(status.code(), StatusCode::kInvalidArgument) << text;
  }
}

}  // namespace
}  // namespace posewarp::labels

namespace posewarp::labels {
namespace {

// A DICOM SEG numbers its segments 1, 2, 3, ... and names them: the preset's meaning follows the names.
TEST(RelabelByName, APresetFollowsSegmentNamesToNewValues) {
  const LabelMap preset = *preset_by_name("totalsegmentator");
  std::vector<std::string> unknown;
  Result<LabelMap> map = relabel_by_name(preset, {{1, "Femur Left"}, {2, "hip-left"}, {3, "tumour"}}, &unknown);
  ASSERT_TRUE(map.ok()) << map.status().to_string();
  ASSERT_NE(map->find(1), nullptr);
  EXPECT_EQ(map->find(1)->name, "femur_left");
  EXPECT_EQ(map->role_of(1), LabelRole::kBone);
  EXPECT_EQ(map->role_of(2), LabelRole::kBone);
  EXPECT_EQ(map->role_of(3), LabelRole::kTissue);
  EXPECT_EQ(unknown, std::vector<std::string>{"tumour"});
  // The hip joint between the two segments present stays; joints to absent segments go.
  EXPECT_NE(map->declared_joint("hip_left", "femur_left"), nullptr);
  EXPECT_EQ(map->declared_joint("hip_right", "femur_right"), nullptr);
  EXPECT_EQ(map->find(75), nullptr);  // the preset's own value for femur_left is gone
  EXPECT_FALSE(relabel_by_name(preset, {{0, "femur_left"}}).ok());
}

}  // namespace
}  // namespace posewarp::labels
