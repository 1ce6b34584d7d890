// MatchPosture: checked, admitted (client limit, a pose slot, memory for the target), then the rig's posture matched
// to the uploaded target's bones (api::match_posture) or a standard posture; the answer is small, sent at once.
#include "posewarp/api/match.h"
#include "convert.h"
#include "service.h"

namespace posewarp::server {
namespace {

// A match's memory: the target's labels as read, and as much again for its bones' surfaces and the Dice pass.
constexpr int64_t kMatchBytesPerVoxel = 2 * static_cast<int64_t>(sizeof(Label));

}  // namespace

grpc::Status PosewarpService::MatchPosture(grpc::ServerContext* context, const v1::MatchPostureRequest* request,
                                           v1::MatchPostureResponse* response) {
  Call call(frame_, context, "MatchPosture", request->rig_id());
  if (call.refused()) return call.refusal();
  if (Status s = check_match_request(*request); !s.ok()) return call.done(s);
  // The target is looked up before any slot is taken: a wrong id costs nothing.
  std::optional<VolumeRecord> target;
  if (!request->target_labels_volume_id().empty()) {
    Result<VolumeRecord> v = store_->volume(request->target_labels_volume_id());
    if (!v.ok()) return call.done(v.status().with_context("target_labels_volume_id"));
    if (v->kind == "intensity") {
      return call.done(invalid_argument_error(
          "target_labels_volume_id names a volume uploaded as VOLUME_KIND_INTENSITY (a CT or MRI); give the "
          "other scan's segmentation"));
    }
    target = std::move(v).value();
  }
  Result<ClientLimits::Entry> admitted = client_limits_.enter_call(call.client());
  if (!admitted.ok()) return call.done(admitted.status());
  Result<PoseSlots::Slot> slot = pose_slots_.acquire([context] { return context->IsCancelled(); });
  if (!slot.ok()) return call.done(slot.status());
  Result<EngineCache::Engine> engine = engines_.get(request->rig_id());
  if (!engine.ok()) return call.done(engine.status());
  store_->touch_rig(request->rig_id());
  const api::Rig& rig = (*engine)->rig();
  if (!target) {
    Result<api::Pose> pose = api::standard_posture(rig, request->standard());
    if (!pose.ok()) return call.done(pose.status());
    put_pose(*pose, response->mutable_pose());
    response->set_pose_json(api::pose_to_json(*pose));
    return call.done(ok_status());
  }
  Result<api::VolumeHeader> header = api::read_header(target->path, read_options());
  if (!header.ok()) return call.done(header.status().with_context("target_labels_volume_id"));
  Result<MemoryBudget::Reservation> memory =
      call.reserve(memory_, header->geometry.voxel_count() * kMatchBytesPerVoxel, "this match");
  if (!memory.ok()) return call.done(memory.status());
  Result<LabelVolume> labels = api::read_label_volume(target->path, read_options());
  if (!labels.ok()) return call.done(labels.status().with_context("target_labels_volume_id"));
  Result<api::LabelMap> names = rig.label_map;
  if (!request->label_map_json().empty()) {
    names = api::label_map_from_json(request->label_map_json(), "in label_map_json");
  } else if (!request->preset().empty()) {
    names = api::preset_by_name(request->preset());
  }
  if (!names.ok()) return call.done(names.status());
  api::MatchOptions options;
  options.constrain_hinges = !request->free_hinges();
  options.anatomical_ranges = !request->beyond_range();
  Result<api::PostureMatch> match = api::match_posture(rig, *labels, *names, options);
  if (!match.ok()) return call.done(match.status());
  put_pose(match->match.pose, response->mutable_pose());
  response->set_pose_json(api::pose_to_json(match->match.pose));
  for (const api::SegmentMatch& s : match->match.segments) put_segment_match(s, response->add_segments());
  for (const std::string& label : match->unnamed_labels) response->add_unnamed_labels(label);
  response->set_report_json(api::posture_match_to_json(*match));
  response->set_seconds(match->seconds);
  put_grid(labels->geometry(), response->mutable_target_grid());
  return call.done(ok_status());
}

}  // namespace posewarp::server
