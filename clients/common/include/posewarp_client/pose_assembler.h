// A Pose answer put together from its stream's parts, checked as they come: no gRPC here, so that read_pose
// (pose_answer.h) and the fuzzer (tests/fuzz/fuzz_pose_answer.cpp) run the same code.
#pragma once

#include <cstddef>
#include <cstdint>
#include <string>
#include <vector>

#include "posewarp/v1/posewarp.pb.h"

namespace posewarp::client {

struct PoseAnswer {
  v1::PoseHeader header;
  std::string labels, ct;  // raw samples (the header's sample types) or the bytes of the requested file format
  std::string inverse_field, forward_field;  // float32 x y z per voxel
  std::vector<v1::Surface> surfaces;
  v1::QualityReport report;
};

// Bytes of one sample of a wire pixel type (PIXEL_TYPE_INT16: 2); 0 for PIXEL_TYPE_UNSPECIFIED or an unknown one.
size_t sample_bytes(v1::PixelType type);

// The most bytes one volume or field of an answer may announce (64 GiB, a 2^31-voxel grid of 3 x 8-byte samples and
// more): a header or chunk that claims more is malformed, whatever the machine could hold.
constexpr uint64_t kMaxAnswerVolumeBytes = uint64_t{1} << 36;

class PoseAssembler {
 public:
  // Fills `answer` (cleared first). A volume or field that announces more than `max_volume_bytes` is malformed.
  explicit PoseAssembler(PoseAnswer* answer, uint64_t max_volume_bytes = kMaxAnswerVolumeBytes);

  // Adds the stream's next part. False when it does not continue its volume where the last chunk ended, its label
  // runs are malformed or go past the volume's size, or a size is past the limit: the call must be cancelled.
  // Throws std::bad_alloc when an announced volume does not fit in memory.
  bool add(const v1::PoseResponse& part);
  // Volume bytes (labels and CT) received so far, and expected (0 until the server has said).
  uint64_t received() const;
  uint64_t expected() const;
  // Every volume and field holds the bytes its header or first chunk announced (after the stream's end).
  bool complete() const;

 private:
  // One volume or field as its chunks arrive: where the next chunk must start, and its size once known. Labels sent
  // as runs (LABEL_ENCODING_RUNS) are decoded as they come: `run_sample` is then their sample's size.
  struct Incoming {
    std::string* bytes;
    uint64_t expected = 0;
    size_t run_sample = 0;
    bool add(const v1::VolumeChunk& chunk, uint64_t limit);
    bool complete() const { return bytes->size() == expected; }
  };

  PoseAnswer* answer_;
  uint64_t limit_;
  Incoming labels_, ct_, inverse_, forward_;
};

}  // namespace posewarp::client
