// The one retry policy of posewarp's clients (the CLI's and the viewer's gRPC calls, the DICOMweb client): a call
// that failed for a reason that may pass (a server restarting, a proxy without a replica, an HTTP 5xx) is tried again
// up to `retries` more times, waiting 0.5, 1, 2, 4, ... s between tries, never more than 16 s.
#pragma once

#include <algorithm>
#include <chrono>

namespace posewarp {

struct RetryPolicy {
  int retries = 3;           // tries after the first
  double first_wait_s = 0.5;
  double longest_wait_s = 16.0;

  // The wait before retry `n` (1 for the first retry), in seconds.
  double wait_s(int n) const {
    double wait = first_wait_s;
    for (int i = 1; i < n && wait < longest_wait_s; ++i) wait *= 2.0;
    return std::min(wait, longest_wait_s);
  }
  std::chrono::milliseconds wait(int n) const {
    return std::chrono::milliseconds(static_cast<int64_t>(1000.0 * wait_s(n)));
  }
};

}  // namespace posewarp
