// posewarp-view's side of the wire: the rigs a server holds, a rig's skeleton and rest surfaces, and a preview
// stream that sends pose updates and keeps the newest answer. It talks the proto only (it never links core/).
#pragma once

#include <grpcpp/grpcpp.h>

#include <array>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "posewarp/v1/posewarp.grpc.pb.h"

namespace posewarp::view {

struct ServerAddress {
  std::string server;      // HOST:PORT
  std::string token_file;  // one line: the bearer token
  std::string tls_ca;      // PEM of the CA that signed the server's certificate
};

// A call that failed, as the user should read it.
struct CallError {
  grpc::StatusCode code = grpc::StatusCode::OK;
  std::string message;
  bool failed() const { return code != grpc::StatusCode::OK; }
};

struct RigAssets {
  v1::Skeleton skeleton;
  std::vector<v1::Surface> surfaces;  // rest positions, with role "bone", "skin" or "tissue"
};

// One joint's angles in its own frame (degrees), the CLI's pose JSON vocabulary.
struct JointAngles {
  double flexion = 0.0, abduction = 0.0, rotation = 0.0;
  bool is_zero() const { return flexion == 0.0 && abduction == 0.0 && rotation == 0.0; }
};
using PoseAngles = std::map<std::string, JointAngles>;

// The pose JSON the server (and the CLI) reads, from joint angles.
std::string pose_json(const PoseAngles& angles, const std::string& name = "posewarp-view");
// Joint angles from a pose JSON (the "angles_deg" form); an error for anything else.
std::optional<PoseAngles> angles_from_json(const std::string& text, std::string* error);

class ViewerClient {
 public:
  // The channel; the token file is read here (an error names it).
  static std::unique_ptr<ViewerClient> connect(const ServerAddress& address, CallError* error);

  CallError list_rigs(std::vector<v1::Rig>* rigs) const;
  CallError rig(const std::string& rig_id, v1::Rig* rig) const;
  CallError assets(const std::string& rig_id, RigAssets* assets) const;

  std::unique_ptr<grpc::ClientContext> context(const std::string& rig_id = "") const;
  v1::Posewarp::Stub& stub() const { return *stub_; }
  const std::string& server() const { return server_; }

 private:
  std::string server_, token_;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<v1::Posewarp::Stub> stub_;
};

// A preview stream for sliders: send() never blocks on the server; a reader thread keeps the newest answer. Each
// answer carries the sequence it answers, the server's time and the round trip measured here.
class PreviewSession {
 public:
  struct Answer {
    uint64_t sequence = 0;
    double round_trip_ms = 0.0;
    double server_ms = 0.0;
    std::vector<std::vector<float>> vertices;  // per surface, x y z per vertex
    std::vector<std::array<double, 3>> joint_centres;
    CallError error;                           // a refused update (the stream goes on)
  };

  PreviewSession(const ViewerClient& client, const std::string& rig_id);
  ~PreviewSession();
  PreviewSession(const PreviewSession&) = delete;
  PreviewSession& operator=(const PreviewSession&) = delete;

  // Sends a pose (the latest wins on the server when updates come faster than it answers); its sequence number.
  uint64_t send(const PoseAngles& angles, v1::Method method);
  // The newest answer not taken yet, if any.
  std::optional<Answer> take();
  // Waits up to timeout_ms for the answer to `sequence` (or a later one); false on timeout or a closed stream.
  bool wait_for(uint64_t sequence, int timeout_ms);
  uint64_t answers() const;
  // Why the stream ended, once it has (empty while open).
  CallError ended() const;

 private:
  void read_loop();
  std::unique_ptr<grpc::ClientContext> context_;
  std::unique_ptr<grpc::ClientReaderWriter<v1::PreviewRequest, v1::PreviewResponse>> stream_;
  std::string rig_id_;
  mutable std::mutex mutex_;
  std::condition_variable answered_;
  std::map<uint64_t, std::chrono::steady_clock::time_point> sent_at_;
  uint64_t next_sequence_ = 1, answers_ = 0, last_answered_ = 0;
  std::optional<Answer> newest_;
  bool closed_ = false;
  CallError end_;
  std::mutex write_mutex_;
  std::thread reader_;
};

}  // namespace posewarp::view
