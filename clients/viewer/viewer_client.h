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

#include "posewarp_client/connection.h"
#include "posewarp_client/pose_answer.h"
#include "posewarp/v1/posewarp.grpc.pb.h"

namespace posewarp::view {

// Where the server is and how to reach it, and a failed call as the user should read it: the client library's.
using ServerAddress = client::Address;
using CallError = client::CallError;

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

// What the viewer poses: joint angles, and the root turned about the body's axes (degrees about L-R, A-P and S-I,
// applied in that order, about the root segment's centroid) and moved (LPS mm).
struct Pose {
  PoseAngles joints;
  std::array<double, 3> root_deg{0.0, 0.0, 0.0};
  std::array<double, 3> root_mm{0.0, 0.0, 0.0};
  bool is_rest() const;
};

// The pose JSON the server (and the CLI) reads, and the same pose typed, as the viewer's requests carry it.
std::string pose_json(const Pose& pose, const std::string& name = "posewarp-view");
void put_pose(const Pose& pose, v1::Pose* out, const std::string& name = "posewarp-view");
// A pose from a pose JSON: joints in the "angles_deg" form, the root in any rotation form; an error otherwise.
std::optional<Pose> pose_from_json(const std::string& text, std::string* error);

class ViewerClient {
 public:
  // The channel; the token file is read here (an error names it).
  static std::unique_ptr<ViewerClient> connect(const ServerAddress& address, CallError* error);

  CallError list_rigs(std::vector<v1::Rig>* rigs) const;
  CallError rig(const std::string& rig_id, v1::Rig* rig) const;
  CallError assets(const std::string& rig_id, RigAssets* assets) const;

  std::unique_ptr<grpc::ClientContext> context(const std::string& rig_id = "") const {
    return connection_->context(rig_id);
  }
  v1::Posewarp::Stub& stub() const { return connection_->stub(); }
  const std::string& server() const { return connection_->server(); }
  const client::Connection& connection() const { return *connection_; }

 private:
  std::unique_ptr<client::Connection> connection_;
};

// A preview stream for sliders: send() does not wait for an answer (it may wait briefly while gRPC's flow control
// holds the write); a reader thread keeps the newest answer. Each answer carries the sequence it answers, the
// server's time and the round trip measured here. The destructor gives the server 2 s to close, then cuts the call.
class PreviewSession {
 public:
  struct Answer {
    uint64_t sequence = 0;
    double round_trip_ms = 0.0;
    double server_ms = 0.0;
    std::vector<std::vector<float>> vertices;  // per surface, x y z per vertex
    std::vector<std::array<double, 3>> joint_centres;
    CallError error;  // a refused update (the stream goes on)
  };

  PreviewSession(const ViewerClient& client, const std::string& rig_id);
  ~PreviewSession();
  PreviewSession(const PreviewSession&) = delete;
  PreviewSession& operator=(const PreviewSession&) = delete;

  // Sends a pose (the latest wins on the server when updates come faster than it answers); its sequence number.
  uint64_t send(const Pose& pose, v1::Method method);
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

// A posed volume as the Pose call answers it: raw samples (the header's sample types) for the slices, or the bytes
// of NIfTI files and the posed surfaces for saving.
struct PosedVolumes : client::PoseAnswer {
  std::string pose_json;  // what was asked
};

// One Pose call on its own thread, so the window never waits on it: progress while it runs, then the result or
// the error; cancel() ends it early (the destructor cancels and waits).
class VolumeRequest {
 public:
  // raw: samples for display; otherwise NIfTI (.nii.gz) bytes and the posed surfaces, for saving. grid: the study's
  // grid (GRID_POLICY_INPUT, what the CLI does by default) or one grown to hold the posed body.
  VolumeRequest(const ViewerClient& client, const std::string& rig_id, const Pose& pose, v1::Method method, bool raw,
                v1::GridPolicy grid = v1::GRID_POLICY_INPUT);
  // Only the quality report of the pose (no volume, no surface): another method's figures beside the slices'.
  static std::unique_ptr<VolumeRequest> report_only(const ViewerClient& client, const std::string& rig_id,
                                                    const Pose& pose, v1::Method method);
  ~VolumeRequest();
  VolumeRequest(const VolumeRequest&) = delete;
  VolumeRequest& operator=(const VolumeRequest&) = delete;

  bool done() const;
  // Bytes received and expected so far (expected is 0 until the server has said).
  std::pair<uint64_t, uint64_t> progress() const;
  void cancel();
  // Once done: the error, or OK with the result moved out.
  CallError take(PosedVolumes* result);
  // Waits until done, at most timeout_ms; false on timeout.
  bool wait(int timeout_ms);

 private:
  VolumeRequest(const ViewerClient& client, const std::string& rig_id, v1::PoseRequest request, std::string asked);
  void run(v1::PoseRequest request);
  std::unique_ptr<grpc::ClientContext> context_;
  const ViewerClient& client_;
  mutable std::mutex mutex_;
  std::condition_variable finished_;
  bool done_ = false;
  uint64_t received_ = 0, expected_ = 0;
  PosedVolumes result_;
  CallError error_;
  std::thread thread_;
};

}  // namespace posewarp::view
