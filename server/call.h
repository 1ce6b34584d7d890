// One call's frame: the token check, the stall watch over its stream, its deadline, then at its end the status
// converted for gRPC (the one place a handler's Status becomes a grpc::Status), the log line and the metrics.
#pragma once

#include <grpcpp/server_context.h>
#include <grpcpp/support/status.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>

#include "admission.h"
#include "auth.h"
#include "metrics.h"
#include "posewarp/api/files.h"
#include "posewarp/api/support.h"

namespace posewarp::server {

// The calls whose answers are on their way: every call but a preview's, whose stream stays open as long as its
// client wants. A stop waits for them before it closes the connections, so that no answer is cut off on the wire.
class Answering {
 public:
  void enter();
  void leave();
  // True once no call is answering, false if one still is at `until`.
  bool wait_idle(std::chrono::steady_clock::time_point until);

 private:
  std::mutex mutex_;
  std::condition_variable idle_;
  int calls_ = 0;
};

// What every call of one service shares.
struct CallFrame {
  StallWatch& stall_watch;
  const Tokens& tokens;
  Metrics& metrics;
  std::string store_directory;  // named in no message a client gets
  std::atomic<uint64_t> next_request{1};
  Answering answering;
};

// The status of a call whose client went away (or stalled: Call::done makes that DEADLINE_EXCEEDED).
inline Status client_gone() {
  return cancelled_error("the client went away");
}

class Call {
 public:
  Call(CallFrame& frame, grpc::ServerContext* context, const char* method, std::string rig_id = "");
  Call(const Call&) = delete;
  Call& operator=(const Call&) = delete;
  ~Call();

  // The token was missing or not one this server accepts: the call ends with refusal().
  bool refused() const { return !refusal_.ok(); }
  grpc::Status refusal() { return done(refusal_); }
  void set_rig(const std::string& rig_id) { rig_id_ = rig_id; }
  // Who the call comes from, for the per-client limits.
  std::string client() const { return client_of(*context_); }

  // One Write or Read of the call's stream, under the stall watch: false when the client went away or stalled.
  template <typename Writer, typename Message>
  bool write(Writer* writer, const Message& message) {
    return stream_->io([&] { return writer->Write(message); });
  }
  template <typename Reader, typename Message>
  bool read(Reader* reader, Message* message) {
    return stream_->io([&] { return reader->Read(message); });
  }
  StallWatch::Stream& stream() { return *stream_; }
  bool cancelled() const { return context_->IsCancelled(); }
  grpc::ServerContext* context() const { return context_; }

  // The engine's hooks for this call: `threads`, its cancel and its deadline.
  ProgressHooks hooks(int threads) const;
  // `bytes` of `memory` for `what`, waiting for room until the call's deadline (a minute without one) or until the
  // client goes away.
  Result<MemoryBudget::Reservation> reserve(MemoryBudget& memory, int64_t bytes, const std::string& what) const;

  // The call's answer: `status` for gRPC (server paths out), DEADLINE_EXCEEDED for a stalled stream or a passed
  // deadline; logged and counted.
  grpc::Status done(const Status& status);

 private:
  CallFrame& frame_;
  grpc::ServerContext* context_;
  const char* method_;
  std::string rig_id_;
  std::string request_id_;
  Stopwatch start_;
  std::unique_ptr<StallWatch::Stream> stream_;
  Status refusal_;
  bool answering_;
};

}  // namespace posewarp::server
