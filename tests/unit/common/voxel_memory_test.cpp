#include "posewarp/common/voxel_memory.h"

#include <gtest/gtest.h>

#include <chrono>
#include <cstring>
#include <thread>

#include "posewarp/common/volume.h"

namespace posewarp {
namespace {

constexpr size_t kMb = size_t{1} << 20;

// Each case starts and ends with nothing kept and the default limit.
class VoxelMemory : public ::testing::Test {
 protected:
  void SetUp() override {
    set_voxel_memory_kept_limit(0);
    set_voxel_memory_kept_limit(64 * kMb);
  }
  void TearDown() override {
    set_voxel_memory_kept_limit(0);
    set_voxel_memory_kept_limit(512 * kMb);
  }
};

TEST_F(VoxelMemory, ALargeBlockFreedIsHandedOutAgainForTheSameSizeOnly) {
  void* a = allocate_voxels(10 * kMb);
  std::memset(a, 7, 10 * kMb);
  free_voxels(a, 10 * kMb);
  EXPECT_EQ(voxel_memory_kept(), 10 * kMb);
  void* other = allocate_voxels(12 * kMb);  // another size: a new block, the kept one stays
  EXPECT_NE(other, a);
  EXPECT_EQ(voxel_memory_kept(), 10 * kMb);
  void* again = allocate_voxels(10 * kMb);
  EXPECT_EQ(again, a);
  EXPECT_EQ(voxel_memory_kept(), 0u);
  free_voxels(again, 10 * kMb);
  free_voxels(other, 12 * kMb);
  EXPECT_EQ(voxel_memory_kept(), 22 * kMb);
}

TEST_F(VoxelMemory, SmallBlocksAreNotKept) {
  void* small = allocate_voxels(kMb);
  free_voxels(small, kMb);
  EXPECT_EQ(voxel_memory_kept(), 0u);
}

TEST_F(VoxelMemory, TheOldestGoFirstWhenTheLimitWouldBePassedAndALimitOfNoneFreesAll) {
  void* first = allocate_voxels(30 * kMb);
  void* second = allocate_voxels(20 * kMb);
  void* third = allocate_voxels(25 * kMb);
  free_voxels(first, 30 * kMb);
  free_voxels(second, 20 * kMb);
  EXPECT_EQ(voxel_memory_kept(), 50 * kMb);
  free_voxels(third, 25 * kMb);  // 75 MB would pass 64: the oldest (30) goes
  EXPECT_EQ(voxel_memory_kept(), 45 * kMb);
  void* back = allocate_voxels(20 * kMb);
  EXPECT_EQ(back, second);
  free_voxels(back, 20 * kMb);
  void* too_big = allocate_voxels(100 * kMb);  // over the limit itself: freed, nothing evicted for it
  free_voxels(too_big, 100 * kMb);
  EXPECT_EQ(voxel_memory_kept(), 45 * kMb);
  set_voxel_memory_kept_limit(0);
  EXPECT_EQ(voxel_memory_kept(), 0u);
}

TEST_F(VoxelMemory, TrimFreesOnlyTheBlocksUnusedForTheGivenTime) {
  using namespace std::chrono_literals;
  void* old_block = allocate_voxels(10 * kMb);
  free_voxels(old_block, 10 * kMb);
  std::this_thread::sleep_for(50ms);
  void* recent = allocate_voxels(12 * kMb);
  free_voxels(recent, 12 * kMb);
  EXPECT_EQ(trim_voxel_memory(1h), 0u);  // none waited that long
  EXPECT_EQ(voxel_memory_kept(), 22 * kMb);
  EXPECT_EQ(trim_voxel_memory(30ms), 10 * kMb);  // the older only
  EXPECT_EQ(voxel_memory_kept(), 12 * kMb);
  void* again = allocate_voxels(12 * kMb);  // taken, so not trimmed
  EXPECT_EQ(again, recent);
  EXPECT_EQ(trim_voxel_memory(0ms), 0u);
  free_voxels(again, 12 * kMb);
  EXPECT_EQ(trim_voxel_memory(0ms), 12 * kMb);
  EXPECT_EQ(voxel_memory_kept(), 0u);
}

TEST_F(VoxelMemory, AVolumeOnReusedMemoryHoldsItsFillNotTheLastVolumesVoxels) {
  ImageGeometry g;
  g.size = {256, 256, 40};  // 2.6M voxels, 10 MB of float
  const void* first_block = nullptr;
  {
    IntensityVolume first(g, 5.0f);
    first_block = first.data();
  }
  const IntensityVolume second(g, -1000.0f);
  EXPECT_EQ(static_cast<const void*>(second.data()), first_block);
  for (int64_t v = 0; v < second.voxel_count(); v += 4099) ASSERT_EQ(second.data()[v], -1000.0f);
  EXPECT_EQ(second.data()[second.voxel_count() - 1], -1000.0f);
}

}  // namespace
}  // namespace posewarp
