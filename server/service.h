// The gRPC service: a thin adapter between posewarp.v1 and the core's api (no pipeline logic here). Builds run on a
// bounded build queue, poses on a bounded number of slots; loaded engines stay in a cache under a byte budget.
#pragma once

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <future>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>

#include "posewarp/api/pose_engine.h"
#include "posewarp/v1/posewarp.grpc.pb.h"
#include "store.h"

namespace posewarp::server {

struct ServiceOptions {
  int build_queue = 4;                         // builds waiting behind the one running; past it RESOURCE_EXHAUSTED
  int build_threads = 0;                       // threads of a build (0: all cores)
  int pose_slots = 2;                          // poses running at once
  int pose_queue = 32;                         // poses waiting for a slot; past it RESOURCE_EXHAUSTED
  int pose_threads = 0;                        // threads of one pose (0: all cores)
  int64_t cache_bytes = int64_t{8} << 30;      // loaded engines kept, by Rig::footprint_bytes()
  int64_t max_upload_bytes = int64_t{4} << 30; // one uploaded file
  int64_t max_output_bytes = 0;                // one pose's outputs (0: half the machine's memory)
};

class PosewarpService final : public v1::Posewarp::Service {
 public:
  PosewarpService(RigStore store, ServiceOptions options);
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
  grpc::Status GetRig(grpc::ServerContext* context, const v1::GetRigRequest* request, v1::Rig* response) override;
  grpc::Status ListRigs(grpc::ServerContext* context, const v1::ListRigsRequest* request,
                        v1::ListRigsResponse* response) override;
  grpc::Status Pose(grpc::ServerContext* context, const v1::PoseRequest* request,
                    grpc::ServerWriter<v1::PoseResponse>* writer) override;
  grpc::Status Preview(grpc::ServerContext* context,
                       grpc::ServerReaderWriter<v1::PreviewResponse, v1::PreviewRequest>* stream) override;

  // Cancels queued and running builds (marked CANCELLED) and stops the build worker; poses in flight finish.
  void shutdown();

 private:
  struct Job {
    v1::Operation operation;  // guarded by mutex_
    v1::BuildRigRequest request;
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
  void run_build(const std::shared_ptr<Job>& job);
  void set_operation(const std::shared_ptr<Job>& job, const std::function<void(v1::Operation&)>& change);
  grpc::Status to_grpc(const Status& status) const;
  Result<std::shared_ptr<const api::PoseEngine>> engine(const std::string& rig_id);

  RigStore store_;
  ServiceOptions options_;

  std::mutex mutex_;  // operations, the build queue, pose slots
  std::condition_variable changed_;
  std::map<std::string, std::shared_ptr<Job>> operations_;
  std::deque<std::shared_ptr<Job>> build_queue_;
  bool stopping_ = false;
  int poses_running_ = 0;
  int poses_waiting_ = 0;
  std::thread build_thread_;

  std::mutex cache_mutex_;
  std::map<std::string, CacheEntry> cache_;
};

}  // namespace posewarp::server
