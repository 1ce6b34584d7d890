#include "posewarp/common/progress.h"

#include <gtest/gtest.h>

#include <vector>

namespace posewarp {
namespace {

TEST(StageProgress, ReportsMonotoneFractionsEndingAtOne) {
  std::vector<double> seen;
  ProgressHooks hooks;
  hooks.on_progress = [&](std::string_view stage, double fraction) {
    EXPECT_EQ(stage, "mesh");
    seen.push_back(fraction);
  };
  StageProgress progress(hooks, "mesh");
  progress.update(0.5);
  progress.update(0.25);  // never backwards
  progress.update(0.501);  // below the 1% throttle
  for (int i = 0; i < 10; ++i) progress.advance(1, 10);
  progress.finish();
  ASSERT_GE(seen.size(), 3u);
  for (size_t i = 1; i < seen.size(); ++i) EXPECT_GT(seen[i], seen[i - 1]);
  EXPECT_DOUBLE_EQ(seen.back(), 1.0);
}

TEST(StageProgress, CancelFlagTurnsIntoCancelledStatus) {
  CancelFlag flag;
  ProgressHooks hooks;
  hooks.cancel_requested = flag.as_hook();
  StageProgress progress(hooks, "weights");
  EXPECT_TRUE(progress.check_cancel().ok());
  flag.cancel();
  const Status status = progress.check_cancel();
  EXPECT_EQ(status.code(), StatusCode::kCancelled);
  EXPECT_NE(status.message().find("weights"), std::string::npos);
}

TEST(StageProgress, APassedDeadlineTurnsIntoDeadlineExceeded) {
  ProgressHooks hooks;
  hooks.deadline = std::chrono::steady_clock::now() + std::chrono::hours(1);
  StageProgress progress(hooks, "warp");
  EXPECT_TRUE(progress.check_cancel().ok());
  EXPECT_FALSE(progress.cancel_requested());
  hooks.deadline = std::chrono::steady_clock::now() - std::chrono::milliseconds(1);
  const Status status = progress.check_cancel();
  EXPECT_EQ(status.code(), StatusCode::kDeadlineExceeded);
  EXPECT_NE(status.message().find("warp"), std::string::npos);
  EXPECT_TRUE(progress.cancel_requested());  // long loops stop on either
}

TEST(StageProgress, EmptyHooksAreAllowed) {
  ProgressHooks hooks;
  StageProgress progress(hooks, "quiet");
  progress.update(0.5);
  EXPECT_TRUE(progress.check_cancel().ok());
}

}  // namespace
}  // namespace posewarp
