// An upload's bytes, from its stream to a staging file as they arrive: never held whole in memory, hashed on the way,
// every refusal naming what to change.
#pragma once

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstdint>
#include <cstring>
#include <string>

#include "posewarp/api/files.h"
#include "requests.h"

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

}  // namespace posewarp::server
