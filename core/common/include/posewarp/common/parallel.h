// Parallel loops over index ranges on oneTBB, run in the task arena of the call that started them.
#pragma once

#include <cstdint>
#include <functional>
#include <optional>
#include <utility>

namespace posewarp {

// The process-wide ceiling on worker threads (0 = all hardware threads), for programs that own the process (the
// CLI's --threads, benchmarks). The library never calls it; a server gives each call its own thread count instead
// (ProgressHooks::threads, run_in_arena).
void set_thread_count(int threads);

// Threads available to the calling code: the size of the task arena it runs in, within the process ceiling.
int thread_count();

// Runs `body` in a task arena of `threads` threads (0 = the arena the caller is in), so that one call's parallel
// loops use only what it was given and calls running at once do not steal each other's threads.
void run_in_arena(int threads, const std::function<void()>& body);

// run_in_arena for a body that returns a value (a Status or Result<T>).
template <typename Body>
auto in_arena(int threads, Body&& body) -> decltype(body()) {
  std::optional<decltype(body())> result;
  run_in_arena(threads, [&] { result.emplace(body()); });
  return std::move(*result);
}

// Calls body(chunk_begin, chunk_end) over disjoint chunks that cover [begin, end), in parallel. Chunks hold at
// least `grain` indices. The body may throw (std::bad_alloc inside a library): the first exception stops the chunks
// not yet started and is rethrown on the calling thread, where the stage boundary turns it into a Status.
void parallel_for(int64_t begin, int64_t end, int64_t grain, const std::function<void(int64_t, int64_t)>& body);

}  // namespace posewarp
