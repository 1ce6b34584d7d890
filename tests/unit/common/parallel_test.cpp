#include "posewarp/common/parallel.h"

#include <gtest/gtest.h>

#include <atomic>
#include <vector>

namespace posewarp {
namespace {

TEST(ParallelFor, VisitsEveryIndexExactlyOnce) {
  set_thread_count(2);
  std::vector<std::atomic<int>> visits(100003);
  parallel_for(0, static_cast<int64_t>(visits.size()), 97, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) visits[static_cast<size_t>(i)].fetch_add(1);
  });
  for (const auto& count : visits) ASSERT_EQ(count.load(), 1);
}

TEST(ParallelFor, EmptyAndSingleThreadRangesWork) {
  int calls = 0;
  parallel_for(5, 5, 1, [&](int64_t, int64_t) { ++calls; });
  EXPECT_EQ(calls, 0);
  set_thread_count(1);
  EXPECT_EQ(thread_count(), 1);
  int64_t sum = 0;
  parallel_for(0, 1000, 10, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) sum += i;  // one thread: no race
  });
  EXPECT_EQ(sum, 999 * 1000 / 2);
  set_thread_count(0);
  EXPECT_GE(thread_count(), 1);
}

}  // namespace
}  // namespace posewarp
