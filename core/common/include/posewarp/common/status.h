// Status: the error type every stage returns; codes equal gRPC's canonical status codes.
#pragma once

#include <string>
#include <string_view>
#include <utility>

namespace posewarp {

// Numerically equal to grpc::StatusCode, so the server maps one to the other with a cast.
enum class StatusCode : int {
  kOk = 0,
  kCancelled = 1,
  kUnknown = 2,
  kInvalidArgument = 3,
  kDeadlineExceeded = 4,
  kNotFound = 5,
  kAlreadyExists = 6,
  kPermissionDenied = 7,
  kResourceExhausted = 8,
  kFailedPrecondition = 9,
  kAborted = 10,
  kOutOfRange = 11,
  kUnimplemented = 12,
  kInternal = 13,
  kUnavailable = 14,
  kDataLoss = 15,
  kUnauthenticated = 16,
};

// Upper-case canonical name, e.g. "INVALID_ARGUMENT".
std::string_view status_code_name(StatusCode code);

// A code and a message that tells the user what went wrong and what to do about it.
class [[nodiscard]] Status {
 public:
  Status() = default;
  Status(StatusCode code, std::string message) : code_(code), message_(std::move(message)) {}

  bool ok() const { return code_ == StatusCode::kOk; }
  StatusCode code() const { return code_; }
  const std::string& message() const { return message_; }

  // "INVALID_ARGUMENT: <message>", or "OK".
  std::string to_string() const;

  // The same status with "<context>: " in front of the message (no-op on OK).
  Status with_context(std::string_view context) const;

 private:
  StatusCode code_ = StatusCode::kOk;
  std::string message_;
};

inline Status ok_status() { return Status(); }
inline Status cancelled_error(std::string m) { return {StatusCode::kCancelled, std::move(m)}; }
inline Status deadline_exceeded_error(std::string m) { return {StatusCode::kDeadlineExceeded, std::move(m)}; }
inline Status invalid_argument_error(std::string m) { return {StatusCode::kInvalidArgument, std::move(m)}; }
inline Status not_found_error(std::string m) { return {StatusCode::kNotFound, std::move(m)}; }
inline Status permission_denied_error(std::string m) { return {StatusCode::kPermissionDenied, std::move(m)}; }
inline Status already_exists_error(std::string m) { return {StatusCode::kAlreadyExists, std::move(m)}; }
inline Status resource_exhausted_error(std::string m) { return {StatusCode::kResourceExhausted, std::move(m)}; }
inline Status failed_precondition_error(std::string m) { return {StatusCode::kFailedPrecondition, std::move(m)}; }
inline Status out_of_range_error(std::string m) { return {StatusCode::kOutOfRange, std::move(m)}; }
inline Status unimplemented_error(std::string m) { return {StatusCode::kUnimplemented, std::move(m)}; }
inline Status internal_error(std::string m) { return {StatusCode::kInternal, std::move(m)}; }
inline Status unavailable_error(std::string m) { return {StatusCode::kUnavailable, std::move(m)}; }
inline Status data_loss_error(std::string m) { return {StatusCode::kDataLoss, std::move(m)}; }

}  // namespace posewarp

#define POSEWARP_CONCAT_INNER_(a, b) a##b
#define POSEWARP_CONCAT_(a, b) POSEWARP_CONCAT_INNER_(a, b)

// Returns the Status of `expr` from the enclosing function if it is not OK.
#define POSEWARP_RETURN_IF_ERROR(expr)                  \
  do {                                                  \
    ::posewarp::Status posewarp_status_ = (expr);       \
    if (!posewarp_status_.ok()) return posewarp_status_; \
  } while (false)

// `lhs = value of Result expr`, or return its Status from the enclosing function.
#define POSEWARP_ASSIGN_OR_RETURN(lhs, expr) \
  POSEWARP_ASSIGN_OR_RETURN_IMPL_(POSEWARP_CONCAT_(posewarp_result_, __LINE__), lhs, expr)
#define POSEWARP_ASSIGN_OR_RETURN_IMPL_(result, lhs, expr) \
  auto result = (expr);                                    \
  if (!result.ok()) return result.status();                \
  lhs = std::move(result).value()
