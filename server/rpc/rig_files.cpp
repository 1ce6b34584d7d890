// DownloadRig and UploadRig: a rig's file as stored, checked before it is sent or stored.
#include <algorithm>

#include "convert.h"
#include "posewarp/api/rig_file.h"
#include "service.h"

namespace posewarp::server {
namespace {

// Streams `size` bytes from `data` as chunks of at most `chunk` bytes through `put(offset, bytes)`.
template <typename Put>
bool stream_chunks(const char* data, uint64_t size, uint64_t chunk, Put&& put) {
  for (uint64_t offset = 0; offset < size; offset += chunk) {
    if (!put(offset, std::string(data + offset, std::min(chunk, size - offset)))) return false;
  }
  return true;
}

}  // namespace

grpc::Status PosewarpService::DownloadRig(grpc::ServerContext* context, const v1::GetRigRequest* request,
                                          grpc::ServerWriter<v1::RigChunk>* writer) {
  Call call(frame_, context, "DownloadRig", request->rig_id());
  if (call.refused()) return call.refusal();
  Result<RigRecord> stored = store_->rig(request->rig_id());
  if (!stored.ok()) return call.done(stored.status());
  Result<ClientLimits::Entry> admitted = client_limits_.enter_call(call.client());
  if (!admitted.ok()) return call.done(admitted.status());
  Result<MemoryBudget::Reservation> memory =
      call.reserve(memory_, static_cast<int64_t>(stored->size_bytes) * 3, "sending this rig");
  if (!memory.ok()) return call.done(memory.status());
  Result<std::string> bytes = api::read_text_input(stored->path, "rig file", int64_t{1} << 40);
  if (!bytes.ok()) return call.done(bytes.status());
  // The file as stored, checked first: a damaged rig is quarantined, never sent.
  if (Result<api::Rig> check = api::rig_from_bytes(*bytes, "rig " + stored->id); !check.ok()) {
    engines_.evict(stored->id);
    (void)store_->quarantine_rig(stored->id, check.status().message());
    return call.done(data_loss_error("rig " + stored->id +
                                     " failed its checksums in the store and was quarantined; "
                                     "build it again"));
  }
  const std::string sha = api::sha256_hex(*bytes);
  const bool sent =
      stream_chunks(bytes->data(), bytes->size(), uint64_t{1} << 20, [&](uint64_t offset, std::string data) {
        v1::RigChunk chunk;
        chunk.set_offset(offset);
        chunk.set_data(std::move(data));
        if (offset == 0) {
          chunk.set_size_bytes(bytes->size());
          chunk.set_sha256(sha);
        }
        return call.write(writer, chunk);
      });
  return call.done(sent ? ok_status() : client_gone());
}

grpc::Status PosewarpService::UploadRig(grpc::ServerContext* context, grpc::ServerReader<v1::UploadRigRequest>* reader,
                                        v1::Rig* response) {
  Call call(frame_, context, "UploadRig");
  if (call.refused()) return call.refusal();
  v1::UploadRigRequest part;
  if (!call.read(reader, &part)) return call.done(client_gone());
  if (!part.has_header())
    return call.done(invalid_argument_error("a rig upload starts with its header (size_bytes, sha256)"));
  const v1::UploadRigHeader header = part.header();
  if (Status s = check_rig_upload_header(header, request_limits()); !s.ok()) return call.done(s);
  StagedUpload upload;
  if (Status s = intake_.stage(call, reader, header.size_bytes(), header.sha256(), "upload.rig", &upload); !s.ok()) {
    return call.done(s);
  }
  // The file's bytes and the rig read from them are in memory at once.
  Result<MemoryBudget::Reservation> memory =
      call.reserve(memory_, static_cast<int64_t>(header.size_bytes()) * 3, "this rig upload");
  if (!memory.ok()) return call.done(memory.status());
  Result<std::string> bytes =
      api::read_text_input(upload.path, "rig upload", static_cast<int64_t>(header.size_bytes()));
  if (!bytes.ok()) return call.done(bytes.status());
  Result<api::Rig> rig = api::rig_from_bytes(*bytes, "uploaded rig");
  if (!rig.ok()) return call.done(rig.status());
  call.set_rig(rig->id());
  Result<RigRecord> stored = store_uploaded_rig(*rig, *bytes, header.name());
  if (!stored.ok()) return call.done(stored.status());
  put_rig(*stored, *rig, response);
  return call.done(ok_status());
}

Result<RigRecord> PosewarpService::store_uploaded_rig(const api::Rig& rig, const std::string& bytes,
                                                      const std::string& name) {
  RigRecord record;
  record.id = rig.id();
  record.name = name;
  for (const auto& [stage, seconds] : rig.provenance.stage_seconds) record.build_seconds += seconds;
  if (!store_->rig(record.id).ok()) POSEWARP_RETURN_IF_ERROR(store_->put_rig(record, bytes));
  return store_->rig(record.id);
}

}  // namespace posewarp::server
