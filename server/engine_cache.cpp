// The engine cache: one load per cold rig, LRU under a byte budget, quarantine of a rig that fails its checks.
#include "engine_cache.h"

#include <spdlog/spdlog.h>

#include <vector>

#include "posewarp/api/rig_file.h"

namespace posewarp::server {

EngineCache::EngineCache(RigStore& store, MemoryBudget& memory, Metrics& metrics, int64_t budget_bytes,
                         int pose_threads)
    : store_(store), memory_(memory), metrics_(metrics), budget_bytes_(budget_bytes), pose_threads_(pose_threads) {
  if (!store_.index().shared()) return;
  store_.index().watch_deleted_rigs(
      [this](const std::string& rig_id) {
        evict(rig_id);
        spdlog::info("rig={} deleted by another replica; dropped from the cache", rig_id.substr(0, 16));
      },
      [this] { resync(); });
}

void EngineCache::resync() {
  std::vector<std::string> cached;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    for (const auto& [id, entry] : entries_) cached.push_back(id);
  }
  for (const std::string& id : cached) {
    Result<std::optional<RigRecord>> row = store_.index().rig(id);
    if (row.ok() && !*row) evict(id);
  }
}

Result<EngineCache::Engine> EngineCache::get(const std::string& rig_id) {
  std::promise<std::shared_ptr<EngineResult>> loading;
  std::shared_future<std::shared_ptr<EngineResult>> waiting;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = entries_.find(rig_id);
    if (it != entries_.end()) {
      it->second.last_used = std::chrono::steady_clock::now();
      waiting = it->second.engine;
    } else {
      // This caller loads; the ones arriving meanwhile wait for the same future (a cold rig is loaded once).
      entries_[rig_id] = {loading.get_future().share(), 0, std::chrono::steady_clock::now()};
    }
  }
  if (waiting.valid()) {
    metrics_.count("cache_hits");
    return *waiting.get();
  }
  metrics_.count("cache_misses");
  auto result = std::make_shared<EngineResult>(load(rig_id));
  loading.set_value(result);
  std::lock_guard<std::mutex> lock(mutex_);
  if (!result->ok()) {
    entries_.erase(rig_id);  // a failure is not cached: the next request tries again
    return *result;
  }
  entries_[rig_id].bytes = (**result)->rig().footprint_bytes();
  trim(rig_id);
  return *result;
}

EngineCache::EngineResult EngineCache::load(const std::string& rig_id) {
  POSEWARP_ASSIGN_OR_RETURN(const RigRecord stored, store_.rig(rig_id));
  // Loading holds the file's bytes beside the rig made of them; the loaded engine then counts in the cache.
  POSEWARP_ASSIGN_OR_RETURN(const MemoryBudget::Reservation loading_memory,
                            memory_.reserve(static_cast<int64_t>(stored.size_bytes) * 2, "loading this rig",
                                            std::chrono::steady_clock::now() + std::chrono::seconds(60), nullptr));
  Result<api::Rig> rig = api::load_rig(stored.path);
  if (!rig.ok() && rig.status().code() == StatusCode::kDataLoss) {
    // Never served: moved aside for a person to look at, and the client told to rebuild.
    if (Status q = store_.quarantine_rig(rig_id, rig.status().message()); !q.ok()) spdlog::error("{}", q.message());
    spdlog::error("rig={} failed its checks on load and was quarantined", rig_id.substr(0, 16));
    return data_loss_error("rig " + rig_id +
                           " failed its checksums in the store and was quarantined; build it "
                           "again (or upload a good copy with UploadRig)");
  }
  if (!rig.ok()) return rig.status();
  ProgressHooks hooks;
  hooks.threads = pose_threads_;
  // A rig from an earlier posewarp lacks what this one keeps in a rig (the engine's tables, the skin vertices): made
  // here once and written back, so that a later load (a restart, another replica, an evicted engine) reads them.
  const std::string missing = api::missing_from_rig(*rig);
  POSEWARP_ASSIGN_OR_RETURN(const bool completed, api::complete_rig(*rig, hooks));
  if (completed) {
    if (Status kept = store_.rewrite_rig(stored, api::rig_to_bytes(*rig)); kept.ok()) {
      spdlog::info("rig={} completed with {}, and written back to the store", rig_id.substr(0, 16), missing);
    } else {
      spdlog::warn("rig={} completed for this load only; writing it back failed: {}", rig_id.substr(0, 16),
                   kept.message());
    }
  }
  POSEWARP_ASSIGN_OR_RETURN(api::PoseEngine engine, api::PoseEngine::create(std::move(rig).value(), hooks));
  return std::make_shared<const api::PoseEngine>(std::move(engine));
}

void EngineCache::trim(const std::string& kept) {
  for (;;) {
    int64_t total = 0;
    auto oldest = entries_.end();
    for (auto it = entries_.begin(); it != entries_.end(); ++it) {
      total += it->second.bytes;
      if (it->first != kept && it->second.bytes > 0 &&
          (oldest == entries_.end() || it->second.last_used < oldest->second.last_used)) {
        oldest = it;
      }
    }
    if (total <= budget_bytes_ || oldest == entries_.end()) return;
    entries_.erase(oldest);
    metrics_.count("cache_evictions");
  }
}

void EngineCache::evict(const std::string& rig_id) {
  std::lock_guard<std::mutex> lock(mutex_);
  entries_.erase(rig_id);
}

int64_t EngineCache::bytes() const {
  std::lock_guard<std::mutex> lock(mutex_);
  int64_t total = 0;
  for (const auto& [id, entry] : entries_) total += entry.bytes;
  return total;
}

int64_t EngineCache::rigs() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return static_cast<int64_t>(entries_.size());
}

}  // namespace posewarp::server
