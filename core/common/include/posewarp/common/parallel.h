// Parallel loops over index ranges, on a thread count that the program sets once.
#pragma once

#include <cstdint>
#include <functional>

namespace posewarp {

// Sets the number of worker threads used by every parallel loop in this process; 0 means all hardware threads.
// Call once at start-up (CLI --threads, server flag). Later calls replace the limit.
void set_thread_count(int threads);

// The thread count in force (at least 1).
int thread_count();

// Calls body(chunk_begin, chunk_end) over disjoint chunks that cover [begin, end), in parallel. Chunks hold at
// least `grain` indices. The body must not throw.
void parallel_for(int64_t begin, int64_t end, int64_t grain, const std::function<void(int64_t, int64_t)>& body);

}  // namespace posewarp
