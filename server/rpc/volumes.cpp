// UploadVolume: a header, then the chunks staged and the volume read before it is stored (intake.h).
#include "service.h"

namespace posewarp::server {

grpc::Status PosewarpService::UploadVolume(grpc::ServerContext* context,
                                           grpc::ServerReader<v1::UploadVolumeRequest>* reader, v1::Volume* response) {
  Call call(frame_, context, "UploadVolume");
  if (call.refused()) return call.refusal();
  v1::UploadVolumeRequest part;
  if (!call.read(reader, &part)) return call.done(client_gone());
  if (!part.has_header()) {
    return call.done(invalid_argument_error("an upload starts with its header (kind, format, size_bytes, sha256)"));
  }
  const v1::UploadVolumeHeader header = part.header();
  Result<UploadPlan> plan = check_upload_header(header, request_limits());
  if (!plan.ok()) return call.done(plan.status());
  // A file the store holds already is answered after the header: the client's chunks are never read.
  if (!plan->raw) {
    if (std::optional<v1::Volume> known = intake_.stored(header)) {
      *response = std::move(*known);
      return call.done(ok_status());
    }
  }
  StagedUpload upload;
  const std::string file_name = "upload" + plan->extension;
  if (Status s = intake_.stage(call, reader, header.size_bytes(), header.sha256(), file_name, &upload); !s.ok()) {
    return call.done(s);
  }
  Result<v1::Volume> stored =
      plan->raw ? intake_.store_raw(call, header, *plan, upload) : intake_.store_file(call, header, *plan, upload);
  if (!stored.ok()) return call.done(stored.status());
  *response = std::move(stored).value();
  return call.done(ok_status());
}

}  // namespace posewarp::server
