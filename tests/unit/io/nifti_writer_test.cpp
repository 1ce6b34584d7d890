// posewarp's NIfTI writer against ITK's: the same bytes once decompressed, in several members when large.
#include <gtest/gtest.h>
#include <zlib.h>

#include <fstream>
#include <iterator>

#include "posewarp/io/itk_reference.h"
#include "posewarp/io/volume_io.h"
#include "test_support.h"

namespace posewarp::io {
namespace {

using posewarp::testing::patterned_intensities;
using posewarp::testing::ScratchDir;
using posewarp::testing::small_oblique_grid;

std::string file_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// The whole stream, every gzip member of it, as zlib's gzread gives it (what ITK's reader uses).
std::string gunzip(const std::string& path) {
  gzFile in = gzopen(path.c_str(), "rb");
  if (in == nullptr) return {};
  std::string bytes;
  char buffer[1 << 16];
  for (int n; (n = gzread(in, buffer, sizeof(buffer))) > 0;) bytes.append(buffer, static_cast<size_t>(n));
  gzclose(in);
  return bytes;
}

// gzip members in a file: each starts with the magic 1f 8b 08 right after the previous one ends.
int gzip_members(const std::string& path) {
  const std::string bytes = file_bytes(path);
  z_stream stream{};
  int members = 0;
  size_t at = 0;
  while (at < bytes.size()) {
    if (inflateInit2(&stream, 16 + MAX_WBITS) != Z_OK) return -1;
    std::string sink(1 << 20, '\0');
    stream.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(bytes.data() + at));
    stream.avail_in = static_cast<uInt>(bytes.size() - at);
    int result = Z_OK;
    while (result == Z_OK) {
      stream.next_out = reinterpret_cast<Bytef*>(sink.data());
      stream.avail_out = static_cast<uInt>(sink.size());
      result = inflate(&stream, Z_NO_FLUSH);
    }
    const size_t used = bytes.size() - at - stream.avail_in;
    inflateEnd(&stream);
    if (result != Z_STREAM_END) return -1;
    at += used;
    ++members;
  }
  return members;
}

struct WriterCase {
  const char* name;
  ImageGeometry grid;
  PixelType type;
  float lo, hi;
};

ImageGeometry grid_of(Index3 size, Vec3 spacing, Vec3 origin, std::array<double, 9> direction) {
  ImageGeometry g;
  g.size = size;
  g.spacing = spacing;
  g.origin = origin;
  g.direction = direction;
  return g;
}

class NiftiWriter : public ::testing::TestWithParam<WriterCase> {};

TEST_P(NiftiWriter, WritesItksBytesAndReadsBack) {
  const WriterCase& c = GetParam();
  ScratchDir dir;
  IntensityVolume volume = patterned_intensities(c.grid, c.lo, c.hi, !is_floating(c.type));
  volume.set_source_type(c.type);
  for (const std::string extension : {".nii", ".nii.gz"}) {
    SCOPED_TRACE(extension);
    const std::string ours = dir.file(std::string("ours") + extension);
    const std::string itk = dir.file(std::string("itk") + extension);
    ASSERT_TRUE(write_volume(volume, ours).ok());
    const Status written = itk_write_volume(volume, c.type, itk);
    ASSERT_TRUE(written.ok()) << written.to_string();
    const bool gz = extension == std::string(".nii.gz");
    const std::string our_bytes = gz ? gunzip(ours) : file_bytes(ours);
    const std::string itk_bytes = gz ? gunzip(itk) : file_bytes(itk);
    ASSERT_EQ(our_bytes.size(), 352 + static_cast<size_t>(volume.voxel_count() * pixel_type_bytes(c.type)));
    EXPECT_EQ(our_bytes.substr(0, 352), itk_bytes.substr(0, 352)) << "the header differs from ITK's";
    EXPECT_TRUE(our_bytes == itk_bytes) << "the voxels differ from ITK's";
    // The server's in-memory file is the same file.
    Result<std::string> in_memory = encode_volume(volume, VolumeFormat::kNifti, gz);
    ASSERT_TRUE(in_memory.ok()) << in_memory.status().to_string();
    EXPECT_TRUE(*in_memory == file_bytes(ours)) << "encode_volume differs from write_volume";
    Result<IntensityVolume> back = read_intensity_volume(ours);
    ASSERT_TRUE(back.ok()) << back.status().to_string();
    EXPECT_EQ(back->source_type(), c.type);
    EXPECT_TRUE(back->geometry().same_grid(volume.geometry()));
    EXPECT_EQ(back->voxels(), volume.voxels());
  }
}

const std::array<double, 9> kIdentity{1, 0, 0, 0, 1, 0, 0, 0, 1};
// A left-handed grid (the slices stacked feet to head, as many scanners write): qfac -1.
const std::array<double, 9> kFlipped{-1, 0, 0, 0, 1, 0, 0, 0, -1};

INSTANTIATE_TEST_SUITE_P(
    GridsAndTypes, NiftiWriter,
    ::testing::Values(WriterCase{"oblique_uint8", small_oblique_grid(), PixelType::kUInt8, 0, 255},
                      WriterCase{"oblique_float", small_oblique_grid(), PixelType::kFloat32, -1000.5f, 3000.25f},
                      WriterCase{"axial_int16", grid_of({9, 8, 7}, {0.7, 0.7, 3.0}, {-120, 80.5, -300}, kIdentity),
                                 PixelType::kInt16, -1024, 3071},
                      WriterCase{"flipped_uint16", grid_of({5, 6, 7}, {1.5, 1.5, 1.0}, {10, -20, 30}, kFlipped),
                                 PixelType::kUInt16, 0, 65535},
                      WriterCase{"oblique_int32", small_oblique_grid(), PixelType::kInt32, -70000, 70000},
                      WriterCase{"oblique_float64", small_oblique_grid(), PixelType::kFloat64, -1, 1}),
    [](const ::testing::TestParamInfo<WriterCase>& param) { return std::string(param.param.name); });

TEST(NiftiWriterLarge, ALargeVolumeIsSeveralMembersAndOneStream) {
  ScratchDir dir;
  // 5.4 MB of int16: two members of voxels after the header's.
  IntensityVolume ct = patterned_intensities(grid_of({150, 120, 150}, {1, 1, 2}, {0, 0, 0}, kIdentity), -1000, 2000,
                                             true);
  ct.set_source_type(PixelType::kInt16);
  const std::string path = dir.file("ct.nii.gz");
  ASSERT_TRUE(write_volume(ct, path).ok());
  EXPECT_EQ(gzip_members(path), 3);
  const std::string reference = dir.file("itk.nii.gz");
  const Status written = itk_write_volume(ct, PixelType::kInt16, reference);
  ASSERT_TRUE(written.ok()) << written.to_string();
  EXPECT_TRUE(gunzip(path) == gunzip(reference));
  Result<IntensityVolume> back = read_intensity_volume(path);
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  EXPECT_EQ(back->voxels(), ct.voxels());
}

}  // namespace
}  // namespace posewarp::io
