// Loaded engines by rig id, under a byte budget (least recently used leave first), each rig loaded once however many
// calls ask for it at the same time. A rig file that fails its checks on load is quarantined, never served.
#pragma once

#include <chrono>
#include <cstdint>
#include <future>
#include <map>
#include <memory>
#include <mutex>
#include <string>

#include "admission.h"
#include "metrics.h"
#include "posewarp/api/pose_engine.h"
#include "store.h"

namespace posewarp::server {

class EngineCache {
 public:
  using Engine = std::shared_ptr<const api::PoseEngine>;

  // Loading reserves twice the rig file's size of `memory`; engines run poses with `pose_threads`. With a shared
  // index, a rig deleted through any replica leaves the cache.
  EngineCache(RigStore& store, MemoryBudget& memory, Metrics& metrics, int64_t budget_bytes, int pose_threads);

  // The loaded engine of `rig_id`, from the cache or the store.
  Result<Engine> get(const std::string& rig_id);
  // Poses holding the engine finish with it; the next get() loads it again.
  void evict(const std::string& rig_id);
  int64_t bytes() const;
  int64_t rigs() const;

 private:
  using EngineResult = Result<Engine>;
  struct Entry {
    std::shared_future<std::shared_ptr<EngineResult>> engine;
    int64_t bytes = 0;
    std::chrono::steady_clock::time_point last_used;
  };
  EngineResult load(const std::string& rig_id);
  // Least recently used engines leave until the cache is within its budget (`kept` stays). Under mutex_.
  void trim(const std::string& kept);
  // After missed notifications of a shared index: each cached rig is looked up again.
  void resync();

  RigStore& store_;
  MemoryBudget& memory_;
  Metrics& metrics_;
  const int64_t budget_bytes_;
  const int pose_threads_;
  mutable std::mutex mutex_;
  std::map<std::string, Entry> entries_;
};

}  // namespace posewarp::server
