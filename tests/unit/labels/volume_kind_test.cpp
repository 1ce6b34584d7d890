#include "posewarp/labels/volume_kind.h"

#include <gtest/gtest.h>

namespace posewarp::labels {
namespace {

LabelMap small_map() {
  return *LabelMap::create("small", {{0, "background", LabelRole::kBackground, ""},
                                     {1, "femur", LabelRole::kBone, "femur"},
                                     {2, "tibia", LabelRole::kBone, "tibia"},
                                     {7, "muscle", LabelRole::kTissue, ""}});
}

ImageGeometry grid(int64_t nx) {
  ImageGeometry g;
  g.size = {nx, 4, 3};
  return g;
}

void expect_invalid(const Status& status, const std::vector<std::string>& fragments) {
  EXPECT_EQ(status.code(), StatusCode::kInvalidArgument) << status.to_string();
  for (const std::string& fragment : fragments) {
    EXPECT_NE(status.message().find(fragment), std::string::npos)
        << "message lacks \"" << fragment << "\": " << status.message();
  }
}

TEST(VolumeKind, LabelsWithAThousandValuesAreLabelsAndMoreAreAnIntensityVolume) {
  LabelVolume labels(grid(100), 0);
  for (int64_t v = 0; v < labels.voxel_count(); ++v) labels.data()[v] = static_cast<Label>(v % 1000);
  EXPECT_TRUE(check_labels_look_like_labels(labels, "the labels 'seg.nii.gz'").ok());
  // An intensity volume stored shifted (air at 0): a thousand and one values.
  labels.data()[1] = 1500;
  expect_invalid(check_labels_look_like_labels(labels, "the labels 'ct.nii.gz'", "the CT 'seg.nii.gz'"),
                 {"the labels 'ct.nii.gz' holds more than 1000 distinct values",
                  "looks like an intensity volume (CT/MRI) given as the labels", "the CT 'seg.nii.gz'", "swapped"});
}

TEST(VolumeKind, LabelsBelowMinusOneHundredAreAnIntensityVolume) {
  // A CT in HU read as labels holds few values when it is a phantom, but always its air.
  LabelVolume labels(grid(10), 40);
  labels.data()[5] = kMinLabelValue;
  EXPECT_TRUE(check_labels_look_like_labels(labels, "the labels").ok());
  labels.data()[7] = -1000;
  expect_invalid(check_labels_look_like_labels(labels, "the labels 'ct.nii.gz'"),
                 {"the labels 'ct.nii.gz' holds the value -1000", "none below -100", "given as the labels"});
}

TEST(VolumeKind, LabelsGivenAsTheCtAreRefusedNamingBoth) {
  const LabelMap map = small_map();
  IntensityVolume ct(grid(10), 0.0f);
  for (int64_t v = 0; v < ct.voxel_count(); ++v) ct.data()[v] = static_cast<float>((v / 7) % 3);  // 0, 1, 2
  expect_invalid(check_ct_is_not_labels(ct, map, "the CT 'seg.nii.gz'", "the labels 'ct.nii.gz'"),
                 {"the CT 'seg.nii.gz' holds only whole values that are 0 or labels the label map 'small' names",
                  "3 distinct: 0, 1, 2", "looks like a label volume given as the CT", "the labels 'ct.nii.gz'"});
  // No zero at all, only named values: still labels.
  std::fill(ct.voxels().begin(), ct.voxels().end(), 7.0f);
  ct.data()[3] = 2.0f;
  expect_invalid(check_ct_is_not_labels(ct, map, "the CT", "the labels"), {"2 distinct: 2, 7"});
}

TEST(VolumeKind, RealIntensitiesAndEmptyCtsAreNotLabels) {
  const LabelMap map = small_map();
  IntensityVolume ct(grid(10), 0.0f);
  EXPECT_TRUE(check_ct_is_not_labels(ct, map, "the CT", "the labels").ok());  // all zero: empty, not labels
  for (int64_t v = 0; v < ct.voxel_count(); ++v) ct.data()[v] = static_cast<float>(v % 3);
  ct.data()[ct.voxel_count() - 1] = -1000.0f;  // air: no label map names it
  EXPECT_TRUE(check_ct_is_not_labels(ct, map, "the CT", "the labels").ok());
  ct.data()[ct.voxel_count() - 1] = 1.5f;  // a fraction
  EXPECT_TRUE(check_ct_is_not_labels(ct, map, "the CT", "the labels").ok());
  ct.data()[ct.voxel_count() - 1] = 3.0f;  // whole, but not a label of this map
  EXPECT_TRUE(check_ct_is_not_labels(ct, map, "the CT", "the labels").ok());
}

}  // namespace
}  // namespace posewarp::labels
