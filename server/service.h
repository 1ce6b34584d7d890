// The gRPC service: a thin adapter between posewarp.v1 and the core's api (no pipeline logic here). Its handlers
// (rpc/*.cpp, one file per group of RPCs) are short: each opens a Call (call.h: token check, stall watch, and at the
// end the status converted, a log line and the metrics), then asks the pieces below, each under its own mutex: the
// intake of uploads (intake.h), the build queue (build_queue.h), the engine cache (engine_cache.h), admission
// (admission.h: memory budget and per-client limits; slots.h: pose slots and preview streams) and the streams of
// poses and previews (pose_stream.h, preview_session.h).
#pragma once

#include <chrono>
#include <cstdint>
#include <memory>
#include <string>
#include <utility>
#include <vector>

#include "admission.h"
#include "auth.h"
#include "build_queue.h"
#include "call.h"
#include "engine_cache.h"
#include "intake.h"
#include "metrics.h"
#include "posewarp/api/pose_engine.h"
#include "posewarp/v1/posewarp.grpc.pb.h"
#include "preview_session.h"
#include "requests.h"
#include "slots.h"
#include "store.h"

namespace posewarp::server {

struct ServiceOptions {
  int build_workers = 1;                         // builds running at once
  int build_queue = 4;                           // builds waiting for a worker; past it RESOURCE_EXHAUSTED
  int build_threads = 0;                         // threads of a build (0: all cores)
  int pose_slots = 0;                            // poses running at once (0: as many as cores)
  int pose_queue = 32;                           // poses waiting for a slot; past it RESOURCE_EXHAUSTED
  int pose_threads = 0;                          // threads of one pose (0: all cores)
  int64_t cache_bytes = int64_t{8} << 30;        // loaded engines kept, by Rig::footprint_bytes()
  int64_t max_upload_bytes = int64_t{4} << 30;   // one uploaded file
  int64_t max_volume_voxels = int64_t{1} << 28;  // one uploaded volume (and what the readers allocate for it)
  int64_t max_output_voxels = int64_t{1} << 28;  // one pose's output grid
  int64_t max_output_bytes = 0;                  // one pose's outputs (0: the whole memory budget)
  // Poses and uploads in flight together, by their estimates (the engine cache's cache_bytes come on top).
  int64_t memory_bytes = int64_t{4} << 30;
  // Freed pose outputs kept for the next pose (posewarp/common/voxel_memory.h), on top of memory_bytes.
  int64_t kept_output_bytes = int64_t{512} << 20;
  int kept_output_idle_s = 60;         // ... given back to the system once no pose has taken them this long
  int stall_timeout_ms = 10000;        // a stream that makes no progress this long is cancelled
  ClientLimitOptions client;           // per client (its token, else its address)
  int preview_streams_per_client = 4;  // open preview streams per client
  double test_pause_in_pose_s = 0.0;   // test hook: a pose holds its slot this long before posing
  std::string replica = "posewarp";    // this replica's name in a shared index (owner of its builds)
  int lease_s = 30;                    // a shared index's build leases, renewed every third of it
};

class PosewarpService final : public v1::Posewarp::Service {
 public:
  PosewarpService(std::unique_ptr<RigStore> store, ServiceOptions options, const Tokens& tokens, Metrics& metrics);
  ~PosewarpService() override;

  // rpc/volumes.cpp
  grpc::Status UploadVolume(grpc::ServerContext* context, grpc::ServerReader<v1::UploadVolumeRequest>* reader,
                            v1::Volume* response) override;
  // rpc/builds.cpp
  grpc::Status BuildRig(grpc::ServerContext* context, const v1::BuildRigRequest* request,
                        v1::Operation* response) override;
  // rpc/operations.cpp
  grpc::Status GetOperation(grpc::ServerContext* context, const v1::GetOperationRequest* request,
                            v1::Operation* response) override;
  grpc::Status WatchOperation(grpc::ServerContext* context, const v1::GetOperationRequest* request,
                              grpc::ServerWriter<v1::Operation>* writer) override;
  grpc::Status CancelOperation(grpc::ServerContext* context, const v1::GetOperationRequest* request,
                               v1::Operation* response) override;
  grpc::Status ListOperations(grpc::ServerContext* context, const v1::ListOperationsRequest* request,
                              v1::ListOperationsResponse* response) override;
  // rpc/rigs.cpp
  grpc::Status GetRig(grpc::ServerContext* context, const v1::GetRigRequest* request, v1::Rig* response) override;
  grpc::Status ListRigs(grpc::ServerContext* context, const v1::ListRigsRequest* request,
                        v1::ListRigsResponse* response) override;
  grpc::Status DeleteRig(grpc::ServerContext* context, const v1::GetRigRequest* request,
                         v1::DeleteRigResponse* response) override;
  grpc::Status GetRigAssets(grpc::ServerContext* context, const v1::GetRigAssetsRequest* request,
                            grpc::ServerWriter<v1::RigAsset>* writer) override;
  // rpc/rig_files.cpp
  grpc::Status DownloadRig(grpc::ServerContext* context, const v1::GetRigRequest* request,
                           grpc::ServerWriter<v1::RigChunk>* writer) override;
  grpc::Status UploadRig(grpc::ServerContext* context, grpc::ServerReader<v1::UploadRigRequest>* reader,
                         v1::Rig* response) override;
  // rpc/pose.cpp
  grpc::Status Pose(grpc::ServerContext* context, const v1::PoseRequest* request,
                    grpc::ServerWriter<v1::PoseResponse>* writer) override;
  // rpc/preview.cpp
  grpc::Status Preview(grpc::ServerContext* context, PreviewStream* stream) override;
  // rpc/match.cpp
  grpc::Status MatchPosture(grpc::ServerContext* context, const v1::MatchPostureRequest* request,
                            v1::MatchPostureResponse* response) override;

  // Refuses new work, cancels queued and running builds (marked CANCELLED) and waits for the build workers; poses
  // in flight finish.
  void shutdown();
  // Waits until every call but a preview has returned its answer, or until `until`: false if one still had not.
  bool wait_for_answers(std::chrono::steady_clock::time_point until) { return frame_.answering.wait_idle(until); }

 private:
  RequestLimits request_limits() const;
  // How uploads are read: the server's voxel limit under its option's name, voxels inline only.
  api::ReadOptions read_options() const;
  // A refusal of the engine's plan with the server's own limits named.
  Status server_limits_named(const Status& status) const;
  // One pose's output bound: the request's, the server's option and the whole memory budget, whichever is least.
  int64_t output_budget(uint64_t requested) const;
  // A build's volumes were uploaded for their purpose: the labels as labels, the CT as intensities.
  Status check_build_volumes(const v1::BuildRigRequest& request) const;
  // An uploaded rig in the store under its id (kept as it is when the store has it already), as the index has it.
  Result<RigRecord> store_uploaded_rig(const api::Rig& rig, const std::string& bytes, const std::string& name);
  // The answer to one preview update (a refusal among them: the stream goes on).
  v1::PreviewResponse answer_preview(Call& call, PreviewSession& session, const v1::PreviewRequest& update,
                                     uint64_t dropped);
  std::vector<std::pair<std::string, double>> gauges();

  std::unique_ptr<RigStore> store_;
  ServiceOptions options_;
  Metrics& metrics_;
  StallWatch stall_watch_;
  CallFrame frame_;
  MemoryBudget memory_;
  ClientLimits client_limits_;
  Intake intake_;
  EngineCache engines_;
  BuildQueue builds_;
  PoseSlots pose_slots_;
  PreviewStreams previews_;
  KeptOutputTrim kept_output_trim_;
};

}  // namespace posewarp::server
