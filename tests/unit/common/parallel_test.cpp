#include "posewarp/common/parallel.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <atomic>
#include <new>
#include <vector>

#include "posewarp/common/result.h"

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

TEST(ParallelFor, AnExceptionInABodyReachesTheCallerAndStopsTheRest) {
  std::atomic<int64_t> chunks{0};
  EXPECT_THROW(parallel_for(0, 1 << 20, 64,
                            [&](int64_t begin, int64_t) {
                              chunks.fetch_add(1);
                              if (begin == 0) throw std::bad_alloc();
                            }),
               std::bad_alloc);
  EXPECT_LT(chunks.load(), (1 << 20) / 64);  // chunks after the failure were skipped
}

TEST(ParallelFor, EachCallRunsInAnArenaOfTheThreadsItWasGiven) {
  int inside = 0;
  run_in_arena(1, [&] { inside = thread_count(); });
  EXPECT_EQ(inside, 1);
  const Result<int> two = in_arena(2, [] { return Result<int>(thread_count()); });
  ASSERT_TRUE(two.ok());
  EXPECT_EQ(*two, std::min(2, thread_count()));  // never above the process's own
  // One thread: chunks run one after another on the calling thread.
  run_in_arena(1, [] {
    int64_t sum = 0;
    parallel_for(0, 1000, 10, [&](int64_t begin, int64_t end) {
      for (int64_t i = begin; i < end; ++i) sum += i;
    });
    EXPECT_EQ(sum, 999 * 1000 / 2);
  });
}

}  // namespace
}  // namespace posewarp
