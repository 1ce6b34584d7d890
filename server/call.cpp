// The call frame: token check, stall watch, deadline, and the one conversion of a call's status with its log line.
#include "call.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cctype>
#include <cstdio>
#include <string_view>

#include "status_map.h"

namespace posewarp::server {
namespace {

// A request id from the client's "x-request-id" metadata when it is a plain token, else one of ours.
std::string request_id_of(const grpc::ServerContext* context, uint64_t counter) {
  const auto& metadata = context->client_metadata();
  const auto it = metadata.find("x-request-id");
  if (it != metadata.end() && it->second.size() <= 64 && !it->second.empty()) {
    const std::string id(it->second.data(), it->second.size());
    if (std::all_of(id.begin(), id.end(),
                    [](char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '-' || c == '_'; })) {
      return id;
    }
  }
  char text[32];
  std::snprintf(text, sizeof text, "s%06llx", static_cast<unsigned long long>(counter));
  return text;
}

}  // namespace

void Answering::enter() {
  std::lock_guard<std::mutex> lock(mutex_);
  ++calls_;
}

void Answering::leave() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    --calls_;
  }
  idle_.notify_all();
}

bool Answering::wait_idle(std::chrono::steady_clock::time_point until) {
  std::unique_lock<std::mutex> lock(mutex_);
  return idle_.wait_until(lock, until, [this] { return calls_ == 0; });
}

Call::Call(CallFrame& frame, grpc::ServerContext* context, const char* method, std::string rig_id)
    : frame_(frame),
      context_(context),
      method_(method),
      rig_id_(std::move(rig_id)),
      request_id_(request_id_of(context, frame.next_request++)),
      stream_(frame.stall_watch.watch(context)),
      answering_(std::string_view(method) != "Preview") {
  if (answering_) frame_.answering.enter();
  if (!frame_.tokens.enabled()) return;
  const auto& metadata = context->client_metadata();
  const auto it = metadata.find("authorization");
  const std::string value = it == metadata.end() ? "" : std::string(it->second.data(), it->second.size());
  if (frame_.tokens.allows(value)) return;
  refusal_ = Status(StatusCode::kUnauthenticated,
                    value.empty() ? "this server needs a bearer token: send 'authorization: Bearer <token>' (the "
                                    "CLI's --token-file)"
                                  : "the bearer token is not one this server accepts; check your token file (tokens "
                                    "are re-read by the server on SIGHUP)");
}

Call::~Call() {
  if (answering_) frame_.answering.leave();
}

ProgressHooks Call::hooks(int threads) const {
  ProgressHooks hooks;
  hooks.threads = threads;
  grpc::ServerContext* context = context_;
  hooks.cancel_requested = [context] { return context->IsCancelled(); };
  if (context->deadline() != std::chrono::system_clock::time_point::max()) {
    hooks.deadline = std::chrono::steady_clock::now() + (context->deadline() - std::chrono::system_clock::now());
  }
  return hooks;
}

Result<MemoryBudget::Reservation> Call::reserve(MemoryBudget& memory, int64_t bytes, const std::string& what) const {
  const auto until = hooks(0).deadline.value_or(std::chrono::steady_clock::now() + std::chrono::minutes(1));
  grpc::ServerContext* context = context_;
  return memory.reserve(bytes, what, until, [context] { return context->IsCancelled(); });
}

grpc::Status Call::done(const Status& result) {
  grpc::Status status = to_grpc(result, frame_.store_directory);
  if (stream_->stalled()) {
    const double limit_s = static_cast<double>(frame_.stall_watch.limit().count()) / 1000.0;
    status = grpc::Status(grpc::StatusCode::DEADLINE_EXCEEDED,
                          "the stream made no progress for " + fmt::format("{:g}", limit_s) +
                              " s (the client stopped reading or sending; the server's --stall-timeout-s); the "
                              "call was cancelled");
  } else if (status.error_code() == grpc::StatusCode::CANCELLED &&
             context_->deadline() <= std::chrono::system_clock::now()) {
    // gRPC cancels a call whose deadline passed: that is the client's deadline, not a cancel.
    status = grpc::Status(grpc::StatusCode::DEADLINE_EXCEEDED, "the client's deadline passed before the call ended");
  }
  const double seconds = start_.seconds();
  const std::string code = status_code_name(static_cast<StatusCode>(status.error_code())).data();
  frame_.metrics.observe(method_, code, seconds);
  if (status.ok() && std::string_view(method_) == "Pose" && api::is_hex_id(rig_id_)) {
    frame_.metrics.count_rig_pose(rig_id_);
  }
  // Ids are hashes and the code is canonical: nothing here names a patient or a client's file.
  const std::string rig = api::is_hex_id(rig_id_) ? " rig=" + rig_id_.substr(0, 16) : "";
  if (status.ok() || status.error_code() == grpc::StatusCode::CANCELLED) {
    spdlog::info("request={} method={}{} status={} ms={:.1f}", request_id_, method_, rig, code, seconds * 1e3);
  } else {
    spdlog::warn("request={} method={}{} status={} ms={:.1f} message=\"{}\"", request_id_, method_, rig, code,
                 seconds * 1e3, status.error_message());
  }
  return status;
}

}  // namespace posewarp::server
