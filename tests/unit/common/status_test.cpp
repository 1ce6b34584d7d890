#include "posewarp/common/status.h"

#include <gtest/gtest.h>

#include <memory>

#include "posewarp/common/result.h"

namespace posewarp {
namespace {

TEST(Status, CodesEqualGrpcCanonicalCodes) {
  // Values from grpc/impl/codegen/status_code_enum.h; the server casts one to the other.
  EXPECT_EQ(static_cast<int>(StatusCode::kOk), 0);
  EXPECT_EQ(static_cast<int>(StatusCode::kCancelled), 1);
  EXPECT_EQ(static_cast<int>(StatusCode::kUnknown), 2);
  EXPECT_EQ(static_cast<int>(StatusCode::kInvalidArgument), 3);
  EXPECT_EQ(static_cast<int>(StatusCode::kDeadlineExceeded), 4);
  EXPECT_EQ(static_cast<int>(StatusCode::kNotFound), 5);
  EXPECT_EQ(static_cast<int>(StatusCode::kAlreadyExists), 6);
  EXPECT_EQ(static_cast<int>(StatusCode::kPermissionDenied), 7);
  EXPECT_EQ(static_cast<int>(StatusCode::kResourceExhausted), 8);
  EXPECT_EQ(static_cast<int>(StatusCode::kFailedPrecondition), 9);
  EXPECT_EQ(static_cast<int>(StatusCode::kAborted), 10);
  EXPECT_EQ(static_cast<int>(StatusCode::kOutOfRange), 11);
  EXPECT_EQ(static_cast<int>(StatusCode::kUnimplemented), 12);
  EXPECT_EQ(static_cast<int>(StatusCode::kInternal), 13);
  EXPECT_EQ(static_cast<int>(StatusCode::kUnavailable), 14);
  EXPECT_EQ(static_cast<int>(StatusCode::kDataLoss), 15);
  EXPECT_EQ(static_cast<int>(StatusCode::kUnauthenticated), 16);
}

TEST(Status, DefaultIsOkAndFormatsWithItsCodeName) {
  EXPECT_TRUE(Status().ok());
  EXPECT_EQ(Status().to_string(), "OK");
  const Status error = invalid_argument_error("spacing is zero");
  EXPECT_FALSE(error.ok());
  EXPECT_EQ(error.to_string(), "INVALID_ARGUMENT: spacing is zero");
}

TEST(Status, ContextIsPrependedToErrorsOnly) {
  EXPECT_EQ(not_found_error("no file").with_context("reading 'a.nii'").message(), "reading 'a.nii': no file");
  EXPECT_TRUE(Status().with_context("ignored").ok());
}

Result<int> half(int value) {
  if (value % 2 != 0) return invalid_argument_error("odd");
  return value / 2;
}

Result<int> quarter(int value) {
  POSEWARP_ASSIGN_OR_RETURN(const int h, half(value));
  POSEWARP_ASSIGN_OR_RETURN(const int q, half(h));
  return q;
}

TEST(Result, HoldsAValueOrTheErrorThatExplainsWhyNot) {
  Result<int> good = half(8);
  ASSERT_TRUE(good.ok());
  EXPECT_EQ(*good, 4);
  EXPECT_TRUE(good.status().ok());
  Result<int> bad = half(3);
  ASSERT_FALSE(bad.ok());
  EXPECT_EQ(bad.status().code(), StatusCode::kInvalidArgument);
}

TEST(Result, AssignOrReturnPropagatesTheFirstError) {
  EXPECT_EQ(*quarter(8), 2);
  EXPECT_EQ(quarter(6).status().message(), "odd");
}

TEST(Result, MovesOnlyTypesOut) {
  Result<std::unique_ptr<int>> boxed(std::make_unique<int>(7));
  std::unique_ptr<int> taken = std::move(boxed).value();
  EXPECT_EQ(*taken, 7);
}

Status fails_then_continues(bool fail) {
  POSEWARP_RETURN_IF_ERROR(fail ? internal_error("boom") : ok_status());
  return ok_status();
}

TEST(Status, ReturnIfErrorStopsOnlyOnError) {
  EXPECT_TRUE(fails_then_continues(false).ok());
  EXPECT_EQ(fails_then_continues(true).code(), StatusCode::kInternal);
}

}  // namespace
}  // namespace posewarp
