// An upload's bytes, from its stream to a staging file as they arrive: never held whole in memory, hashed on the way,
// every refusal naming what to change.
#pragma once

#include <fcntl.h>
#include <unistd.h>

#include <cerrno>
#include <cstdint>
#include <cstring>
#include <string>

#include "posewarp/common/result.h"
#include "posewarp/common/sha256.h"
#include "requests.h"

namespace posewarp::server {

struct StagedUpload {
  uint64_t bytes = 0;
  std::string sha256;  // of what arrived
};

// Reads messages with `read(&message)` until the client closes its side, writing each chunk (`chunk_of(message)`,
// nullptr for a message that is not a chunk) to a new file at `path`. INVALID_ARGUMENT for a message that is not a
// chunk, more bytes than `size`, or a chunk under kMinUploadChunkBytes that does not end the file; DATA_LOSS when
// the stream ends short; RESOURCE_EXHAUSTED when the disk is full.
template <typename Message, typename Read, typename ChunkOf>
Result<StagedUpload> receive_upload(Read&& read, ChunkOf&& chunk_of, uint64_t size, const std::string& path) {
  const int fd = ::open(path.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_CLOEXEC, 0600);
  if (fd < 0) return internal_error("cannot stage an upload: " + std::string(std::strerror(errno)));
  struct Close {
    int fd;
    ~Close() { ::close(fd); }
  } closing{fd};
  StagedUpload staged;
  Sha256 hash;
  Message message;
  while (read(&message)) {
    const std::string* chunk = chunk_of(message);
    if (chunk == nullptr) return invalid_argument_error("an upload has one header, then only chunks");
    if (staged.bytes + chunk->size() > size) {
      return invalid_argument_error("the upload sent more bytes than its header's size_bytes (" + std::to_string(size) +
                                    ")");
    }
    if (chunk->size() < kMinUploadChunkBytes && staged.bytes + chunk->size() != size) {
      return invalid_argument_error("an upload chunk of " + std::to_string(chunk->size()) +
                                    " bytes does not end the file; send chunks of at least " +
                                    std::to_string(kMinUploadChunkBytes) + " bytes (1 MiB is a good size)");
    }
    hash.update(*chunk);
    for (size_t written = 0; written < chunk->size();) {
      const ssize_t n = ::write(fd, chunk->data() + written, chunk->size() - written);
      if (n < 0 && errno == EINTR) continue;
      if (n <= 0) {
        if (errno == ENOSPC || errno == EDQUOT) {
          return resource_exhausted_error("the server's disk is full; try again later or ask the operator");
        }
        return internal_error("cannot stage an upload: " + std::string(std::strerror(errno)));
      }
      written += static_cast<size_t>(n);
    }
    staged.bytes += chunk->size();
  }
  if (staged.bytes != size) {
    return data_loss_error("the upload ended after " + std::to_string(staged.bytes) + " of " + std::to_string(size) +
                           " bytes (its header's size_bytes); send it again");
  }
  staged.sha256 = hash.hex_digest();
  return staged;
}

}  // namespace posewarp::server
