// The real TotalSegmentator sample: its sform-only RAS header, its labels, and round trips in every format.
#include <gtest/gtest.h>

#include <set>

#include "posewarp/io/volume_io.h"
#include "test_support.h"

namespace posewarp::io {
namespace {

using posewarp::testing::expect_same_geometry;
using posewarp::testing::ScratchDir;

const std::string kSample = POSEWARP_SAMPLE_DIR;

TEST(RealSample, SformOnlyRasHeaderBecomesLpsGeometry) {
  Result<LabelVolume> seg = read_label_volume(kSample + "/seg_total.nii.gz");
  ASSERT_TRUE(seg.ok()) << seg.status().to_string();
  const ImageGeometry& g = seg->geometry();
  EXPECT_EQ(g.size, (Index3{122, 101, 112}));
  for (int a = 0; a < 3; ++a) EXPECT_NEAR(g.spacing[a], 3.0, 1e-4);
  // RAS axes on disk: in LPS the first two axes point the other way.
  EXPECT_NEAR(g.direction[0], -1.0, 1e-6);
  EXPECT_NEAR(g.direction[4], -1.0, 1e-6);
  EXPECT_NEAR(g.direction[8], 1.0, 1e-6);
  EXPECT_NEAR(g.origin[0], 177.956, 1e-2);
  EXPECT_NEAR(g.origin[1], -11.319, 1e-2);
  EXPECT_NEAR(g.origin[2], 94.302, 1e-2);
  EXPECT_EQ(seg->source_type(), PixelType::kUInt8);
  std::set<Label> present(seg->voxels().begin(), seg->voxels().end());
  present.erase(0);
  EXPECT_EQ(present.size(), 61u);  // as the sample's README says
}

TEST(RealSample, CtAndLabelsShareTheGrid) {
  Result<IntensityVolume> ct = read_intensity_volume(kSample + "/ct.nii.gz");
  Result<LabelVolume> seg = read_label_volume(kSample + "/seg_total.nii.gz");
  ASSERT_TRUE(ct.ok() && seg.ok());
  EXPECT_TRUE(ct->geometry().same_grid(seg->geometry()));
  EXPECT_EQ(ct->source_type(), PixelType::kInt32);
  int metal = 0;
  for (const float hu : ct->voxels()) metal += hu > 2000.0f;
  EXPECT_GT(metal, 500);  // the left femur's implant
}

class SampleRoundTrip : public ::testing::TestWithParam<std::string> {};

TEST_P(SampleRoundTrip, LabelsAndCtSurviveVoxelForVoxel) {
  ScratchDir dir;
  Result<LabelVolume> seg = read_label_volume(kSample + "/seg_total.nii.gz");
  Result<IntensityVolume> ct = read_intensity_volume(kSample + "/ct.nii.gz");
  ASSERT_TRUE(seg.ok() && ct.ok());
  const std::string ext = GetParam();
  const std::string seg_path = dir.file("seg" + ext);
  const std::string ct_path = dir.file("ct" + ext);
  ASSERT_TRUE(write_volume(*seg, seg_path).ok());
  WriteOptions ct_options;
  if (ext.empty()) ct_options.pixel_type = PixelType::kInt16;  // DICOM CT is 16-bit
  ASSERT_TRUE(write_volume(*ct, ct_path, ct_options).ok());
  Result<LabelVolume> seg_back = read_label_volume(seg_path);
  Result<IntensityVolume> ct_back = read_intensity_volume(ct_path);
  ASSERT_TRUE(seg_back.ok()) << seg_back.status().to_string();
  ASSERT_TRUE(ct_back.ok()) << ct_back.status().to_string();
  expect_same_geometry(seg_back->geometry(), seg->geometry(), 1e-3);
  expect_same_geometry(ct_back->geometry(), ct->geometry(), 1e-3);
  EXPECT_EQ(seg_back->voxels(), seg->voxels());
  EXPECT_EQ(ct_back->voxels(), ct->voxels());
}

INSTANTIATE_TEST_SUITE_P(EveryFormat, SampleRoundTrip, ::testing::Values(".nii.gz", ".nii", ".nrrd", ".mha", ""),
                         [](const ::testing::TestParamInfo<std::string>& param_info) {
                           if (param_info.param.empty()) return std::string("dicom_series");
                           std::string name = param_info.param.substr(1);
                           for (char& c : name) {
                             if (c == '.') c = '_';
                           }
                           return name;
                         });

}  // namespace
}  // namespace posewarp::io
