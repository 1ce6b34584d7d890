// A preview stream's session: a reader thread keeps only the newest update of the client (a slider moves faster than
// poses come back), and the answers carry the posed surfaces' vertices, their topology once, and the joint centres.
#pragma once

#include <grpcpp/server_context.h>
#include <grpcpp/support/sync_stream.h>

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>

#include "posewarp/api/pose_engine.h"
#include "posewarp/api/support.h"
#include "posewarp/v1/posewarp.grpc.pb.h"

namespace posewarp::server {

using PreviewStream = grpc::ServerReaderWriter<v1::PreviewResponse, v1::PreviewRequest>;

class PreviewUpdates {
 public:
  PreviewUpdates(grpc::ServerContext* context, PreviewStream* stream);
  // On an early end (an error) the client may still be sending: the call is cancelled so the reader's Read ends.
  ~PreviewUpdates();
  PreviewUpdates(const PreviewUpdates&) = delete;
  PreviewUpdates& operator=(const PreviewUpdates&) = delete;

  // Waits for the newest update (its rig id the stream's first when it names none) and how many were skipped since
  // the last; false when the client closed and everything was answered.
  bool next(v1::PreviewRequest* update, uint64_t* dropped);

 private:
  grpc::ServerContext* context_;
  std::mutex mutex_;
  std::condition_variable arrived_;
  std::optional<v1::PreviewRequest> latest_;
  uint64_t skipped_ = 0;
  bool closed_ = false;
  std::string rig_id_;
  std::thread reader_;
};

// What a preview stream keeps between updates.
struct PreviewSession {
  std::shared_ptr<const api::PoseEngine> engine;  // loaded at the first update
  bool topology_sent = false;
};

// The answer to `update`: the posed surfaces (with their topology the first time) and joint centres, with the
// time since `start`.
v1::PreviewResponse preview_answer(const v1::PreviewRequest& update, uint64_t dropped,
                                   const api::PreviewResult& preview, PreviewSession& session,
                                   const Stopwatch& start);
// A refused update, answered with its code and message; the stream goes on.
v1::PreviewResponse preview_refusal(const v1::PreviewRequest& update, uint64_t dropped, int32_t code,
                                    const std::string& message);

}  // namespace posewarp::server
