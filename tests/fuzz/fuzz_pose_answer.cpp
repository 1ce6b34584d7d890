// Fuzzes the C++ clients' reading of a Pose answer (clients/common, PoseAssembler, which read_pose feeds): arbitrary
// bytes as the stream's parts, each a PoseResponse message behind a 2-byte little-endian length, put together as the
// CLI's remote mode, batch and the viewer put them together. Volumes are bounded at 16 MiB here (the clients' own
// bound, kMaxAnswerVolumeBytes, is for real machines).
#include <algorithm>
#include <cstddef>
#include <cstdint>

#include "posewarp_client/pose_assembler.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace posewarp;
  client::PoseAnswer answer;
  client::PoseAssembler assembler(&answer, uint64_t{16} << 20);
  size_t at = 0;
  while (at + 2 <= size) {
    const size_t length = std::min<size_t>(data[at] | (size_t{data[at + 1]} << 8), size - at - 2);
    at += 2;
    v1::PoseResponse part;
    if (part.ParseFromArray(data + at, static_cast<int>(length)) && !assembler.add(part)) break;
    at += length;
  }
  (void)assembler.received();
  (void)assembler.complete();
  return 0;
}
