// Volumes encoded in memory (NIfTI-1, NRRD) read back through ITK as the files they claim to be.
#include <gtest/gtest.h>

#include <limits>

#include "posewarp/io/volume_io.h"
#include "test_support.h"

namespace posewarp::io {
namespace {

using posewarp::testing::expect_same_geometry;
using posewarp::testing::patterned_intensities;
using posewarp::testing::patterned_labels;
using posewarp::testing::ScratchDir;
using posewarp::testing::small_oblique_grid;
using posewarp::testing::write_bytes;

struct Encoding {
  VolumeFormat format;
  bool gzip;
  std::string extension;
};

class EncodedVolume : public ::testing::TestWithParam<Encoding> {};

// A grid whose third axis points against the first two's cross product (NIfTI's qfac = -1).
ImageGeometry left_handed_grid() {
  ImageGeometry g = small_oblique_grid();
  for (int r = 0; r < 3; ++r) g.direction[static_cast<size_t>(3 * r + 2)] *= -1.0;
  return g;
}

TEST_P(EncodedVolume, LabelsReadBackWithTheirTypeValuesAndObliqueGeometry) {
  const Encoding& e = GetParam();
  ScratchDir dir;
  for (const ImageGeometry& grid : {small_oblique_grid(), left_handed_grid()}) {
    for (const auto& [type, values] : std::vector<std::pair<PixelType, std::vector<Label>>>{
             {PixelType::kUInt8, {0, 1, 2, 255}}, {PixelType::kUInt16, {0, 7, 300, 65535}},
             {PixelType::kInt16, {-5, 0, 117, 32767}}, {PixelType::kInt32, {0, 70000, -70000}}}) {
      LabelVolume labels = patterned_labels(grid, values);
      labels.set_source_type(type);
      Result<std::string> bytes = encode_volume(labels, e.format, e.gzip);
      ASSERT_TRUE(bytes.ok()) << bytes.status().to_string();
      const std::string path = dir.file("labels" + e.extension);
      write_bytes(path, *bytes);
      Result<LabelVolume> back = read_label_volume(path);
      ASSERT_TRUE(back.ok()) << back.status().to_string();
      EXPECT_EQ(back->source_type(), type);
      expect_same_geometry(back->geometry(), labels.geometry());
      EXPECT_EQ(back->voxels(), labels.voxels());
    }
  }
}

TEST_P(EncodedVolume, IntensitiesAreRoundedToTheirIntegerTypeAsFilesAre) {
  const Encoding& e = GetParam();
  ScratchDir dir;
  IntensityVolume ct = patterned_intensities(small_oblique_grid(), -1024.0f, 1800.0f, false);
  ct.set_source_type(PixelType::kInt16);
  Result<std::string> bytes = encode_volume(ct, e.format, e.gzip);
  ASSERT_TRUE(bytes.ok()) << bytes.status().to_string();
  write_bytes(dir.file("ct" + e.extension), *bytes);
  ASSERT_TRUE(write_volume(ct, dir.file("ct_itk.nrrd")).ok());
  Result<IntensityVolume> back = read_intensity_volume(dir.file("ct" + e.extension));
  Result<IntensityVolume> written = read_intensity_volume(dir.file("ct_itk.nrrd"));
  ASSERT_TRUE(back.ok() && written.ok());
  EXPECT_EQ(back->source_type(), PixelType::kInt16);
  EXPECT_EQ(back->voxels(), written->voxels());  // the same values write_volume stores

  Result<std::string> floats = encode_volume(ct, e.format, e.gzip, PixelType::kFloat32);
  ASSERT_TRUE(floats.ok());
  write_bytes(dir.file("ct_float" + e.extension), *floats);
  Result<IntensityVolume> exact = read_intensity_volume(dir.file("ct_float" + e.extension));
  ASSERT_TRUE(exact.ok());
  EXPECT_EQ(exact->voxels(), ct.voxels());
}

INSTANTIATE_TEST_SUITE_P(NiftiAndNrrd, EncodedVolume,
                         ::testing::Values(Encoding{VolumeFormat::kNifti, false, ".nii"},
                                           Encoding{VolumeFormat::kNifti, true, ".nii.gz"},
                                           Encoding{VolumeFormat::kNrrd, false, ".nrrd"},
                                           Encoding{VolumeFormat::kNrrd, true, ".nrrd"}),
                         [](const ::testing::TestParamInfo<Encoding>& param_info) {
                           return std::string(param_info.param.format == VolumeFormat::kNifti ? "nifti" : "nrrd") +
                                  (param_info.param.gzip ? "_gzip" : "_raw");
                         });

TEST(EncodeVolume, RefusesValuesThatDoNotFitAndFormatsItCannotMakeInMemory) {
  LabelVolume labels = patterned_labels(small_oblique_grid(), {0, 300});
  labels.set_source_type(PixelType::kUInt8);
  EXPECT_EQ(encode_volume(labels, VolumeFormat::kNifti, true).status().code(), StatusCode::kOutOfRange);
  labels.set_source_type(PixelType::kUInt16);
  EXPECT_EQ(encode_volume(labels, VolumeFormat::kMetaImage, false).status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(encode_volume(LabelVolume(), VolumeFormat::kNrrd, false).status().code(), StatusCode::kInvalidArgument);
}

TEST(ConvertSamples, RoundsLikeFilesAndSaysWhenAValueDoesNotFit) {
  const float in[] = {-1.5f, -0.5f, 0.49f, 2.5f, 32767.4f};
  int16_t out[5];
  EXPECT_TRUE(convert_samples(in, 5, PixelType::kInt16, reinterpret_cast<char*>(out)));
  EXPECT_EQ(out[0], -2);
  EXPECT_EQ(out[1], -1);
  EXPECT_EQ(out[2], 0);
  EXPECT_EQ(out[3], 3);
  EXPECT_EQ(out[4], 32767);
  const float outside[] = {-32768.4f, -32768.6f, std::numeric_limits<float>::quiet_NaN()};
  EXPECT_TRUE(convert_samples(outside, 1, PixelType::kInt16, reinterpret_cast<char*>(out)));
  EXPECT_EQ(out[0], -32768);
  EXPECT_FALSE(convert_samples(outside + 1, 1, PixelType::kInt16, reinterpret_cast<char*>(out)));
  EXPECT_FALSE(convert_samples(outside + 2, 1, PixelType::kInt16, reinterpret_cast<char*>(out)));
  const int32_t labels[] = {0, 255, 256};
  uint8_t narrow[3];
  EXPECT_FALSE(convert_samples(labels, 3, PixelType::kUInt8, reinterpret_cast<char*>(narrow)));
  EXPECT_TRUE(convert_samples(labels, 2, PixelType::kUInt8, reinterpret_cast<char*>(narrow)));
  EXPECT_EQ(narrow[1], 255);
}

}  // namespace
}  // namespace posewarp::io
