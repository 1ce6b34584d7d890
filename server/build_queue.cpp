// The build queue: operations, workers, leases and claims among replicas, progress for watchers.
#include "build_queue.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <optional>

#include "call.h"
#include "convert.h"
#include "posewarp/api/rig_file.h"
#include "status_map.h"

namespace posewarp::server {

BuildQueue::BuildQueue(RigStore& store, Metrics& metrics, BuildQueueOptions options)
    : store_(store), metrics_(metrics), options_(std::move(options)) {
  for (int i = 0; i < std::max(1, options_.workers); ++i) workers_.emplace_back([this] { worker(); });
  if (store_.index().shared()) lease_thread_ = std::thread([this] { lease_keeper(); });
}

BuildQueue::~BuildQueue() {
  shutdown();
}

void BuildQueue::persist(const Job& job) {
  OperationRecord record = record_from(job.operation, job.request);
  record.owner = options_.replica;
  record.lease_s = options_.lease_s;
  if (Status s = store_.index().put_operation(record); !s.ok()) {
    spdlog::error("operation {}: {}", job.operation.id(), s.message());
  }
}

Result<v1::Operation> BuildQueue::submit(const v1::BuildRigRequest& request, uint64_t unique) {
  v1::BuildRigRequest unnamed = request;
  unnamed.clear_name();
  const std::string key = api::sha256_hex(unnamed.SerializeAsString());
  auto job = std::make_shared<Job>();
  job->request = request;
  job->key = key;
  job->operation.set_id(api::sha256_hex(key +
                                        std::to_string(std::chrono::system_clock::now().time_since_epoch().count()) +
                                        std::to_string(unique))
                            .substr(0, 32));
  job->operation.set_state(v1::Operation::QUEUED);
  job->operation.set_name(request.name());
  job->operation.set_created(iso_now());
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (stopping_) return unavailable_error("the server is shutting down; try again shortly");
    // The same build already queued or running: its operation, not a second build.
    if (const auto live = live_by_key_.find(key); live != live_by_key_.end()) return live->second->operation;
    if (static_cast<int>(queue_.size()) >= options_.queue) {
      return resource_exhausted_error("the build queue is full (" + std::to_string(options_.queue) +
                                      " waiting); try again when a build has finished");
    }
    OperationRecord record = record_from(job->operation, job->request);
    record.owner = options_.replica;
    record.lease_s = options_.lease_s;
    POSEWARP_RETURN_IF_ERROR(store_.index().put_operation(record));
    operations_[job->operation.id()] = job;
    live_by_key_[key] = job;
    queue_.push_back(job);
  }
  changed_.notify_all();
  return job->operation;
}

void BuildQueue::worker() {
  for (;;) {
    std::shared_ptr<Job> job;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      changed_.wait(lock, [this] { return stopping_ || !queue_.empty(); });
      if (stopping_) return;
      job = queue_.front();
      queue_.pop_front();
      job->operation.set_state(v1::Operation::RUNNING);
      job->started.restart();
      ++running_;
      persist(*job);
    }
    changed_.notify_all();
    const Stopwatch started;
    finish(job, build(job), started);
    {
      std::lock_guard<std::mutex> lock(mutex_);
      --running_;
      live_by_key_.erase(job->key);
    }
    changed_.notify_all();
  }
}

void BuildQueue::lease_keeper() {
  const auto period = std::chrono::milliseconds(std::max(1, options_.lease_s) * 1000 / 3);
  std::unique_lock<std::mutex> lock(mutex_);
  while (!stopping_) {
    // Woken early only to stop (changed_ also carries every build's progress).
    changed_.wait_until(lock, std::chrono::steady_clock::now() + period, [this] { return stopping_; });
    if (stopping_) break;
    lock.unlock();
    if (Status s = store_.index().renew_operations(options_.replica, options_.lease_s); !s.ok()) {
      spdlog::warn("cannot renew this replica's build leases: {}", s.message());
    }
    Result<int> failed = store_.index().fail_expired_operations(static_cast<int>(StatusCode::kAborted),
                                                                "the replica running the build stopped; build again");
    if (failed.ok() && *failed > 0) spdlog::warn("{} build(s) of a stopped replica marked failed", *failed);
    lock.lock();
  }
}

Result<bool> BuildQueue::claim(const std::shared_ptr<Job>& job, const std::string& rig_id) {
  bool told = false;
  for (;;) {
    POSEWARP_ASSIGN_OR_RETURN(const bool mine, store_.index().claim_build(rig_id, options_.replica, options_.lease_s));
    if (mine) return true;
    if (!told) {
      spdlog::info("operation={} rig={} is being built by another replica; waiting for it", job->operation.id(),
                   rig_id.substr(0, 16));
      set_operation(
          job, [](v1::Operation& op) { op.set_stage("waiting for another replica's build"); }, false);
      metrics_.count("builds_waited_for_another_replica");
      told = true;
    }
    for (int i = 0; i < 5 && !job->cancel.cancelled(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(100));
    if (job->cancel.cancelled()) return cancelled_error("the build was cancelled");
    // Built by the other replica: done. Its claim released without a rig (it failed or died): tried again above.
    if (store_.rig(rig_id).ok()) return false;
  }
}

void BuildQueue::set_operation(const std::shared_ptr<Job>& job, const std::function<void(v1::Operation&)>& change,
                               bool persist) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const v1::Operation before = job->operation;
    change(job->operation);
    job->operation.set_elapsed_s(
        job->started.seconds());
    if (!before.stage().empty() && before.stage() != job->operation.stage()) {
      v1::Operation& ended = job->passed.emplace_back(before);
      ended.set_stage_fraction(1.0);
      ended.set_elapsed_s(job->operation.elapsed_s());
    }
    if (persist) this->persist(*job);
  }
  changed_.notify_all();
}

void BuildQueue::succeeded(const std::shared_ptr<Job>& job, const std::string& rig_id) {
  set_operation(
      job,
      [&](v1::Operation& op) {
        op.set_state(v1::Operation::SUCCEEDED);
        op.set_rig_id(rig_id);
      },
      true);
}

void BuildQueue::finish(const std::shared_ptr<Job>& job, const Status& status,
                        const Stopwatch& started) {
  const grpc::Status g = to_grpc(status, store_.directory());
  const std::string code = status_code_name(status.code()).data();
  metrics_.observe("build", code, started.seconds());
  spdlog::info("operation={} build status={} s={:.1f}", job->operation.id(), code,
               started.seconds());
  set_operation(
      job,
      [&](v1::Operation& op) {
        if (status.ok()) return;
        op.set_state(status.code() == StatusCode::kCancelled ? v1::Operation::CANCELLED : v1::Operation::FAILED);
        op.set_error_code(static_cast<int32_t>(g.error_code()));
        op.set_error_message(g.error_message());
      },
      true);
}

Result<api::BuildInputs> BuildQueue::inputs_of(const v1::BuildRigRequest& request) {
  api::BuildInputs inputs;
  POSEWARP_ASSIGN_OR_RETURN(const VolumeRecord labels, store_.volume(request.labels_volume_id()));
  POSEWARP_ASSIGN_OR_RETURN(inputs.labels, api::read_label_volume(labels.path));
  if (!request.ct_volume_id().empty()) {
    POSEWARP_ASSIGN_OR_RETURN(const VolumeRecord ct, store_.volume(request.ct_volume_id()));
    POSEWARP_ASSIGN_OR_RETURN(inputs.ct, api::read_intensity_volume(ct.path));
  }
  POSEWARP_ASSIGN_OR_RETURN(inputs.label_map,
                            request.label_map_json().empty()
                                ? api::preset_by_name(request.preset().empty() ? "totalsegmentator" : request.preset())
                                : api::label_map_from_json(request.label_map_json(), "in the request"));
  if (!request.rig_spec_json().empty()) {
    POSEWARP_ASSIGN_OR_RETURN(inputs.spec, api::rig_spec_from_json(request.rig_spec_json(), "in the request"));
  }
  inputs.labels_source = "volume " + request.labels_volume_id();
  if (!request.ct_volume_id().empty()) inputs.ct_source = "volume " + request.ct_volume_id();
  return inputs;
}

Status BuildQueue::build(const std::shared_ptr<Job>& job) {
  POSEWARP_ASSIGN_OR_RETURN(const api::BuildInputs inputs, inputs_of(job->request));
  const api::BuildParams params;
  const std::string id = api::rig_id_of(inputs, params);
  if (store_.rig(id).ok()) {  // built before from the same inputs: no second build
    succeeded(job, id);
    return ok_status();
  }
  // Replicas sharing the store build the same rig once: the claim's holder builds, the others wait for its rig.
  POSEWARP_ASSIGN_OR_RETURN(const bool mine, claim(job, id));
  if (!mine) {
    succeeded(job, id);
    return ok_status();
  }
  struct Release {
    StoreIndex& index;
    const std::string& rig_id;
    const std::string& owner;
    ~Release() { (void)index.release_build(rig_id, owner); }
  } release{store_.index(), id, options_.replica};
  if (store_.rig(id).ok()) {  // finished by another replica just before the claim
    succeeded(job, id);
    return ok_status();
  }
  return build_here(job, inputs, params);
}

Status BuildQueue::build_here(const std::shared_ptr<Job>& job, const api::BuildInputs& inputs,
                              const api::BuildParams& params) {
  ProgressHooks hooks;
  hooks.threads = options_.threads;
  hooks.cancel_requested = job->cancel.as_hook();
  hooks.on_progress = [&](std::string_view stage, double fraction) {
    set_operation(
        job,
        [&](v1::Operation& op) {
          op.set_stage(std::string(stage));
          op.set_stage_fraction(fraction);
        },
        false);
  };
  POSEWARP_ASSIGN_OR_RETURN(const api::Rig rig, api::build_rig(inputs, params, hooks));
  if (job->cancel.cancelled()) return cancelled_error("the build was cancelled");
  const v1::BuildRigRequest& request = job->request;
  RigRecord record;
  record.id = rig.id();
  record.name = request.name();
  record.labels_volume_id = request.labels_volume_id();
  record.ct_volume_id = request.ct_volume_id();
  for (const auto& [stage, seconds] : rig.provenance.stage_seconds) record.build_seconds += seconds;
  POSEWARP_RETURN_IF_ERROR(store_.put_rig(record, api::rig_to_bytes(rig)));
  metrics_.count("rigs_built");  // by this replica (replicas sharing a store build each rig once in all)
  succeeded(job, record.id);
  return ok_status();
}

std::shared_ptr<BuildQueue::Job> BuildQueue::live(const std::string& id) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = operations_.find(id);
  return it == operations_.end() ? nullptr : it->second;
}

Result<v1::Operation> BuildQueue::find(const std::string& id) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (const auto it = operations_.find(id); it != operations_.end()) return it->second->operation;
  }
  if (id.empty() || id.size() > 64) return invalid_argument_error("an operation id is 32 hex digits (from BuildRig)");
  POSEWARP_ASSIGN_OR_RETURN(const std::optional<OperationRecord> row, store_.index().operation(id));
  if (!row) return not_found_error("no operation " + id + " on this server (ListOperations shows them)");
  return operation_from(*row);
}

Result<v1::Operation> BuildQueue::cancel(const std::string& id) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = operations_.find(id);
    if (it != operations_.end()) {
      const std::shared_ptr<Job>& job = it->second;
      job->cancel.cancel();
      if (job->operation.state() == v1::Operation::QUEUED) {
        queue_.erase(std::remove(queue_.begin(), queue_.end(), job), queue_.end());
        live_by_key_.erase(job->key);
        job->operation.set_state(v1::Operation::CANCELLED);
        job->operation.set_error_code(static_cast<int32_t>(StatusCode::kCancelled));
        job->operation.set_error_message("cancelled before it started");
        persist(*job);
      }
      changed_.notify_all();
      return job->operation;
    }
  }
  return find(id);  // finished in an earlier run
}

Status BuildQueue::watch(const std::string& id, const std::function<bool(const v1::Operation&)>& write,
                         const std::function<bool()>& cancelled) {
  const std::shared_ptr<Job> job = live(id);
  if (!job) return watch_row(id, write, cancelled);
  std::unique_lock<std::mutex> lock(mutex_);
  std::string last;
  size_t sent = 0;  // of job->passed
  for (;;) {
    while (sent < job->passed.size()) {
      const v1::Operation ended = job->passed[sent++];
      lock.unlock();
      const bool written = write(ended);
      lock.lock();
      if (!written) return client_gone();
    }
    const v1::Operation now = job->operation;
    const std::string serialized = now.SerializeAsString();
    if (serialized != last) {
      last = serialized;
      lock.unlock();
      const bool written = write(now);
      lock.lock();
      if (!written) return client_gone();
    }
    if (is_final(now.state())) return ok_status();
    if (cancelled()) return cancelled_error("the client cancelled the watch");
    changed_.wait_for(lock, std::chrono::milliseconds(200));
  }
}

// An operation of an earlier run (final already), or, with a shared index, one another replica runs: its row is
// followed until it ends (its state only; the stages are the running replica's).
Status BuildQueue::watch_row(const std::string& id, const std::function<bool(const v1::Operation&)>& write,
                             const std::function<bool()>& cancelled) {
  std::string last;
  for (;;) {
    POSEWARP_ASSIGN_OR_RETURN(const v1::Operation operation, find(id));
    if (const std::string serialized = operation.SerializeAsString(); serialized != last) {
      last = serialized;
      if (!write(operation)) return client_gone();
    }
    if (is_final(operation.state()) || !store_.index().shared()) return ok_status();
    if (cancelled()) return cancelled_error("the client cancelled the watch");
    std::this_thread::sleep_for(std::chrono::milliseconds(250));
  }
}

void BuildQueue::shutdown() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (stopping_) return;
    stopping_ = true;
    for (auto& [id, job] : operations_) {
      job->cancel.cancel();
      if (job->operation.state() == v1::Operation::QUEUED) {
        job->operation.set_state(v1::Operation::CANCELLED);
        job->operation.set_error_code(static_cast<int32_t>(StatusCode::kCancelled));
        job->operation.set_error_message("the server stopped before the build started; build again");
        persist(*job);
      }
    }
    queue_.clear();
  }
  changed_.notify_all();
  for (std::thread& t : workers_) {
    if (t.joinable()) t.join();
  }
  if (lease_thread_.joinable()) lease_thread_.join();
}

int BuildQueue::running() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return running_;
}

int BuildQueue::queued() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return static_cast<int>(queue_.size());
}

}  // namespace posewarp::server
