// PosewarpService: its pieces put together, the gauges, the stop, and the limits its handlers share.
#include "service.h"

#include <algorithm>
#include <thread>

#include "posewarp/api/support.h"

namespace posewarp::server {
namespace {

ServiceOptions resolved(ServiceOptions options) {
  if (options.pose_slots <= 0) options.pose_slots = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  return options;
}

BuildQueueOptions build_options(const ServiceOptions& options) {
  BuildQueueOptions b;
  b.workers = options.build_workers;
  b.queue = options.build_queue;
  b.threads = options.build_threads;
  b.replica = options.replica;
  b.lease_s = options.lease_s;
  return b;
}

}  // namespace

PosewarpService::PosewarpService(std::unique_ptr<RigStore> store, ServiceOptions options, const Tokens& tokens,
                                 Metrics& metrics)
    : store_(std::move(store)),
      options_(resolved(std::move(options))),
      metrics_(metrics),
      stall_watch_(std::chrono::milliseconds(std::max(1, options_.stall_timeout_ms)),
                   [&metrics] { metrics.count("streams_stalled"); }),
      frame_{stall_watch_, tokens, metrics, store_->directory()},
      memory_(options_.memory_bytes),
      client_limits_(options_.client),
      intake_(*store_, client_limits_, memory_, read_options()),
      engines_(*store_, memory_, metrics, options_.cache_bytes, options_.pose_threads),
      builds_(*store_, metrics, build_options(options_)),
      pose_slots_(options_.pose_slots, options_.pose_queue),
      previews_(options_.preview_streams_per_client),
      kept_output_trim_(std::chrono::seconds(std::max(0, options_.kept_output_idle_s))) {
  metrics_.set_gauges([this] { return gauges(); });
  // An idle time of 0 keeps nothing (no trim would give it back).
  api::set_voxel_memory_kept_limit(
      options_.kept_output_idle_s > 0 ? static_cast<size_t>(std::max<int64_t>(0, options_.kept_output_bytes)) : 0);
}

PosewarpService::~PosewarpService() {
  shutdown();
  metrics_.set_gauges(nullptr);
}

void PosewarpService::shutdown() {
  pose_slots_.stop();
  builds_.shutdown();
}

std::vector<std::pair<std::string, double>> PosewarpService::gauges() {
  std::vector<std::pair<std::string, double>> values;
  values.emplace_back("builds_running", builds_.running());
  values.emplace_back("build_queue_depth", builds_.queued());
  values.emplace_back("poses_running", pose_slots_.running());
  values.emplace_back("pose_queue_depth", pose_slots_.waiting());
  values.emplace_back("preview_streams", previews_.count());
  values.emplace_back("memory_reserved_bytes", static_cast<double>(memory_.used()));
  values.emplace_back("memory_budget_bytes", static_cast<double>(memory_.total()));
  values.emplace_back("cache_bytes", static_cast<double>(engines_.bytes()));
  values.emplace_back("cache_rigs", static_cast<double>(engines_.rigs()));
  values.emplace_back("kept_output_bytes", static_cast<double>(api::voxel_memory_kept()));
  return values;
}

RequestLimits PosewarpService::request_limits() const {
  RequestLimits limits;
  limits.max_upload_bytes = options_.max_upload_bytes;
  limits.max_volume_voxels = options_.max_volume_voxels;
  return limits;
}

api::ReadOptions PosewarpService::read_options() const {
  api::ReadOptions options;
  options.max_voxels = options_.max_volume_voxels;
  options.voxel_limit_name = "the server's --max-volume-voxels";
  options.inline_data_only = true;
  return options;
}

Status PosewarpService::server_limits_named(const Status& status) const {
  if (status.code() != StatusCode::kResourceExhausted) return status;
  return Status(status.code(), status.message() + " (this server makes output grids of at most " +
                                   std::to_string(options_.max_output_voxels) + " voxels, its --max-output-voxels, " +
                                   "within a memory budget of " + std::to_string(memory_.total() >> 20) +
                                   " MB, its --memory-mb; max_output_bytes lowers it for one request)");
}

int64_t PosewarpService::output_budget(uint64_t requested) const {
  int64_t budget = memory_.total();
  if (options_.max_output_bytes > 0) budget = std::min(budget, options_.max_output_bytes);
  if (requested > 0) budget = std::min(budget, static_cast<int64_t>(std::min<uint64_t>(requested, uint64_t{1} << 62)));
  return budget;
}

}  // namespace posewarp::server
