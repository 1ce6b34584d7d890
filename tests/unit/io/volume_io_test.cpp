#include "posewarp/io/volume_io.h"

#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>

#include "test_support.h"

namespace posewarp::io {
namespace {

using posewarp::testing::expect_same_geometry;
using posewarp::testing::patterned_intensities;
using posewarp::testing::patterned_labels;
using posewarp::testing::ScratchDir;
using posewarp::testing::small_oblique_grid;

struct LabelCase {
  std::string extension;
  PixelType type;
  std::vector<Label> values;
};

class LabelRoundTrip : public ::testing::TestWithParam<LabelCase> {};

TEST_P(LabelRoundTrip, KeepsEveryVoxelTheTypeAndTheObliqueGeometry) {
  const LabelCase& c = GetParam();
  ScratchDir dir;
  LabelVolume labels = patterned_labels(small_oblique_grid(), c.values);
  labels.set_source_type(c.type);
  const std::string path = dir.file("labels" + c.extension);
  ASSERT_TRUE(write_volume(labels, path).ok());
  Result<LabelVolume> back = read_label_volume(path);
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  EXPECT_EQ(back->source_type(), c.type);
  expect_same_geometry(back->geometry(), labels.geometry());
  EXPECT_EQ(back->voxels(), labels.voxels());
}

std::string case_name(const ::testing::TestParamInfo<LabelCase>& info) {
  std::string name = info.param.extension + "_" + std::string(pixel_type_name(info.param.type));
  for (char& ch : name) {
    if (!std::isalnum(static_cast<unsigned char>(ch))) ch = '_';
  }
  return name;
}

INSTANTIATE_TEST_SUITE_P(
    EveryFormatAndLabelType, LabelRoundTrip,
    ::testing::Values(LabelCase{".nii", PixelType::kUInt8, {0, 1, 2, 255}},
                      LabelCase{".nii.gz", PixelType::kUInt16, {0, 7, 300, 65535}},
                      LabelCase{".nii.gz", PixelType::kInt16, {-5, 0, 117, 32767}},
                      LabelCase{".nii.gz", PixelType::kInt32, {0, 1, 70000, -70000}},
                      LabelCase{".nrrd", PixelType::kUInt8, {0, 10, 20}},
                      LabelCase{".nhdr", PixelType::kUInt16, {0, 1000}},
                      LabelCase{".nrrd", PixelType::kInt32, {0, 123456}},
                      LabelCase{".mha", PixelType::kUInt8, {0, 3, 5}},
                      LabelCase{".mhd", PixelType::kInt16, {0, -2, 900}},
                      LabelCase{".mha", PixelType::kInt32, {0, 99999}},
                      LabelCase{"", PixelType::kUInt8, {0, 1, 2, 200}},
                      LabelCase{"", PixelType::kUInt16, {0, 4000}},
                      LabelCase{"", PixelType::kInt16, {0, -3, 3}}),
    case_name);

struct IntensityCase {
  std::string extension;
  PixelType type;
};

class IntensityRoundTrip : public ::testing::TestWithParam<IntensityCase> {};

TEST_P(IntensityRoundTrip, KeepsValuesAndGeometry) {
  const IntensityCase& c = GetParam();
  ScratchDir dir;
  const bool integral = !is_floating(c.type);
  IntensityVolume ct = patterned_intensities(small_oblique_grid(), -1024.0f, 3071.0f, integral);
  ct.set_source_type(c.type);
  const std::string path = dir.file("ct" + c.extension);
  ASSERT_TRUE(write_volume(ct, path).ok());
  Result<IntensityVolume> back = read_intensity_volume(path);
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  EXPECT_EQ(back->source_type(), c.type);
  expect_same_geometry(back->geometry(), ct.geometry());
  ASSERT_EQ(back->voxel_count(), ct.voxel_count());
  for (int64_t v = 0; v < ct.voxel_count(); ++v) ASSERT_FLOAT_EQ(back->data()[v], ct.data()[v]) << "voxel " << v;
}

std::string intensity_case_name(const ::testing::TestParamInfo<IntensityCase>& info) {
  std::string name = (info.param.extension.empty() ? std::string("dicom") : info.param.extension) + "_" +
                     std::string(pixel_type_name(info.param.type));
  for (char& ch : name) {
    if (!std::isalnum(static_cast<unsigned char>(ch))) ch = '_';
  }
  return name;
}

INSTANTIATE_TEST_SUITE_P(EveryFormatAndIntensityType, IntensityRoundTrip,
                         ::testing::Values(IntensityCase{".nii.gz", PixelType::kInt16},
                                           IntensityCase{".nii", PixelType::kInt32},
                                           IntensityCase{".nii.gz", PixelType::kFloat32},
                                           IntensityCase{".nrrd", PixelType::kInt16},
                                           IntensityCase{".nrrd", PixelType::kFloat32},
                                           IntensityCase{".mha", PixelType::kInt32},
                                           IntensityCase{".mhd", PixelType::kFloat32},
                                           IntensityCase{"", PixelType::kInt16}),
                         intensity_case_name);

TEST(VolumeIo, HeaderIsReadWithoutTheVoxels) {
  ScratchDir dir;
  LabelVolume labels = patterned_labels(small_oblique_grid(), {0, 1});
  labels.set_source_type(PixelType::kUInt8);
  ASSERT_TRUE(write_volume(labels, dir.file("l.nrrd")).ok());
  Result<VolumeHeader> header = read_header(dir.file("l.nrrd"));
  ASSERT_TRUE(header.ok()) << header.status().to_string();
  EXPECT_EQ(header->format, VolumeFormat::kNrrd);
  EXPECT_EQ(header->pixel_type, PixelType::kUInt8);
  expect_same_geometry(header->geometry, labels.geometry());
}

TEST(VolumeIo, WritingReplacesAtomicallyAndLeavesNoPartialFiles) {
  ScratchDir dir;
  LabelVolume labels = patterned_labels(small_oblique_grid(), {0, 1});
  ASSERT_TRUE(write_volume(labels, dir.file("l.nii.gz")).ok());
  ASSERT_TRUE(write_volume(labels, dir.file("l.nii.gz")).ok());
  int files = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir.path())) {
    ++files;
    EXPECT_EQ(entry.path().filename(), "l.nii.gz");
  }
  EXPECT_EQ(files, 1);
}

TEST(VolumeIo, OutputTypeCanBeChosenAndValuesThatDoNotFitAreRefused) {
  ScratchDir dir;
  LabelVolume labels = patterned_labels(small_oblique_grid(), {0, 300});
  WriteOptions as_uint8;
  as_uint8.pixel_type = PixelType::kUInt8;
  const Status refused = write_volume(labels, dir.file("l.nii.gz"), as_uint8);
  EXPECT_EQ(refused.code(), StatusCode::kOutOfRange);
  EXPECT_NE(refused.message().find("uint8"), std::string::npos);
  EXPECT_NE(refused.message().find("span 0..300"), std::string::npos) << refused.to_string();
  EXPECT_FALSE(std::filesystem::exists(dir.file("l.nii.gz")));
  // NIfTI checks the values as it converts them: a refused write leaves no partial file behind, in either form,
  // and the other writers refuse the same way before they write.
  for (const char* name : {"l.nii", "l.nrrd"}) {
    const Status also = write_volume(labels, dir.file(name), as_uint8);
    EXPECT_EQ(also.code(), StatusCode::kOutOfRange) << name;
    EXPECT_NE(also.message().find("span 0..300"), std::string::npos) << also.to_string();
  }
  EXPECT_TRUE(std::filesystem::is_empty(dir.path()));
  IntensityVolume ct = patterned_intensities(small_oblique_grid(), -1000.0f, 1000.0f, false);
  ct.data()[ct.voxel_count() / 2] = std::nanf("");
  WriteOptions as_int16;
  as_int16.pixel_type = PixelType::kInt16;
  const Status not_a_number = write_volume(ct, dir.file("c.nii.gz"), as_int16);
  EXPECT_EQ(not_a_number.code(), StatusCode::kOutOfRange);
  EXPECT_NE(not_a_number.message().find("NaN"), std::string::npos) << not_a_number.to_string();
  EXPECT_TRUE(std::filesystem::is_empty(dir.path()));
  WriteOptions as_uint16;
  as_uint16.pixel_type = PixelType::kUInt16;
  ASSERT_TRUE(write_volume(labels, dir.file("l.nii.gz"), as_uint16).ok());
  EXPECT_EQ(read_label_volume(dir.file("l.nii.gz"))->source_type(), PixelType::kUInt16);
}

TEST(VolumeIo, FloatLabelFilesWithIntegerValuesAreAccepted) {
  ScratchDir dir;
  IntensityVolume as_float = patterned_intensities(small_oblique_grid(), 0.0f, 40.0f, true);
  ASSERT_TRUE(write_volume(as_float, dir.file("float_labels.nii.gz")).ok());
  Result<LabelVolume> labels = read_label_volume(dir.file("float_labels.nii.gz"));
  ASSERT_TRUE(labels.ok()) << labels.status().to_string();
  EXPECT_EQ(labels->source_type(), PixelType::kFloat32);
  for (int64_t v = 0; v < labels->voxel_count(); ++v) {
    ASSERT_EQ(labels->data()[v], static_cast<Label>(as_float.data()[v]));
  }
}

TEST(VolumeIo, FormatComesFromTheExtension) {
  EXPECT_EQ(*format_from_path("a.nii.gz"), VolumeFormat::kNifti);
  EXPECT_EQ(*format_from_path("a.NII"), VolumeFormat::kNifti);
  EXPECT_EQ(*format_from_path("a.nhdr"), VolumeFormat::kNrrd);
  EXPECT_EQ(*format_from_path("a.mhd"), VolumeFormat::kMetaImage);
  EXPECT_EQ(*format_from_path("series_dir"), VolumeFormat::kDicomSeries);
  EXPECT_EQ(format_from_path("a.png").status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(format_from_path("slice.dcm").status().code(), StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace posewarp::io
