// parallel_for on oneTBB, limited by a process-wide thread count.
#include "posewarp/common/parallel.h"

#include <tbb/blocked_range.h>
#include <tbb/global_control.h>
#include <tbb/info.h>
#include <tbb/parallel_for.h>

#include <algorithm>
#include <memory>
#include <mutex>

namespace posewarp {
namespace {

std::mutex g_mutex;
std::unique_ptr<tbb::global_control> g_control;
int g_threads = 0;

}  // namespace

void set_thread_count(int threads) {
  std::lock_guard<std::mutex> lock(g_mutex);
  const int hardware = std::max(1, tbb::info::default_concurrency());
  g_threads = threads <= 0 ? hardware : threads;
  g_control.reset();
  g_control = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism,
                                                    static_cast<size_t>(g_threads));
}

int thread_count() {
  std::lock_guard<std::mutex> lock(g_mutex);
  if (g_threads > 0) return g_threads;
  return std::max<int>(1, static_cast<int>(
                              tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism)));
}

void parallel_for(int64_t begin, int64_t end, int64_t grain, const std::function<void(int64_t, int64_t)>& body) {
  if (end <= begin) return;
  grain = std::max<int64_t>(1, grain);
  if (end - begin <= grain || thread_count() == 1) {
    body(begin, end);
    return;
  }
  tbb::parallel_for(tbb::blocked_range<int64_t>(begin, end, static_cast<size_t>(grain)),
                    [&body](const tbb::blocked_range<int64_t>& range) { body(range.begin(), range.end()); });
}

}  // namespace posewarp
