// Progress and cancellation hooks that long stages call, and the per-stage reporter they call them through.
#pragma once

#include <atomic>
#include <chrono>
#include <functional>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <string_view>

#include "posewarp/common/status.h"
#include "posewarp/common/stopwatch.h"

namespace posewarp {

// What the caller (CLI, server job) hands to each long call, as TF Serving's RunOptions: progress, cancellation, a
// deadline and the threads the call may use. Every field may be left empty.
struct ProgressHooks {
  // Called with the stage name and its completed fraction in [0, 1]; may be called from any thread, but never
  // concurrently (the reporter serializes calls).
  std::function<void(std::string_view stage, double fraction)> on_progress;
  // Polled from inside long loops; returning true makes the stage stop with CANCELLED.
  std::function<bool()> cancel_requested;
  // Polled where cancellation is: work still running at this instant stops with DEADLINE_EXCEEDED.
  std::optional<std::chrono::steady_clock::time_point> deadline;
  // Worker threads of the call, in a task arena of its own (build_rig, PoseEngine::create and pose run their work
  // in one); 0 = the arena of the caller.
  int threads = 0;
  // Called as each phase of a stage ends (the warp's select, raster, shell, ...; the mesh report's parts), with the
  // stage, the phase and its seconds, from the thread that runs the stage, never concurrently: what a bench's
  // --phases prints. Empty: the phases are not timed.
  std::function<void(std::string_view stage, std::string_view phase, double seconds)> on_phase;

  bool past_deadline() const { return deadline && std::chrono::steady_clock::now() >= *deadline; }
};

// A flag a caller can set from another thread to cancel work; hooks() wires it into ProgressHooks.
class CancelFlag {
 public:
  void cancel() { cancelled_->store(true); }
  bool cancelled() const { return cancelled_->load(); }
  std::function<bool()> as_hook() const {
    return [flag = cancelled_] { return flag->load(); };
  }

 private:
  std::shared_ptr<std::atomic<bool>> cancelled_ = std::make_shared<std::atomic<bool>>(false);
};

// Times a stage's phases for ProgressHooks::on_phase: mark(phase) ends the phase begun at the last mark (or at the
// clock's making), a Stopwatch lap, and hands its seconds to the hook; without the hook it hands on nothing.
class PhaseClock {
 public:
  PhaseClock(const ProgressHooks& hooks, std::string_view stage) : hooks_(hooks), stage_(stage) {}

  void mark(std::string_view phase) {
    if (hooks_.on_phase) hooks_.on_phase(stage_, phase, stopwatch_.lap());
  }
  // Hands a phase timed elsewhere (one of several that ran side by side) to the hook.
  void report(std::string_view phase, double seconds) const {
    if (hooks_.on_phase) hooks_.on_phase(stage_, phase, seconds);
  }

 private:
  const ProgressHooks& hooks_;
  std::string_view stage_;
  Stopwatch stopwatch_;
};

// Reports one stage's progress through the hooks, throttled to 1% steps, thread-safe.
class StageProgress {
 public:
  StageProgress(const ProgressHooks& hooks, std::string stage);
  StageProgress(const StageProgress&) = delete;
  StageProgress& operator=(const StageProgress&) = delete;

  // Sets the completed fraction; values outside [0, 1] are clamped, and progress never goes backwards.
  void update(double fraction);
  // Adds `units` of `total` (call from parallel workers as they finish chunks).
  void advance(int64_t units, int64_t total);
  // CANCELLED naming the stage once cancellation was requested, DEADLINE_EXCEEDED once the deadline has passed,
  // else OK.
  Status check_cancel() const;
  // True once either has happened: the work should stop.
  bool cancel_requested() const;
  // Reports 100%.
  void finish();

  const std::string& stage() const { return stage_; }

 private:
  const ProgressHooks& hooks_;
  std::string stage_;
  std::mutex mutex_;
  std::atomic<int64_t> done_units_{0};
  int last_percent_ = -1;
  bool finished_ = false;
};

}  // namespace posewarp
