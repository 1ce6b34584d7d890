// The one clock of posewarp's own timings (stage seconds in reports and provenance, solver statistics, a batch's
// per-study figures): a steady clock read as seconds since a start, and laps appended to a list as they end.
#pragma once

#include <chrono>
#include <string>
#include <utility>
#include <vector>

namespace posewarp {

class Stopwatch {
 public:
  using Clock = std::chrono::steady_clock;

  Stopwatch() : start_(Clock::now()), last_(start_) {}

  // Seconds since the stopwatch started (or was restarted).
  double seconds() const { return std::chrono::duration<double>(Clock::now() - start_).count(); }
  void restart() { start_ = last_ = Clock::now(); }

  // Seconds since the last lap (or the start), and begins the next lap.
  double lap() {
    const Clock::time_point now = Clock::now();
    const double seconds = std::chrono::duration<double>(now - last_).count();
    last_ = now;
    return seconds;
  }

 private:
  Clock::time_point start_;
  Clock::time_point last_;
};

// Named laps into a list in the order they end: a pipeline's stage timings ("skeleton", "mesh", ...).
class StageTimer {
 public:
  explicit StageTimer(std::vector<std::pair<std::string, double>>& laps) : laps_(laps) {}
  void lap(const std::string& stage) { laps_.emplace_back(stage, stopwatch_.lap()); }

 private:
  std::vector<std::pair<std::string, double>>& laps_;
  Stopwatch stopwatch_;
};

}  // namespace posewarp
