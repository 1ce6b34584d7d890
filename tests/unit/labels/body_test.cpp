#include "posewarp/labels/body.h"

#include <gtest/gtest.h>

#include "posewarp/io/volume_io.h"
#include "posewarp/labels/presets.h"

namespace posewarp::labels {
namespace {

LabelMap two_bone_map() {
  return *LabelMap::create("test", {{0, "background", LabelRole::kBackground, ""},
                                    {1, "organ", LabelRole::kTissue, ""},
                                    {5, "femur", LabelRole::kBone, "leg"},
                                    {6, "patella", LabelRole::kBone, "leg"},
                                    {7, "tibia", LabelRole::kBone, "shank"}});
}

// A 20^3 grid: a CT "body" block with an enclosed air pocket, a separate "table" slab, labels inside.
struct Scene {
  LabelVolume labels;
  IntensityVolume ct;
};

Scene make_scene() {
  ImageGeometry g;
  g.size = {20, 20, 20};
  Scene s{LabelVolume(g, 0), IntensityVolume(g, -1000.0f)};
  for (int k = 2; k < 18; ++k)
    for (int j = 2; j < 14; ++j)
      for (int i = 2; i < 18; ++i) s.ct.at(i, j, k) = 40.0f;
  for (int k = 8; k < 11; ++k)
    for (int j = 6; j < 9; ++j)
      for (int i = 8; i < 11; ++i) s.ct.at(i, j, k) = -900.0f;  // bowel gas, enclosed
  for (int k = 0; k < 20; ++k)
    for (int i = 0; i < 20; ++i) s.ct.at(i, 17, k) = 200.0f;  // the table, not touching the body
  s.labels.at(4, 4, 4) = 5;
  s.labels.at(5, 4, 4) = 6;
  s.labels.at(12, 12, 12) = 7;
  s.labels.at(9, 7, 9) = 1;  // an organ label inside the gas pocket
  return s;
}

TEST(BodyMask, JoinsCtAndLabelsDropsTheTableAndFillsHoles) {
  const Scene s = make_scene();
  Result<LabelVolume> body = body_mask(two_bone_map(), s.labels, &s.ct);
  ASSERT_TRUE(body.ok()) << body.status().to_string();
  EXPECT_EQ(body->at(3, 3, 3), 1);
  EXPECT_EQ(body->at(9, 7, 9), 1);   // enclosed gas filled
  EXPECT_EQ(body->at(8, 6, 8), 1);
  EXPECT_EQ(body->at(5, 17, 5), 0);  // table dropped
  EXPECT_EQ(body->at(0, 0, 0), 0);
  int64_t inside = 0;
  for (const Label v : body->voxels()) inside += v;
  EXPECT_EQ(inside, 16 * 12 * 16);
}

TEST(BodyMask, WithoutCtTheBodyIsTheLabelledVoxels) {
  const Scene s = make_scene();
  BodyParams params;
  params.fill_holes = false;
  Result<LabelVolume> body = body_mask(two_bone_map(), s.labels, nullptr, params);
  ASSERT_TRUE(body.ok());
  int64_t inside = 0;
  for (const Label v : body->voxels()) inside += v;
  EXPECT_EQ(inside, 4);
}

TEST(BodyMask, CtOnAnotherGridIsRefused) {
  const Scene s = make_scene();
  IntensityVolume shifted = s.ct;
  ImageGeometry g = shifted.geometry();
  g.origin[0] += 5.0;
  shifted.set_placement(g);
  Result<LabelVolume> body = body_mask(two_bone_map(), s.labels, &shifted);
  EXPECT_EQ(body.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(body.status().message().find("same grid"), std::string::npos);
}

TEST(SegmentClasses, BonesGetTwoPlusSegmentIndexAndSoftTissueOne) {
  const Scene s = make_scene();
  const LabelMap map = two_bone_map();
  Result<LabelVolume> body = body_mask(map, s.labels, &s.ct);
  ASSERT_TRUE(body.ok());
  const LabelVolume classes = segment_classes(map, s.labels, *body);
  EXPECT_EQ(classes.at(4, 4, 4), 2);  // femur -> segment "leg" (k = 0)
  EXPECT_EQ(classes.at(5, 4, 4), 2);  // patella -> "leg" as well
  EXPECT_EQ(classes.at(12, 12, 12), 3);
  EXPECT_EQ(classes.at(9, 7, 9), 1);
  EXPECT_EQ(classes.at(3, 3, 3), 1);
  EXPECT_EQ(classes.at(0, 0, 0), 0);
}

TEST(BodyMask, RealSampleBodyMatchesItsReadme) {
  const std::string dir = POSEWARP_SAMPLE_DIR;
  Result<LabelVolume> seg = io::read_label_volume(dir + "/seg_total.nii.gz");
  Result<IntensityVolume> ct = io::read_intensity_volume(dir + "/ct.nii.gz");
  ASSERT_TRUE(seg.ok() && ct.ok());
  Result<LabelVolume> body = body_mask(totalsegmentator_v2_preset(), *seg, &*ct);
  ASSERT_TRUE(body.ok());
  int64_t inside = 0;
  for (const Label v : body->voxels()) inside += v;
  // The sample's README: "HU > -500, largest connected component, holes filled, union with all labels gives ~896k".
  EXPECT_NEAR(static_cast<double>(inside), 896000.0, 10000.0);
}

}  // namespace
}  // namespace posewarp::labels
