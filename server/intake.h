// Intake: an upload's bytes, from its stream to a staging file as they arrive (never held whole in memory, hashed on
// the way, every refusal naming what to change), then a volume read as posing will read it before it gets its name
// in the store.
#pragma once

#include <fcntl.h>
#include <grpcpp/support/sync_stream.h>
#include <unistd.h>

#include <cerrno>
#include <cstdint>
#include <cstring>
#include <memory>
#include <optional>
#include <string>

#include "admission.h"
#include "call.h"
#include "posewarp/api/files.h"
#include "posewarp/v1/posewarp.grpc.pb.h"
#include "requests.h"
#include "store.h"

namespace posewarp::server {

// Reads messages with `read(&message)` until the client closes its side, writing each chunk of an upload request
// (UploadVolumeRequest, UploadRigRequest: a oneof of header and chunk) to a new file at `path`. INVALID_ARGUMENT for a
// message that is not a chunk, more bytes than `size`, or a chunk under kMinUploadChunkBytes that does not end the
// file; DATA_LOSS when the stream ends short or its bytes do not hash to `sha256`; RESOURCE_EXHAUSTED when the disk
// is full.
template <typename Request, typename Read>
Status receive_upload(Read&& read, uint64_t size, const std::string& sha256, const std::string& path) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0600);
  if (fd < 0) return internal_error("cannot stage an upload: " + std::string(std::strerror(errno)));
  struct Close {
    int fd;
    ~Close() { ::close(fd); }
  } closing{fd};
  uint64_t received = 0;
  api::Sha256 hash;
  Request message;
  while (read(&message)) {
    if (message.part_case() != Request::kChunk)
      return invalid_argument_error("an upload has one header, then only chunks");
    const std::string& chunk = message.chunk();
    if (received + chunk.size() > size) {
      return invalid_argument_error("the upload sent more bytes than its header's size_bytes (" + std::to_string(size) +
                                    ")");
    }
    if (chunk.size() < kMinUploadChunkBytes && received + chunk.size() != size) {
      return invalid_argument_error("an upload chunk of " + std::to_string(chunk.size()) +
                                    " bytes does not end the file; send chunks of at least " +
                                    std::to_string(kMinUploadChunkBytes) + " bytes (1 MiB is a good size)");
    }
    hash.update(chunk);
    for (size_t written = 0; written < chunk.size();) {
      const ssize_t n = ::write(fd, chunk.data() + written, chunk.size() - written);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) {
        if (errno == ENOSPC || errno == EDQUOT) {
          return resource_exhausted_error("the server's disk is full; try again later or ask the operator");
        }
        return internal_error("cannot stage an upload: " + std::string(std::strerror(errno)));
      }
      written += static_cast<size_t>(n);
    }
    received += chunk.size();
  }
  if (received != size) {
    return data_loss_error("the upload ended after " + std::to_string(received) + " of " + std::to_string(size) +
                           " bytes (its header's size_bytes); send it again");
  }
  if (hash.hex_digest() != sha256) {
    return data_loss_error("the upload's bytes do not match its header's sha256; send it again");
  }
  return ok_status();
}

// An upload admitted for its client (--uploads-per-client, --upload-mb-per-client) and received: its chunks in a file
// of a staging directory of its own, checked against the header's size and SHA-256.
struct StagedUpload {
  std::optional<ClientLimits::Entry> admitted;
  std::unique_ptr<StagingDirectory> directory;
  std::string path;
};

class Intake {
 public:
  // Uploads are read with `read_options` (the server's voxel limit, voxels inline only).
  Intake(RigStore& store, ClientLimits& client_limits, MemoryBudget& memory, api::ReadOptions read_options)
      : store_(store), client_limits_(client_limits), memory_(memory), read_options_(std::move(read_options)) {}

  // The rest of the call's upload stream, admitted for its client, into `staged`.
  template <typename Request>
  Status stage(Call& call, grpc::ServerReader<Request>* reader, uint64_t size, const std::string& sha256,
               const std::string& file_name, StagedUpload* staged);
  // A volume file the store holds already (its id is its SHA-256) under the same kind, described; answered right
  // after the header, so a client re-sending a study does not move its bytes again.
  std::optional<v1::Volume> stored(const v1::UploadVolumeHeader& header) const;
  // Raw samples become a NIfTI file in the store; the id covers the samples and their geometry.
  Result<v1::Volume> store_raw(Call& call, const v1::UploadVolumeHeader& header, const UploadPlan& plan,
                               const StagedUpload& staged);
  // A file is read as posing will read it before it gets its name in the store: its header first, then, with
  // memory reserved for them, its voxels (labels checked to look like labels).
  Result<v1::Volume> store_file(Call& call, const v1::UploadVolumeHeader& header, const UploadPlan& plan,
                                const StagedUpload& staged);

 private:
  Result<api::VolumeHeader> read_staged(Call& call, bool labels, const std::string& path);

  RigStore& store_;
  ClientLimits& client_limits_;
  MemoryBudget& memory_;
  api::ReadOptions read_options_;
};

template <typename Request>
Status Intake::stage(Call& call, grpc::ServerReader<Request>* reader, uint64_t size, const std::string& sha256,
                     const std::string& file_name, StagedUpload* staged) {
  POSEWARP_ASSIGN_OR_RETURN(ClientLimits::Entry admitted,
                            client_limits_.enter_upload(call.client(), static_cast<int64_t>(size)));
  staged->admitted.emplace(std::move(admitted));
  // The bytes go to a file in a directory of this upload's own as they arrive (never held whole in memory): a
  // header there that names a data file beside itself finds nothing it did not send.
  POSEWARP_ASSIGN_OR_RETURN(const std::string directory, store_.make_staging_directory());
  staged->directory = std::make_unique<StagingDirectory>(directory);
  staged->path = directory + "/" + file_name;
  const Status received =
      receive_upload<Request>([&](Request* message) { return call.read(reader, message); }, size, sha256, staged->path);
  if (received.ok()) return received;
  return call.stream().stalled() || call.cancelled() ? client_gone() : received;
}

}  // namespace posewarp::server
