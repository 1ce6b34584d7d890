// Preview: a bidirectional stream of poses answered with surfaces, newest update first (preview_session.h).
#include <chrono>

#include "posewarp/api/support.h"
#include "convert.h"
#include "service.h"
#include "status_map.h"

namespace posewarp::server {

v1::PreviewResponse PosewarpService::answer_preview(Call& call, PreviewSession& session,
                                                    const v1::PreviewRequest& update, uint64_t dropped) {
  // A refused update is answered with its code; the stream goes on (a slider's next move may be fine).
  const auto refusal = [&](const Status& status) {
    const grpc::Status converted = to_grpc(status, store_->directory());
    return preview_refusal(update, dropped, static_cast<int32_t>(converted.error_code()), converted.error_message());
  };
  if (!session.engine) {
    call.set_rig(update.rig_id());
    Result<EngineCache::Engine> loaded = api::is_hex_id(update.rig_id())
                                             ? engines_.get(update.rig_id())
                                             : Result<EngineCache::Engine>(invalid_argument_error(
                                                   "the first preview update names the rig (64 hex digits)"));
    if (!loaded.ok()) return refusal(loaded.status());
    session.engine = *loaded;
  }
  const Stopwatch start;
  Result<api::Pose> pose = check_preview_request(update);
  Result<api::PreviewResult> preview = pose.ok() ? session.engine->preview(*pose, method_of(update.method()))
                                                 : Result<api::PreviewResult>(pose.status());
  if (!preview.ok()) return refusal(preview.status());
  return preview_answer(update, dropped, *preview, session, start);
}

grpc::Status PosewarpService::Preview(grpc::ServerContext* context, PreviewStream* stream) {
  Call call(frame_, context, "Preview");
  if (call.refused()) return call.refusal();
  Result<PreviewStreams::Open> open = previews_.open(call.client());
  if (!open.ok()) return call.done(open.status());
  // A reader thread keeps only the newest update; this thread answers whatever is newest when it is free.
  PreviewUpdates updates(context, stream);
  PreviewSession session;
  v1::PreviewRequest update;
  uint64_t dropped = 0;
  while (updates.next(&update, &dropped)) {
    metrics_.count("preview_updates");
    if (dropped > 0) metrics_.count("preview_updates_dropped", static_cast<int64_t>(dropped));
    if (context->IsCancelled()) return call.done(cancelled_error("the client cancelled the preview"));
    if (!call.write(stream, answer_preview(call, session, update, dropped))) return call.done(client_gone());
  }
  return call.done(ok_status());  // the client closed and everything was answered
}

}  // namespace posewarp::server
