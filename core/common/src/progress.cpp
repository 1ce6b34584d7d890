// StageProgress: throttled, serialized progress reports and cancellation checks.
#include "posewarp/common/progress.h"

#include <algorithm>
#include <cmath>

namespace posewarp {

StageProgress::StageProgress(const ProgressHooks& hooks, std::string stage) : hooks_(hooks), stage_(std::move(stage)) {
  update(0.0);
}

void StageProgress::update(double fraction) {
  if (!hooks_.on_progress) return;
  fraction = std::clamp(std::isfinite(fraction) ? fraction : 0.0, 0.0, 1.0);
  const int percent = static_cast<int>(std::floor(fraction * 100.0));
  std::lock_guard<std::mutex> lock(mutex_);
  if (percent <= last_percent_) return;
  last_percent_ = percent;
  hooks_.on_progress(stage_, fraction);
}

void StageProgress::advance(int64_t units, int64_t total) {
  const int64_t done = done_units_.fetch_add(units) + units;
  if (total > 0) update(static_cast<double>(done) / static_cast<double>(total));
}

bool StageProgress::cancel_requested() const {
  return (hooks_.cancel_requested && hooks_.cancel_requested()) || hooks_.past_deadline();
}

Status StageProgress::check_cancel() const {
  if (hooks_.cancel_requested && hooks_.cancel_requested()) {
    return cancelled_error("cancelled during stage '" + stage_ + "' at the caller's request");
  }
  if (hooks_.past_deadline()) {
    return deadline_exceeded_error("stage '" + stage_ + "' did not finish before the call's deadline");
  }
  return ok_status();
}

void StageProgress::finish() {
  finished_ = true;
  update(1.0);
}

}  // namespace posewarp
