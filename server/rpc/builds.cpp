// BuildRig: the request and its volumes checked, then an operation on the build queue (build_queue.h).
#include "service.h"

namespace posewarp::server {

Status PosewarpService::check_build_volumes(const v1::BuildRigRequest& request) const {
  // The swap is refused before any work; a volume of an older store, adopted without its kind, is checked by the
  // build.
  Result<VolumeRecord> labels = store_->volume(request.labels_volume_id());
  if (!labels.ok()) return labels.status().with_context("labels_volume_id");
  std::optional<VolumeRecord> ct;
  if (!request.ct_volume_id().empty()) {
    Result<VolumeRecord> v = store_->volume(request.ct_volume_id());
    if (!v.ok()) return v.status().with_context("ct_volume_id");
    ct = *v;
  }
  const bool labels_wrong = labels->kind == "intensity";
  const bool ct_wrong = ct && ct->kind == "labels";
  if (labels_wrong && ct_wrong) {
    return invalid_argument_error(
        "labels_volume_id names an intensity volume and ct_volume_id a label volume: they "
        "are swapped");
  }
  if (labels_wrong) {
    return invalid_argument_error(
        "labels_volume_id names a volume uploaded as VOLUME_KIND_INTENSITY (a CT or MRI); "
        "give the segmentation's id");
  }
  if (ct_wrong) {
    return invalid_argument_error(
        "ct_volume_id names a volume uploaded as VOLUME_KIND_LABELS (a segmentation); give "
        "the CT's id");
  }
  return ok_status();
}

grpc::Status PosewarpService::BuildRig(grpc::ServerContext* context, const v1::BuildRigRequest* request,
                                       v1::Operation* response) {
  Call call(frame_, context, "BuildRig");
  if (call.refused()) return call.refusal();
  if (Status s = check_build_request(*request); !s.ok()) return call.done(s);
  if (Status s = check_build_volumes(*request); !s.ok()) return call.done(s);
  Result<v1::Operation> operation = builds_.submit(*request, frame_.next_request++);
  if (!operation.ok()) return call.done(operation.status());
  *response = std::move(operation).value();
  return call.done(ok_status());
}

}  // namespace posewarp::server
