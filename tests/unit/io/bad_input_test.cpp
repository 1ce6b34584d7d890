#include "posewarp/io/volume_io.h"

#include <gtest/gtest.h>

#include <sys/stat.h>
#include <zlib.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>

#include "test_support.h"

namespace posewarp::io {
namespace {

using posewarp::testing::patterned_intensities;
using posewarp::testing::patterned_labels;
using posewarp::testing::read_bytes;
using posewarp::testing::ScratchDir;
using posewarp::testing::small_oblique_grid;
using posewarp::testing::write_bytes;

// NIfTI-1 header offsets (nifti1.h).
constexpr size_t kDimOffset = 40;     // int16 dim[8]
constexpr size_t kPixdimOffset = 76;  // float pixdim[8]

std::string valid_nifti(const ScratchDir& dir, const std::string& name) {
  LabelVolume labels = patterned_labels(small_oblique_grid(), {0, 1, 2});
  labels.set_source_type(PixelType::kUInt8);
  const std::string path = dir.file(name);
  EXPECT_TRUE(write_volume(labels, path).ok());
  return path;
}

template <typename T>
void patch(std::string& bytes, size_t offset, T value) {
  std::memcpy(bytes.data() + offset, &value, sizeof(T));
}

// Every failure must name the file, so a user with many inputs knows which one is wrong.
void expect_error_naming(const Status& status, const std::string& path, StatusCode code) {
  EXPECT_EQ(status.code(), code) << status.to_string();
  EXPECT_NE(status.message().find(std::filesystem::path(path).filename().string()), std::string::npos)
      << status.to_string();
}

TEST(BadInput, MissingFileIsNotFound) {
  ScratchDir dir;
  expect_error_naming(read_label_volume(dir.file("nope.nii.gz")).status(), "nope.nii.gz", StatusCode::kNotFound);
  expect_error_naming(read_intensity_volume(dir.file("no_series")).status(), "no_series", StatusCode::kNotFound);
}

TEST(BadInput, EmptyFileIsRejected) {
  ScratchDir dir;
  write_bytes(dir.file("empty.nii"), "");
  expect_error_naming(read_label_volume(dir.file("empty.nii")).status(), "empty.nii", StatusCode::kInvalidArgument);
}

TEST(BadInput, GarbageIsNotAnImage) {
  ScratchDir dir;
  const std::string garbage(4096, '\x5a');
  for (const std::string name : {"garbage.nii", "garbage.nii.gz", "garbage.nrrd", "garbage.mha"}) {
    write_bytes(dir.file(name), garbage);
    const Status status = read_label_volume(dir.file(name)).status();
    EXPECT_FALSE(status.ok()) << name;
    EXPECT_NE(status.message().find(name), std::string::npos) << status.to_string();
  }
}

TEST(BadInput, ZeroAndNegativeDimensionsAreRejectedBeforeReading) {
  ScratchDir dir;
  const std::string path = valid_nifti(dir, "dims.nii");
  for (int16_t bad : {int16_t{0}, int16_t{-4}}) {
    std::string bytes = read_bytes(path);
    patch<int16_t>(bytes, kDimOffset + 2 * 2, bad);  // dim[2]
    write_bytes(dir.file("bad_dims.nii"), bytes);
    const Status status = read_label_volume(dir.file("bad_dims.nii")).status();
    expect_error_naming(status, "bad_dims.nii", StatusCode::kInvalidArgument);
    // Named by field, not ITK's "is not recognized as a NIFTI file".
    EXPECT_NE(status.message().find("dim[2] = " + std::to_string(bad)), std::string::npos) << status.to_string();
  }
  std::string bytes = read_bytes(path);
  patch<int16_t>(bytes, kDimOffset, int16_t{0});  // dim[0]
  write_bytes(dir.file("no_dims.nii"), bytes);
  const Status none = read_header(dir.file("no_dims.nii")).status();
  expect_error_naming(none, "no_dims.nii", StatusCode::kInvalidArgument);
  EXPECT_NE(none.message().find("dim[0] = 0"), std::string::npos) << none.to_string();
}

TEST(BadInput, AbsurdDimensionsNeverAllocate) {
  ScratchDir dir;
  std::string bytes = read_bytes(valid_nifti(dir, "huge.nii"));
  for (int d = 1; d <= 3; ++d) patch<int16_t>(bytes, kDimOffset + 2 * static_cast<size_t>(d), int16_t{30000});
  write_bytes(dir.file("huge.nii"), bytes);
  // 2.7e13 voxels: refused from the header alone (this test would run out of memory otherwise).
  const Status status = read_label_volume(dir.file("huge.nii")).status();
  EXPECT_EQ(status.code(), StatusCode::kResourceExhausted) << status.to_string();
  EXPECT_NE(status.message().find("huge.nii"), std::string::npos);
  EXPECT_NE(status.message().find("--max-voxels"), std::string::npos);
  // A server names its own option.
  ReadOptions server;
  server.voxel_limit_name = "the server's --max-volume-voxels";
  const Status named = read_header(dir.file("huge.nii"), server).status();
  EXPECT_EQ(named.code(), StatusCode::kResourceExhausted) << named.to_string();
  EXPECT_NE(named.message().find("(the server's --max-volume-voxels)"), std::string::npos) << named.to_string();
  EXPECT_EQ(named.message().find("--max-voxels"), std::string::npos) << named.to_string();
}

TEST(BadInput, ZeroOrNegativeSpacingIsRejected) {
  ScratchDir dir;
  const std::string path = valid_nifti(dir, "spacing.nii");
  for (float bad : {0.0f, -2.0f}) {
    // With the qform and sform in use (ITK said "orthonormal direction cosines") and without (pixdim alone).
    for (bool orientation : {true, false}) {
      std::string bytes = read_bytes(path);
      patch<float>(bytes, kPixdimOffset + 4 * 3, bad);  // pixdim[3]
      if (!orientation) {
        patch<int16_t>(bytes, 252, int16_t{0});  // qform_code 0: spacing from pixdim alone
        patch<int16_t>(bytes, 254, int16_t{0});  // sform_code 0
      }
      write_bytes(dir.file("bad_spacing.nii"), bytes);
      const Status status = read_label_volume(dir.file("bad_spacing.nii")).status();
      SCOPED_TRACE("spacing " + std::to_string(bad) + (orientation ? " with" : " without") + " qform/sform");
      expect_error_naming(status, "bad_spacing.nii", StatusCode::kInvalidArgument);
      EXPECT_NE(status.message().find("pixdim[3] = " + std::string(bad == 0.0f ? "0" : "-2")), std::string::npos)
          << status.to_string();
    }
  }
}

// MetaImage sizes and spacings are named by field too (ITK: "orthonormal direction cosines" for a zero spacing).
TEST(BadInput, MetaImageZeroSizeAndZeroOrNegativeSpacingAreNamedByField) {
  ScratchDir dir;
  auto mha = [](const std::string& dims, const std::string& spacing) {
    return "ObjectType = Image\nNDims = 3\nDimSize = " + dims + "\nElementSpacing = " + spacing +
           "\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n" + std::string(120, '\1');
  };
  struct Case {
    std::string name, bytes, says;
  };
  const std::vector<Case> cases{{"zero_size.mha", mha("6 0 4", "1 1 1"), "DimSize[1] = 0"},
                                {"zero_spacing.mha", mha("6 5 4", "1 0 1"), "ElementSpacing[1] = 0"},
                                {"negative_spacing.mha", mha("6 5 4", "1 1 -2.5"), "ElementSpacing[2] = -2.5"}};
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    write_bytes(dir.file(c.name), c.bytes);
    const Status status = read_header(dir.file(c.name)).status();
    expect_error_naming(status, c.name, StatusCode::kInvalidArgument);
    EXPECT_NE(status.message().find(c.says), std::string::npos) << status.to_string();
  }
  write_bytes(dir.file("fine.mha"), mha("6 5 4", "1 1 2.5"));
  EXPECT_TRUE(read_label_volume(dir.file("fine.mha")).ok());
}

TEST(BadInput, VoxelLimitIsConfigurable) {
  ScratchDir dir;
  const std::string path = valid_nifti(dir, "limit.nii");
  ReadOptions tight;
  tight.max_voxels = 100;
  expect_error_naming(read_label_volume(path, tight).status(), path, StatusCode::kResourceExhausted);
  ReadOptions roomy;
  roomy.max_voxels = 1000;
  EXPECT_TRUE(read_label_volume(path, roomy).ok());
}

TEST(BadInput, TruncatedUncompressedFileIsDataLoss) {
  ScratchDir dir;
  std::string bytes = read_bytes(valid_nifti(dir, "whole.nii"));
  bytes.resize(bytes.size() - 60);
  write_bytes(dir.file("cut.nii"), bytes);
  expect_error_naming(read_label_volume(dir.file("cut.nii")).status(), "cut.nii", StatusCode::kDataLoss);
}

TEST(BadInput, TruncatedCompressedFilesAreErrors) {
  ScratchDir dir;
  ImageGeometry g = small_oblique_grid();
  g.size = {64, 64, 64};
  IntensityVolume ct = patterned_intensities(g, -1000.0f, 2000.0f, true);
  ct.set_source_type(PixelType::kInt16);
  for (const std::string name : {"ct.nii.gz", "ct.nrrd", "ct.mha"}) {
    ASSERT_TRUE(write_volume(ct, dir.file(name)).ok());
    std::string bytes = read_bytes(dir.file(name));
    bytes.resize(bytes.size() / 2);
    write_bytes(dir.file("cut_" + name), bytes);
    const Status status = read_intensity_volume(dir.file("cut_" + name)).status();
    EXPECT_FALSE(status.ok()) << name;
    EXPECT_NE(status.message().find("cut_" + name), std::string::npos) << status.to_string();
  }
}

TEST(BadInput, FloatLabelsWithFractionsAreNotLabels) {
  ScratchDir dir;
  IntensityVolume ct = patterned_intensities(small_oblique_grid(), -10.0f, 10.0f, false);
  ASSERT_TRUE(write_volume(ct, dir.file("ct.nii.gz")).ok());
  const Status status = read_label_volume(dir.file("ct.nii.gz")).status();
  expect_error_naming(status, "ct.nii.gz", StatusCode::kInvalidArgument);
  EXPECT_NE(status.message().find("not an integer label"), std::string::npos);
}

// A NaN among float voxels was read as 0 from NIfTI (label 0, or water in a CT, silently).
TEST(BadInput, NanAmongFloatVoxelsIsRefused) {
  ScratchDir dir;
  IntensityVolume ct = patterned_intensities(small_oblique_grid(), 0.0f, 3.0f, false);
  for (int64_t v = 0; v < ct.voxel_count(); ++v) ct.data()[v] = std::round(ct.data()[v]);
  ct.data()[7] = std::nanf("");
  ct.set_source_type(PixelType::kFloat32);
  for (const char* name : {"nan.nii", "nan.nrrd", "nan.mha"}) {
    ASSERT_TRUE(write_volume(ct, dir.file(name)).ok());
    const Status status = read_label_volume(dir.file(name)).status();
    expect_error_naming(status, name, StatusCode::kInvalidArgument);
    EXPECT_NE(status.message().find("at voxel 7"), std::string::npos) << status.to_string();
    const Status intensities = read_intensity_volume(dir.file(name)).status();
    expect_error_naming(intensities, name, StatusCode::kInvalidArgument);
    EXPECT_NE(intensities.message().find("NaN or infinite value at voxel 7"), std::string::npos)
        << intensities.to_string();
  }
}

TEST(BadInput, FourDimensionalSeriesAndVectorImagesAreRefused) {
  ScratchDir dir;
  const std::string frames =
      "ObjectType = Image\nNDims = 4\nDimSize = 2 2 2 3\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n";
  write_bytes(dir.file("frames.mha"), frames + std::string(24, '\1'));
  const Status four_d = read_label_volume(dir.file("frames.mha")).status();
  expect_error_naming(four_d, "frames.mha", StatusCode::kInvalidArgument);
  EXPECT_NE(four_d.message().find("3 frames"), std::string::npos) << four_d.to_string();

  const std::string rgb =
      "ObjectType = Image\nNDims = 3\nDimSize = 2 2 2\nElementNumberOfChannels = 3\nElementType = MET_UCHAR\n"
      "ElementDataFile = LOCAL\n";
  write_bytes(dir.file("rgb.mha"), rgb + std::string(24, '\1'));
  const Status vector = read_label_volume(dir.file("rgb.mha")).status();
  expect_error_naming(vector, "rgb.mha", StatusCode::kInvalidArgument);
  EXPECT_NE(vector.message().find("components"), std::string::npos) << vector.to_string();
}

TEST(BadInput, DicomDirectoryWithoutSeries) {
  ScratchDir dir;
  std::filesystem::create_directories(dir.file("empty_series"));
  write_bytes(dir.file("empty_series/readme.txt"), "not dicom");
  expect_error_naming(read_label_volume(dir.file("empty_series")).status(), "empty_series", StatusCode::kNotFound);
}

TEST(BadInput, DicomRefusesWhatItCannotStore) {
  ScratchDir dir;
  IntensityVolume ct = patterned_intensities(small_oblique_grid(), -10.0f, 10.0f, false);
  EXPECT_EQ(write_volume(ct, dir.file("float_series")).code(), StatusCode::kInvalidArgument);

  LabelVolume labels = patterned_labels(small_oblique_grid(), {0, 1});
  labels.set_source_type(PixelType::kUInt8);
  ImageGeometry mirrored = labels.geometry();
  for (int r = 0; r < 3; ++r) mirrored.direction[3 * r + 2] *= -1.0;  // left-handed
  labels.set_placement(mirrored);
  EXPECT_EQ(write_volume(labels, dir.file("left_handed")).code(), StatusCode::kInvalidArgument);

  LabelVolume fine = patterned_labels(small_oblique_grid(), {0, 1});
  fine.set_source_type(PixelType::kUInt8);
  ASSERT_TRUE(write_volume(fine, dir.file("series")).ok());
  EXPECT_EQ(write_volume(fine, dir.file("series")).code(), StatusCode::kAlreadyExists);
}

TEST(BadInput, EmptyVolumeIsNotWritten) {
  ScratchDir dir;
  EXPECT_EQ(write_volume(LabelVolume(), dir.file("empty.nii.gz")).code(), StatusCode::kInvalidArgument);
  EXPECT_FALSE(std::filesystem::exists(dir.file("empty.nii.gz")));
}

}  // namespace
}  // namespace posewarp::io

namespace posewarp::io {
namespace {

// NIfTI-1 header offsets (nifti1.h) of the geometry ITK would otherwise take as it is.
constexpr size_t kVoxOffset = 108;   // float vox_offset
constexpr size_t kSformCode = 254;   // int16 sform_code
constexpr size_t kSrowX = 280;       // float srow_x[4]

TEST(BadInput, NonFiniteOrEmptySformAndNegativeOffsetAreRefusedBeforeItk) {
  ScratchDir dir;
  const std::string good = read_bytes(valid_nifti(dir, "good.nii"));
  struct Case {
    std::string name;
    size_t offset;
    float value;
    std::string says;
  };
  const std::vector<Case> cases{{"nan_sform.nii", kSrowX, std::nanf(""), "srow_x"},
                                {"inf_qoffset.nii", 268, INFINITY, "qoffset"},
                                {"nan_pixdim.nii", kPixdimOffset + 4, std::nanf(""), "pixdim"},
                                {"negative_offset.nii", kVoxOffset, -352.0f, "vox_offset"},
                                // found by fuzzing: converting 3e38 to an integer is undefined behaviour
                                {"huge_offset.nii", kVoxOffset, 3e38f, "vox_offset"}};
  for (const Case& c : cases) {
    SCOPED_TRACE(c.name);
    std::string bytes = good;
    patch<float>(bytes, c.offset, c.value);
    write_bytes(dir.file(c.name), bytes);
    const Status status = read_label_volume(dir.file(c.name)).status();
    expect_error_naming(status, c.name, StatusCode::kInvalidArgument);
    EXPECT_NE(status.message().find(c.says), std::string::npos) << status.to_string();
  }
  std::string zero = good;
  patch<int16_t>(zero, kSformCode, 1);
  for (int i = 0; i < 12; ++i) patch<float>(zero, kSrowX + 4 * static_cast<size_t>(i), 0.0f);
  write_bytes(dir.file("zero_sform.nii"), zero);
  expect_error_naming(read_label_volume(dir.file("zero_sform.nii")).status(), "zero_sform.nii",
                      StatusCode::kInvalidArgument);
}

TEST(BadInput, DirectoriesFifosAndDevicesAreNamedForWhatTheyAre) {
  ScratchDir dir;
  std::filesystem::create_directories(dir.file("folder.nii"));
  const Status folder = read_label_volume(dir.file("folder.nii")).status();
  expect_error_naming(folder, "folder.nii", StatusCode::kInvalidArgument);
  EXPECT_NE(folder.message().find("directory"), std::string::npos) << folder.to_string();
  ASSERT_EQ(::mkfifo(dir.file("pipe.nii").c_str(), 0600), 0);
  const Status fifo = read_label_volume(dir.file("pipe.nii")).status();  // must not block
  expect_error_naming(fifo, "pipe.nii", StatusCode::kInvalidArgument);
  EXPECT_NE(fifo.message().find("FIFO"), std::string::npos) << fifo.to_string();
  std::filesystem::create_symlink("/dev/zero", dir.file("zero.nii"));
  const Status device = read_intensity_volume(dir.file("zero.nii")).status();
  EXPECT_EQ(device.code(), StatusCode::kInvalidArgument) << device.to_string();
  EXPECT_NE(device.message().find("device"), std::string::npos) << device.to_string();
}

}  // namespace
}  // namespace posewarp::io

namespace posewarp::io {
namespace {

// A few bytes of compressed data whose header promises a large grid: refused before anything is allocated (ITK
// would allocate the grid, then print "Uncompress failed" and hand back uninitialised voxels).
TEST(BadInput, CompressedDataShorterThanItsHeaderPromisesIsRefusedBeforeAllocating) {
  ScratchDir dir;
  const std::string zeros(1000, '\0');
  // A zlib stream of 1000 zero bytes (what MetaIO writes), and the same as gzip (what NRRD writes).
  auto deflated = [&](int window_bits) {
    z_stream stream{};
    deflateInit2(&stream, Z_DEFAULT_COMPRESSION, Z_DEFLATED, window_bits, 8, Z_DEFAULT_STRATEGY);
    std::string out(2048, '\0');
    stream.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(zeros.data()));
    stream.avail_in = static_cast<uInt>(zeros.size());
    stream.next_out = reinterpret_cast<Bytef*>(out.data());
    stream.avail_out = static_cast<uInt>(out.size());
    deflate(&stream, Z_FINISH);
    out.resize(stream.total_out);
    deflateEnd(&stream);
    return out;
  };
  const std::string zlib = deflated(15), gzip = deflated(15 + 16);
  write_bytes(dir.file("bomb.mha"), "ObjectType = Image\nNDims = 3\nDimSize = 400 400 400\nElementSpacing = 1 1 1\n"
                                    "ElementType = MET_UCHAR\nCompressedData = True\nCompressedDataSize = " +
                                        std::to_string(zlib.size()) + "\nElementDataFile = LOCAL\n" + zlib);
  write_bytes(dir.file("bomb.nrrd"),
              "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 400 400 400\nencoding: gzip\n\n" + gzip);
  for (const std::string name : {"bomb.mha", "bomb.nrrd"}) {
    SCOPED_TRACE(name);
    const Status status = read_label_volume(dir.file(name)).status();
    expect_error_naming(status, name, StatusCode::kDataLoss);
    EXPECT_NE(status.message().find("promises 64000000"), std::string::npos) << status.to_string();
  }
}

}  // namespace
}  // namespace posewarp::io

namespace posewarp::io {
namespace {

// Every volume the fuzzer found crashing, hanging or allocating without bound (tests/fuzz/corpus/volume/
// regression-*: a format byte, then the file) is refused here too, in the ordinary build, with a message.
TEST(BadInput, EveryVolumeFuzzingFoundIsRefused) {
  ScratchDir dir;
  const char* const extensions[] = {".nii", ".nii.gz", ".nrrd", ".mha"};
  int seen = 0;
  for (const auto& entry :
       std::filesystem::directory_iterator(std::filesystem::path(POSEWARP_SOURCE_DIR) / "tests/fuzz/corpus/volume")) {
    const std::string name = entry.path().filename().string();
    if (name.rfind("regression-", 0) != 0) continue;
    SCOPED_TRACE(name);
    const std::string bytes = read_bytes(entry.path().string());
    ASSERT_FALSE(bytes.empty());
    const std::string path = dir.file(name + extensions[static_cast<unsigned char>(bytes[0]) % 4]);
    write_bytes(path, bytes.substr(1));
    ReadOptions options;
    options.max_voxels = int64_t{1} << 22;
    const Status labels = read_label_volume(path, options).status();
    const Status intensities = read_intensity_volume(path, options).status();
    // The leak seeds are damaged files ITK leaks on; they must be refused like the rest.
    EXPECT_FALSE(labels.ok());
    EXPECT_FALSE(intensities.ok());
    EXPECT_FALSE(labels.message().empty());
    ++seen;
  }
  EXPECT_GE(seen, 10);
}

}  // namespace
}  // namespace posewarp::io

namespace posewarp::io {
namespace {

ReadOptions inline_only() {
  ReadOptions options;
  options.inline_data_only = true;
  return options;
}

// A server's uploads must hold their own voxels: a header naming a data file beside it could read another stored
// volume (or any file) as its voxels.
TEST(BadInput, InlineDataOnlyRefusesDetachedHeadersAndDicomBeforeReading) {
  ScratchDir dir;
  LabelVolume labels = patterned_labels(small_oblique_grid(), {0, 1, 2});
  labels.set_source_type(PixelType::kUInt8);
  for (const char* name :
       {"detached.nhdr", "detached.mhd", "inline.nii", "inline.nii.gz", "inline.nrrd", "inline.mha", "series"}) {
    ASSERT_TRUE(write_volume(labels, dir.file(name)).ok()) << name;
  }
  // Other spellings of a detached header under an inline extension.
  std::string mhd = read_bytes(dir.file("detached.mhd"));
  write_bytes(dir.file("detached_as.mha"), mhd);
  const std::string data_file = mhd.substr(mhd.find("ElementDataFile = ") + 18);
  write_bytes(dir.file("shouting.nrrd"),
              "NRRD0004\ntype: uchar\ndimension: 3\nsizes: 7 6 5\nencoding: raw\nDATA FILE: " +
                  data_file.substr(0, data_file.find('\n')) + "\n");
  std::string pair = read_bytes(dir.file("inline.nii"));
  std::memcpy(pair.data() + 344, "ni1", 4);  // a .hdr/.img pair's magic: the voxels are in another file
  write_bytes(dir.file("pair.nii"), pair);

  struct Case {
    std::string name, says;
  };
  const std::vector<Case> refused{{"detached.nhdr", "\"data file\""},
                                  {"shouting.nrrd", "\"data file\""},
                                  {"detached.mhd", "ElementDataFile"},
                                  {"detached_as.mha", "ElementDataFile"},
                                  {"pair.nii", "n+1"},
                                  {"series", "DICOM series"}};
  for (const Case& c : refused) {
    SCOPED_TRACE(c.name);
    const std::string path = dir.file(c.name);
    for (const Status& status :
         {read_header(path, inline_only()).status(), read_label_volume(path, inline_only()).status(),
          read_intensity_volume(path, inline_only()).status()}) {
      expect_error_naming(status, c.name, StatusCode::kInvalidArgument);
      EXPECT_NE(status.message().find(c.says), std::string::npos) << status.to_string();
      EXPECT_NE(status.message().find("send the voxels inline: a .nii/.nii.gz, a .nrrd with its data inline, or a "
                                      ".mha with ElementDataFile = LOCAL"),
                std::string::npos)
          << status.to_string();
    }
  }
  // Without the option the detached files are read as before; with it, self-contained files still are.
  EXPECT_TRUE(read_label_volume(dir.file("detached.nhdr")).ok());
  EXPECT_TRUE(read_label_volume(dir.file("detached.mhd")).ok());
  for (const char* name : {"inline.nii", "inline.nii.gz", "inline.nrrd", "inline.mha"}) {
    Result<LabelVolume> read = read_label_volume(dir.file(name), inline_only());
    ASSERT_TRUE(read.ok()) << name << ": " << read.status().to_string();
    EXPECT_EQ(read->voxels(), labels.voxels()) << name;
  }
}

// `raw` as a gzip file, written in 1 MB pieces, followed by `zeros` zero bytes.
void write_gzip(const std::string& path, const std::string& raw, int64_t zeros) {
  gzFile file = gzopen(path.c_str(), "wb1");
  ASSERT_NE(file, nullptr);
  ASSERT_EQ(gzwrite(file, raw.data(), static_cast<unsigned>(raw.size())), static_cast<int>(raw.size()));
  const std::string piece(size_t{1} << 20, '\0');
  for (int64_t left = zeros; left > 0; left -= static_cast<int64_t>(piece.size())) {
    const unsigned n = static_cast<unsigned>(std::min<int64_t>(left, static_cast<int64_t>(piece.size())));
    ASSERT_EQ(gzwrite(file, piece.data(), n), static_cast<int>(n));
  }
  ASSERT_EQ(gzclose(file), Z_OK);
}

// A small .nii.gz can inflate to gigabytes: the check inflates only what the header promises, and a header that
// promises too much is refused by the voxel limit before anything is inflated.
TEST(BadInput, NiftiGzipBombsCostNoMoreThanTheVoxelsTheirHeaderPromises) {
  ScratchDir dir;
  ImageGeometry g = small_oblique_grid();
  g.size = {10, 1, 1};
  LabelVolume ten = patterned_labels(g, {0, 1, 2});
  ten.set_source_type(PixelType::kUInt8);
  ASSERT_TRUE(write_volume(ten, dir.file("ten.nii")).ok());
  const std::string nii = read_bytes(dir.file("ten.nii"));

  // 10 voxels, then 200 MB of zeros the header never mentions: read as the 10 voxels.
  write_gzip(dir.file("trailing.nii.gz"), nii, int64_t{200} << 20);
  EXPECT_LT(std::filesystem::file_size(dir.file("trailing.nii.gz")), 2u << 20);
  Result<LabelVolume> read = read_label_volume(dir.file("trailing.nii.gz"));
  ASSERT_TRUE(read.ok()) << read.status().to_string();
  EXPECT_EQ(read->voxels(), ten.voxels());

  // 800^3 voxels claimed, over a 100 M limit: RESOURCE_EXHAUSTED. The stream is cut after its first part, so had
  // it been inflated the answer would have been DATA_LOSS.
  std::string huge = nii;
  for (size_t d = 1; d <= 3; ++d) patch<int16_t>(huge, kDimOffset + 2 * d, int16_t{800});
  write_gzip(dir.file("whole.nii.gz"), huge, int64_t{8} << 20);
  std::string cut = read_bytes(dir.file("whole.nii.gz"));
  cut.resize(cut.size() / 2);
  write_bytes(dir.file("claims.nii.gz"), cut);
  ReadOptions options;
  options.max_voxels = 100'000'000;
  const Status status = read_label_volume(dir.file("claims.nii.gz"), options).status();
  expect_error_naming(status, "claims.nii.gz", StatusCode::kResourceExhausted);
  EXPECT_NE(status.message().find("512000000 voxels"), std::string::npos) << status.to_string();
  // Within the limit, the same cut stream is found short.
  options.max_voxels = int64_t{1} << 30;
  expect_error_naming(read_label_volume(dir.file("claims.nii.gz"), options).status(), "claims.nii.gz",
                      StatusCode::kDataLoss);
}

}  // namespace
}  // namespace posewarp::io
