// The warp's parallel counting sort (core/resample/src/raster.h): the same order as one thread, at any thread count.
#include "raster.h"

#include <gtest/gtest.h>

#include <random>
#include <vector>

#include "posewarp/common/parallel.h"

namespace posewarp::resample::internal {
namespace {

TEST(SortByKeys, KeepsEachKeysItemsInTheirOrderAtAnyThreadCount) {
  // 50,000 items with none, one or up to three neighbouring keys each (a tet in the slabs its box meets).
  constexpr int64_t kItems = 50000, kKeys = 37;
  std::mt19937 random(7);
  std::vector<std::pair<int64_t, int64_t>> keys(kItems);  // first key, how many
  for (auto& [first, count] : keys) {
    first = static_cast<int64_t>(random() % kKeys);
    count = std::min<int64_t>(static_cast<int64_t>(random() % 4), kKeys - first);
  }
  const auto for_keys = [&](int64_t i, const auto& emit) {
    for (int64_t k = 0; k < keys[static_cast<size_t>(i)].second; ++k) emit(keys[static_cast<size_t>(i)].first + k);
  };
  std::vector<std::vector<int32_t>> expected(kKeys);
  for (int64_t i = 0; i < kItems; ++i)
    for_keys(i, [&](int64_t key) { expected[key].push_back(static_cast<int32_t>(i)); });
  for (const int threads : {1, 2, 3, 8}) {
    std::vector<int32_t> out;
    std::vector<int64_t> first;
    run_in_arena(threads, [&] { sort_by_keys(kItems, kKeys, for_keys, out, first); });
    ASSERT_EQ(first.size(), static_cast<size_t>(kKeys) + 1);
    EXPECT_EQ(first.front(), 0);
    EXPECT_EQ(first.back(), static_cast<int64_t>(out.size()));
    for (int64_t key = 0; key < kKeys; ++key) {
      const std::vector<int32_t> got(out.begin() + first[static_cast<size_t>(key)],
                                     out.begin() + first[static_cast<size_t>(key) + 1]);
      EXPECT_EQ(got, expected[static_cast<size_t>(key)]) << "key " << key << " at " << threads << " threads";
    }
  }
}

TEST(SortByKeys, NoItemsOrNoKeysGiveAnEmptyOrder) {
  std::vector<int32_t> out{1, 2, 3};
  std::vector<int64_t> first;
  sort_by_keys(
      0, 5, [](int64_t, const auto&) {}, out, first);
  EXPECT_TRUE(out.empty());
  EXPECT_EQ(first, std::vector<int64_t>(6, 0));
  sort_by_keys(
      1000, 5, [](int64_t, const auto&) {}, out, first);
  EXPECT_TRUE(out.empty());
  EXPECT_EQ(first, std::vector<int64_t>(6, 0));
}

}  // namespace
}  // namespace posewarp::resample::internal
