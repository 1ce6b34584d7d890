// The small shared mechanisms of common/: the retry policy's waits, the stopwatch, the strict JSON reader.
#include <gtest/gtest.h>

#include <thread>

#include "posewarp/common/json.h"
#include "posewarp/common/retry.h"
#include "posewarp/common/stopwatch.h"

namespace posewarp {
namespace {

TEST(RetryPolicy, WaitsDoubleFromHalfASecondUpToSixteen) {
  const RetryPolicy policy{10};
  EXPECT_DOUBLE_EQ(policy.wait_s(1), 0.5);
  EXPECT_DOUBLE_EQ(policy.wait_s(2), 1.0);
  EXPECT_DOUBLE_EQ(policy.wait_s(3), 2.0);
  EXPECT_DOUBLE_EQ(policy.wait_s(6), 16.0);
  EXPECT_DOUBLE_EQ(policy.wait_s(10), 16.0);
  EXPECT_EQ(policy.wait(2).count(), 1000);
}

TEST(Stopwatch, LapsFollowEachOtherAndAddUpToTheWhole) {
  std::vector<std::pair<std::string, double>> laps;
  const Stopwatch whole;
  StageTimer timer(laps);
  std::this_thread::sleep_for(std::chrono::milliseconds(20));
  timer.lap("first");
  timer.lap("second");
  ASSERT_EQ(laps.size(), 2u);
  EXPECT_EQ(laps[0].first, "first");
  EXPECT_GE(laps[0].second, 0.019);
  EXPECT_LT(laps[1].second, laps[0].second);
  EXPECT_GE(whole.seconds(), laps[0].second + laps[1].second);
}

TEST(StrictJson, RefusesKeysTwiceNestingTooDeepAndNumbersPastADouble) {
  EXPECT_TRUE(parse_json<nlohmann::json>(R"({"a": 1, "b": {"a": 2}})", "x").ok());  // one key per object
  const Status twice = parse_json<nlohmann::json>(R"({"a": 1, "b": {"c": 2, "c": 3}})", "label map 'm.json'").status();
  EXPECT_EQ(twice.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(twice.message().find("\"c\" appears twice"), std::string::npos) << twice.to_string();
  EXPECT_EQ(parse_json<nlohmann::ordered_json>(std::string(200, '[') + std::string(200, ']'), "x").status().code(),
            StatusCode::kInvalidArgument);
  const Status huge = parse_json<nlohmann::json>(R"({"a": 1e999})", "pose").status();
  EXPECT_EQ(huge.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(huge.message().find("pose is not valid JSON"), std::string::npos) << huge.to_string();
  // ordered keeps the order written
  const Result<nlohmann::ordered_json> ordered = parse_json<nlohmann::ordered_json>(R"({"z": 1, "a": 2})", "x");
  ASSERT_TRUE(ordered.ok());
  EXPECT_EQ(ordered->begin().key(), "z");
}

}  // namespace
}  // namespace posewarp
