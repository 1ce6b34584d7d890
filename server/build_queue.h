// Rig builds as operations: a bounded queue, build workers, identical requests sharing one operation, progress for
// watchers, and with a shared index the claims and leases by which replicas build each rig once. Everything here is
// under the queue's own mutex; the operations' rows live in the store's index across restarts.
#pragma once

#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <deque>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <thread>
#include <vector>

#include "metrics.h"
#include "posewarp/api/files.h"
#include "posewarp/api/rig.h"
#include "posewarp/api/support.h"
#include "posewarp/v1/posewarp.pb.h"
#include "store.h"

namespace posewarp::server {

struct BuildQueueOptions {
  int workers = 1;                   // builds running at once
  int queue = 4;                     // builds waiting for a worker
  int threads = 0;                   // threads of a build (0: all cores)
  std::string replica = "posewarp";  // this replica's name in a shared index (owner of its builds)
  int lease_s = 30;                  // a shared index's build leases, renewed every third of it
};

class BuildQueue {
 public:
  BuildQueue(RigStore& store, Metrics& metrics, BuildQueueOptions options);
  ~BuildQueue();
  BuildQueue(const BuildQueue&) = delete;
  BuildQueue& operator=(const BuildQueue&) = delete;

  // The operation of `request`: a new one queued (its id made unique with `unique`), or the one already queued or
  // running for the same request. UNAVAILABLE while stopping, RESOURCE_EXHAUSTED when the queue is full.
  Result<v1::Operation> submit(const v1::BuildRigRequest& request, uint64_t unique);
  // An operation of this run, or of an earlier one (or another replica's) from the index.
  Result<v1::Operation> find(const std::string& id);
  // Cancels a queued or running build; an operation that ended already is answered as it is.
  Result<v1::Operation> cancel(const std::string& id);
  // Hands each new state of the operation to `write` until it is final. CANCELLED when `write` fails (the client
  // went away) or `cancelled()` turns true.
  Status watch(const std::string& id, const std::function<bool(const v1::Operation&)>& write,
               const std::function<bool()>& cancelled);
  // Refuses new builds, cancels queued and running ones (marked CANCELLED) and waits for the workers.
  void shutdown();
  int running() const;
  int queued() const;

 private:
  struct Job {
    v1::Operation operation;  // guarded by mutex_
    // The operation as each stage it has left ended (its fraction 1), in order, guarded by mutex_: a watch sends
    // every stage, also one that passed between two of its writes or before it opened.
    std::vector<v1::Operation> passed;
    v1::BuildRigRequest request;
    std::string key;  // the request without its name: identical builds share one operation
    CancelFlag cancel;
    Stopwatch started;
  };

  void worker();
  // With a shared index: renews this replica's leases and fails builds whose replica stopped renewing theirs.
  void lease_keeper();
  // Waits until this replica holds the build of `rig_id` (true), or another replica's build made it (false).
  Result<bool> claim(const std::shared_ptr<Job>& job, const std::string& rig_id);
  // The inputs of a build, read from the store and the request.
  Result<api::BuildInputs> inputs_of(const v1::BuildRigRequest& request);
  Status build(const std::shared_ptr<Job>& job);
  // The build's rig, built here and put in the store.
  Status build_here(const std::shared_ptr<Job>& job, const api::BuildInputs& inputs, const api::BuildParams& params);
  void finish(const std::shared_ptr<Job>& job, const Status& status, const Stopwatch& started);
  void succeeded(const std::shared_ptr<Job>& job, const std::string& rig_id);
  Status watch_row(const std::string& id, const std::function<bool(const v1::Operation&)>& write,
                   const std::function<bool()>& cancelled);
  std::shared_ptr<Job> live(const std::string& id);
  // Under mutex_.
  void persist(const Job& job);
  void set_operation(const std::shared_ptr<Job>& job, const std::function<void(v1::Operation&)>& change, bool persist);

  RigStore& store_;
  Metrics& metrics_;
  BuildQueueOptions options_;
  mutable std::mutex mutex_;
  std::condition_variable changed_;                          // a queued build, a build's progress, or the stop
  std::map<std::string, std::shared_ptr<Job>> operations_;   // this run's builds
  std::map<std::string, std::shared_ptr<Job>> live_by_key_;  // queued or running
  std::deque<std::shared_ptr<Job>> queue_;
  int running_ = 0;
  bool stopping_ = false;
  std::vector<std::thread> workers_;
  std::thread lease_thread_;
};

}  // namespace posewarp::server
