// parallel_for on oneTBB: per-call task arenas under an optional process-wide ceiling.
#include "posewarp/common/parallel.h"

#include <tbb/blocked_range.h>
#include <tbb/global_control.h>
#include <tbb/info.h>
#include <tbb/parallel_for.h>
#include <tbb/task_arena.h>

#include <algorithm>
#include <atomic>
#include <exception>
#include <memory>
#include <mutex>

namespace posewarp {
namespace {

std::mutex g_control_mutex;  // guards replacing the ceiling only; thread_count() reads TBB's state
std::unique_ptr<tbb::global_control> g_control;

}  // namespace

void set_thread_count(int threads) {
  std::lock_guard<std::mutex> lock(g_control_mutex);
  const int hardware = std::max(1, tbb::info::default_concurrency());
  g_control.reset();
  g_control = std::make_unique<tbb::global_control>(tbb::global_control::max_allowed_parallelism,
                                                    static_cast<size_t>(threads <= 0 ? hardware : threads));
}

int thread_count() {
  const int arena = tbb::this_task_arena::max_concurrency();
  const int ceiling = static_cast<int>(tbb::global_control::active_value(tbb::global_control::max_allowed_parallelism));
  return std::max(1, std::min(arena, ceiling));
}

void run_in_arena(int threads, const std::function<void()>& body) {
  if (threads <= 0) {
    body();
    return;
  }
  tbb::task_arena arena(threads);
  arena.execute(body);
}

void parallel_for(int64_t begin, int64_t end, int64_t grain, const std::function<void(int64_t, int64_t)>& body) {
  if (end <= begin) return;
  grain = std::max<int64_t>(1, grain);
  if (end - begin <= grain || thread_count() == 1) {
    body(begin, end);
    return;
  }
  std::atomic<bool> failed{false};
  std::exception_ptr first;
  std::mutex mutex;
  tbb::parallel_for(tbb::blocked_range<int64_t>(begin, end, static_cast<size_t>(grain)),
                    [&](const tbb::blocked_range<int64_t>& range) {
                      if (failed.load()) return;
                      try {
                        body(range.begin(), range.end());
                      } catch (...) {
                        std::lock_guard<std::mutex> lock(mutex);
                        if (!first) first = std::current_exception();
                        failed.store(true);
                      }
                    });
  if (first) std::rethrow_exception(first);
}

}  // namespace posewarp
