// Pose: checked, admitted (client limit, pose slot, memory), planned, then streamed as the engine goes (pose_stream.h).
#include <spdlog/spdlog.h>

#include <chrono>
#include <thread>

#include "pose_stream.h"
#include "service.h"

namespace posewarp::server {

grpc::Status PosewarpService::Pose(grpc::ServerContext* context, const v1::PoseRequest* request,
                                   grpc::ServerWriter<v1::PoseResponse>* writer) {
  Call call(frame_, context, "Pose", request->rig_id());
  if (call.refused()) return call.refusal();
  Result<CheckedPose> checked = check_pose_request(*request);
  if (!checked.ok()) return call.done(checked.status());
  Result<ClientLimits::Entry> admitted = client_limits_.enter_call(call.client());
  if (!admitted.ok()) return call.done(admitted.status());
  // A slot, or a place in the bounded queue, or RESOURCE_EXHAUSTED at once; given back as soon as the engine is
  // done: sending what it made (under the stall watch) holds no slot.
  Result<PoseSlots::Slot> slot = pose_slots_.acquire([context] { return context->IsCancelled(); });
  if (!slot.ok()) return call.done(slot.status());
  if (options_.test_pause_in_pose_s > 0.0) {
    spdlog::info("test hook: pausing {:.1f} s inside a pose", options_.test_pause_in_pose_s);
    std::this_thread::sleep_for(std::chrono::duration<double>(options_.test_pause_in_pose_s));
  }
  Result<EngineCache::Engine> engine = engines_.get(request->rig_id());
  if (!engine.ok()) return call.done(engine.status());
  store_->touch_rig(request->rig_id());
  const api::Rig& rig = (*engine)->rig();
  const uint64_t chunk_bytes = checked->chunk_bytes;
  api::PoseRequest core = engine_request(std::move(checked).value(), *request, rig);
  core.limits.max_bytes = output_budget(request->max_output_bytes());
  core.limits.max_voxels = options_.max_output_voxels;
  Result<VolumeEncoding> encoding = volume_encoding(*request, rig);
  if (!encoding.ok()) return call.done(encoding.status());
  Result<api::PosePlan> plan = (*engine)->plan(core);
  if (!plan.ok()) return call.done(server_limits_named(plan.status()));
  Result<MemoryBudget::Reservation> memory =
      call.reserve(memory_, pose_memory_estimate(*plan, rig, core, *encoding), "this pose");
  if (!memory.ok()) return call.done(memory.status());
  const PoseWrite write = [&call, writer](const v1::PoseResponse& message) { return call.write(writer, message); };
  if (!write(pose_header(*plan, rig, core, *encoding, request->format()))) return call.done(client_gone());
  return call.done(stream_pose(
      **engine, std::move(core), call.hooks(options_.pose_threads), *encoding, chunk_bytes, write,
      [&slot] { slot->release(); }, [&call] { return call.stream().stalled(); }));
}

}  // namespace posewarp::server
