// The gRPC service: a thin adapter between posewarp.v1 and the core's api (no pipeline logic here). Builds run on a
// bounded build queue, poses on a bounded number of slots; loaded engines stay in a cache under a byte budget. Every
// call passes one Call scope: token check, a log line (request id, method, rig id, code, duration; never patient
// data) and the metrics.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <future>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "admission.h"
#include "auth.h"
#include "metrics.h"
#include "posewarp/api/pose_engine.h"
#include "posewarp/v1/posewarp.grpc.pb.h"
#include "requests.h"
#include "store.h"

namespace posewarp::server {

struct ServiceOptions {
  int build_workers = 1;                       // builds running at once
  int build_queue = 4;                         // builds waiting for a worker; past it RESOURCE_EXHAUSTED
  int build_threads = 0;                       // threads of a build (0: all cores)
  int pose_slots = 0;                          // poses running at once (0: as many as cores)
  int pose_queue = 32;                         // poses waiting for a slot; past it RESOURCE_EXHAUSTED
  int pose_threads = 0;                        // threads of one pose (0: all cores)
  int64_t cache_bytes = int64_t{8} << 30;      // loaded engines kept, by Rig::footprint_bytes()
  int64_t max_upload_bytes = int64_t{4} << 30; // one uploaded file
  int64_t max_volume_voxels = int64_t{1} << 28;  // one uploaded volume (and what the readers allocate for it)
  int64_t max_output_voxels = int64_t{1} << 28;  // one pose's output grid
  int64_t max_output_bytes = 0;                  // one pose's outputs (0: the whole memory budget)
  // Poses and uploads in flight together, by their estimates (the engine cache's cache_bytes come on top).
  int64_t memory_bytes = int64_t{4} << 30;
  int stall_timeout_ms = 10000;                // a stream that makes no progress this long is cancelled
  ClientLimitOptions client;                   // per client (its token, else its address)
  int preview_streams_per_client = 4;          // open preview streams per client
  double test_pause_in_pose_s = 0.0;           // test hook: a pose holds its slot this long before posing
  std::string replica = "posewarp";            // this replica's name in a shared index (owner of its builds)
  int lease_s = 30;                            // a shared index's build leases, renewed every third of it
};

class PosewarpService final : public v1::Posewarp::Service {
 public:
  PosewarpService(std::unique_ptr<RigStore> store, ServiceOptions options, const Tokens& tokens, Metrics& metrics);
  ~PosewarpService() override;

  grpc::Status UploadVolume(grpc::ServerContext* context, grpc::ServerReader<v1::UploadVolumeRequest>* reader,
                            v1::Volume* response) override;
  grpc::Status BuildRig(grpc::ServerContext* context, const v1::BuildRigRequest* request,
                        v1::Operation* response) override;
  grpc::Status GetOperation(grpc::ServerContext* context, const v1::GetOperationRequest* request,
                            v1::Operation* response) override;
  grpc::Status WatchOperation(grpc::ServerContext* context, const v1::GetOperationRequest* request,
                              grpc::ServerWriter<v1::Operation>* writer) override;
  grpc::Status CancelOperation(grpc::ServerContext* context, const v1::GetOperationRequest* request,
                               v1::Operation* response) override;
  grpc::Status ListOperations(grpc::ServerContext* context, const v1::ListOperationsRequest* request,
                              v1::ListOperationsResponse* response) override;
  grpc::Status GetRig(grpc::ServerContext* context, const v1::GetRigRequest* request, v1::Rig* response) override;
  grpc::Status ListRigs(grpc::ServerContext* context, const v1::ListRigsRequest* request,
                        v1::ListRigsResponse* response) override;
  grpc::Status DeleteRig(grpc::ServerContext* context, const v1::GetRigRequest* request,
                         v1::DeleteRigResponse* response) override;
  grpc::Status GetRigAssets(grpc::ServerContext* context, const v1::GetRigAssetsRequest* request,
                            grpc::ServerWriter<v1::RigAsset>* writer) override;
  grpc::Status DownloadRig(grpc::ServerContext* context, const v1::GetRigRequest* request,
                           grpc::ServerWriter<v1::RigChunk>* writer) override;
  grpc::Status UploadRig(grpc::ServerContext* context, grpc::ServerReader<v1::UploadRigRequest>* reader,
                         v1::Rig* response) override;
  grpc::Status Pose(grpc::ServerContext* context, const v1::PoseRequest* request,
                    grpc::ServerWriter<v1::PoseResponse>* writer) override;
  grpc::Status Preview(grpc::ServerContext* context,
                       grpc::ServerReaderWriter<v1::PreviewResponse, v1::PreviewRequest>* stream) override;

  // Refuses new work, cancels queued and running builds (marked CANCELLED) and waits for the build workers; poses
  // in flight finish.
  void shutdown();

 private:
  class Call;
  struct Job {
    v1::Operation operation;  // guarded by mutex_
    v1::BuildRigRequest request;
    std::string key;          // the request without its name: identical builds share one operation
    CancelFlag cancel;
    std::chrono::steady_clock::time_point started;
  };
  using EngineResult = Result<std::shared_ptr<const api::PoseEngine>>;
  struct CacheEntry {
    std::shared_future<std::shared_ptr<EngineResult>> engine;
    int64_t bytes = 0;
    std::chrono::steady_clock::time_point last_used;
  };

  void build_worker();
  // With a shared index: renews this replica's leases and fails builds whose replica stopped renewing theirs.
  void lease_keeper();
  // Waits until this replica holds the build of `rig_id` (true), or another replica's build made it (false).
  Result<bool> claim_build(const std::shared_ptr<Job>& job, const std::string& rig_id);
  void persist(const Job& job);
  void run_build(const std::shared_ptr<Job>& job);
  void set_operation(const std::shared_ptr<Job>& job, const std::function<void(v1::Operation&)>& change,
                     bool persist);
  grpc::Status to_grpc(const Status& status) const;
  // An upload admitted for its client (--uploads-per-client, --upload-mb-per-client) and received: its chunks in a
  // file of a staging directory of its own, checked against the header's size and SHA-256.
  struct StagedUpload {
    std::optional<ClientLimits::Entry> admitted;
    std::unique_ptr<StagingDirectory> directory;
    std::string path;
  };
  // OK with `staged` filled, or the status the call ends with.
  template <typename Request>
  grpc::Status stage_upload(Call& call, grpc::ServerReader<Request>* reader, uint64_t size, const std::string& sha256,
                            const std::string& file_name, StagedUpload* staged);
  // `bytes` of the memory budget for `what`, waiting for room until the call's deadline (a minute without one) or
  // until the client goes away.
  Result<MemoryBudget::Reservation> reserve(grpc::ServerContext* context, int64_t bytes, const std::string& what);
  RequestLimits request_limits() const;
  // How uploads are read: the server's voxel limit under its option's name, voxels inline only.
  api::ReadOptions read_options() const;
  // A refusal of the engine's plan with the server's own limits named.
  Status server_limits_named(const Status& status) const;
  Result<v1::Operation> find_operation(const std::string& id);
  // The loaded engine of a rig, from the cache or the store (once, however many ask at the same time). A rig file
  // that fails its checks is quarantined.
  Result<std::shared_ptr<const api::PoseEngine>> engine(const std::string& rig_id);
  void evict(const std::string& rig_id);
  ProgressHooks call_hooks(grpc::ServerContext* context) const;
  std::vector<std::pair<std::string, double>> gauges();

  std::unique_ptr<RigStore> store_;
  ServiceOptions options_;
  StallWatch stall_watch_;
  MemoryBudget memory_;
  ClientLimits client_limits_;
  const Tokens& tokens_;
  Metrics& metrics_;
  std::atomic<uint64_t> next_request_{1};

  std::mutex mutex_;  // operations, the build queue, pose slots, preview streams
  std::condition_variable changed_;
  std::map<std::string, std::shared_ptr<Job>> operations_;  // this run's builds
  std::map<std::string, std::shared_ptr<Job>> live_by_key_;  // queued or running
  std::deque<std::shared_ptr<Job>> build_queue_;
  int builds_running_ = 0;
  bool stopping_ = false;
  int poses_running_ = 0;
  int poses_waiting_ = 0;
  std::map<std::string, int> previews_by_client_;
  std::vector<std::thread> build_threads_;
  std::thread lease_thread_;

  std::mutex cache_mutex_;
  std::map<std::string, CacheEntry> cache_;
};

}  // namespace posewarp::server
