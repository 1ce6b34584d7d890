#include "posewarp/common/compact_intensities.h"

#include <gtest/gtest.h>

#include <bit>
#include <cmath>
#include <cstdint>
#include <limits>

namespace posewarp {
namespace {

IntensityVolume ramp(float first, PixelType source) {
  ImageGeometry g;
  g.size = {7, 5, 3};
  g.spacing = {0.8, 0.9, 2.5};
  IntensityVolume v(g);
  for (int64_t i = 0; i < v.voxel_count(); ++i) v.data()[i] = first + static_cast<float>(i);
  v.set_source_type(source);
  return v;
}

TEST(CompactIntensities, WholeNumbersInInt16sRangeAreHeldInTwoBytesAndComeBackBitForBit) {
  const IntensityVolume ct = ramp(-1024.0f, PixelType::kInt16);
  const CompactIntensities held(ct);
  ASSERT_NE(held.as_int16(), nullptr);
  EXPECT_EQ(held.as_float(), nullptr);
  EXPECT_EQ(held.voxel_bytes(), ct.voxel_count() * 2);
  EXPECT_EQ(held.source_type(), PixelType::kInt16);
  EXPECT_TRUE(held.geometry().same_grid(ct.geometry(), 0.0));
  const IntensityVolume back = held.to_float();
  EXPECT_EQ(back.source_type(), PixelType::kInt16);
  ASSERT_EQ(back.voxel_count(), ct.voxel_count());
  for (int64_t i = 0; i < ct.voxel_count(); ++i) {
    EXPECT_EQ(std::bit_cast<uint32_t>(back.data()[i]), std::bit_cast<uint32_t>(ct.data()[i]));
  }
  // The type on disk is kept whichever type holds the values (a uint8 volume's, a float file's whole numbers).
  EXPECT_EQ(CompactIntensities(ramp(0.0f, PixelType::kUInt8)).source_type(), PixelType::kUInt8);
  EXPECT_NE(CompactIntensities(ramp(0.0f, PixelType::kFloat32)).as_int16(), nullptr);
  EXPECT_NE(CompactIntensities(ramp(32767.0f - 104.0f, PixelType::kInt32)).as_int16(), nullptr);
}

TEST(CompactIntensities, AnyValueInt16WouldChangeKeepsTheVolumeInFloats) {
  const float changed[] = {0.5f,
                           -0.0f,
                           32768.0f,
                           -32769.0f,
                           1e9f,
                           std::numeric_limits<float>::quiet_NaN(),
                           std::numeric_limits<float>::infinity()};
  for (const float x : changed) {
    IntensityVolume ct = ramp(-1024.0f, PixelType::kFloat32);
    ct.data()[ct.voxel_count() / 2] = x;
    const CompactIntensities held(ct);
    ASSERT_NE(held.as_float(), nullptr) << x;
    EXPECT_EQ(held.voxel_bytes(), ct.voxel_count() * 4);
    EXPECT_EQ(std::bit_cast<uint32_t>(held.to_float().data()[ct.voxel_count() / 2]), std::bit_cast<uint32_t>(x));
  }
  EXPECT_TRUE(CompactIntensities().empty());
}

TEST(CompactIntensities, ReadsInt16OnlyFromTheTypesThatHoldEveryInt16) {
  const char bytes[4] = {char(0xff), char(0x7f), char(0x80), char(0x00)};
  int16_t out[2] = {};
  ASSERT_TRUE(read_samples(bytes, 2, PixelType::kInt16, out));
  EXPECT_EQ(out[0], 32767);
  EXPECT_EQ(out[1], 128);
  ASSERT_TRUE(read_samples(bytes, 2, PixelType::kUInt8, out));
  EXPECT_EQ(out[0], 255);
  EXPECT_EQ(out[1], 127);
  for (const PixelType wider : {PixelType::kUInt16, PixelType::kInt32, PixelType::kFloat32}) {
    EXPECT_FALSE(read_samples(bytes, 1, wider, out)) << pixel_type_name(wider);
  }
}

}  // namespace
}  // namespace posewarp
