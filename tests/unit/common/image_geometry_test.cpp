#include "posewarp/common/image_geometry.h"

#include <gtest/gtest.h>

#include <cmath>

#include "posewarp/common/volume.h"

namespace posewarp {
namespace {

// A rotation of 30 degrees about z followed by 20 about x: a grid no axis of which is aligned with LPS.
std::array<double, 9> oblique_direction() {
  const double a = 30.0 * M_PI / 180.0, b = 20.0 * M_PI / 180.0;
  const double rz[9] = {std::cos(a), -std::sin(a), 0, std::sin(a), std::cos(a), 0, 0, 0, 1};
  const double rx[9] = {1, 0, 0, 0, std::cos(b), -std::sin(b), 0, std::sin(b), std::cos(b)};
  std::array<double, 9> d{};
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      for (int k = 0; k < 3; ++k) d[3 * r + c] += rx[3 * r + k] * rz[3 * k + c];
  return d;
}

TEST(ImageGeometry, IndexToPhysicalFollowsItksDefinition) {
  ImageGeometry g;
  g.size = {10, 20, 30};
  g.spacing = {0.5, 2.0, 3.0};
  g.origin = {-10.0, 5.0, 100.0};
  g.direction = {-1, 0, 0, 0, -1, 0, 0, 0, 1};  // a RAS file seen in LPS
  const Vec3 p = g.index_to_physical({2, 3, 4});
  EXPECT_DOUBLE_EQ(p[0], -10.0 - 1.0);
  EXPECT_DOUBLE_EQ(p[1], 5.0 - 6.0);
  EXPECT_DOUBLE_EQ(p[2], 100.0 + 12.0);
}

TEST(ImageGeometry, PhysicalToIndexInvertsIndexToPhysicalOnAnObliqueGrid) {
  ImageGeometry g;
  g.size = {64, 64, 40};
  g.spacing = {0.8, 0.9, 2.5};
  g.origin = {12.0, -40.0, 7.5};
  g.direction = oblique_direction();
  ASSERT_TRUE(g.validate().ok());
  const Vec3 index{3.25, 17.5, 9.75};
  const Vec3 back = g.physical_to_index(g.index_to_physical(index));
  for (int a = 0; a < 3; ++a) EXPECT_NEAR(back[a], index[a], 1e-9);
}

TEST(ImageGeometry, RejectsZeroSpacingNegativeSizeAndShear) {
  ImageGeometry g;
  g.size = {4, 4, 4};
  EXPECT_TRUE(g.validate().ok());
  ImageGeometry zero_spacing = g;
  zero_spacing.spacing[1] = 0.0;
  EXPECT_EQ(zero_spacing.validate().code(), StatusCode::kInvalidArgument);
  ImageGeometry negative_spacing = g;
  negative_spacing.spacing[2] = -1.0;
  EXPECT_EQ(negative_spacing.validate().code(), StatusCode::kInvalidArgument);
  ImageGeometry empty = g;
  empty.size[0] = 0;
  EXPECT_EQ(empty.validate().code(), StatusCode::kInvalidArgument);
  ImageGeometry sheared = g;
  sheared.direction = {1, 0.5, 0, 0, 1, 0, 0, 0, 1};
  EXPECT_EQ(sheared.validate().code(), StatusCode::kInvalidArgument);
  ImageGeometry nan_origin = g;
  nan_origin.origin[0] = std::nan("");
  EXPECT_EQ(nan_origin.validate().code(), StatusCode::kInvalidArgument);
}

TEST(ImageGeometry, SameGridComparesEveryField) {
  ImageGeometry a;
  a.size = {3, 4, 5};
  ImageGeometry b = a;
  EXPECT_TRUE(a.same_grid(b));
  b.origin[2] += 0.01;
  EXPECT_FALSE(a.same_grid(b));
  b = a;
  b.size[1] = 5;
  EXPECT_FALSE(a.same_grid(b));
}

TEST(Volume, StoresVoxelsXFastest) {
  ImageGeometry g;
  g.size = {3, 4, 5};
  LabelVolume v(g, 0);
  v.at(2, 1, 3) = 42;
  EXPECT_EQ(v.data()[2 + 3 * (1 + 4 * 3)], 42);
  EXPECT_EQ(v.voxel_count(), 60);
  EXPECT_TRUE(v.contains(2, 3, 4));
  EXPECT_FALSE(v.contains(3, 0, 0));
  EXPECT_EQ(v.source_type(), PixelType::kInt32);
  EXPECT_EQ(IntensityVolume(g).source_type(), PixelType::kFloat32);
}

TEST(PixelType, RangesMatchTheCTypes) {
  EXPECT_EQ(pixel_type_max(PixelType::kUInt8), 255.0);
  EXPECT_EQ(pixel_type_min(PixelType::kInt16), -32768.0);
  EXPECT_TRUE(is_floating(PixelType::kFloat32));
  EXPECT_FALSE(is_floating(PixelType::kInt32));
  EXPECT_EQ(pixel_type_name(PixelType::kUInt16), "uint16");
}

}  // namespace
}  // namespace posewarp

namespace posewarp {
namespace {

// A size whose product overflows int64 (a crafted rig's grid, found by fuzzing) is refused, not multiplied.
TEST(ImageGeometry, SizesBeyondAnyImageAreRefusedBeforeTheyOverflow) {
  ImageGeometry g;
  g.size = {441, int64_t{2089670227099910195}, 3};
  const Status status = g.validate();
  EXPECT_EQ(status.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(status.message().find("2^60"), std::string::npos) << status.to_string();
  g.size = {60000, 60000, 60000};  // absurd, but the voxel limits of the callers refuse it (RESOURCE_EXHAUSTED)
  EXPECT_TRUE(g.validate().ok());
}

}  // namespace
}  // namespace posewarp
