// A Pose stream read whole and checked.
#include "posewarp_client/pose_answer.h"

#include <cstring>

namespace posewarp::client {
namespace {

// One volume or field as its chunks arrive: where the next chunk must start, and its size once known. Labels sent as
// runs (LABEL_ENCODING_RUNS) are decoded as they come: `run_sample` is then their sample's size.
struct Incoming {
  std::string* bytes;
  uint64_t expected = 0;
  size_t run_sample = 0;
  // False when the chunk does not continue the bytes where they end, or its runs are malformed or go past the end.
  bool add(const v1::VolumeChunk& chunk) {
    if (chunk.offset() != bytes->size()) return false;
    if (chunk.total_bytes() > 0) expected = chunk.total_bytes();
    if (bytes->empty() && expected > 0) bytes->reserve(expected);
    if (run_sample == 0) {
      *bytes += chunk.data();
      return true;
    }
    const std::string& runs = chunk.data();
    const size_t pair = run_sample + 4;
    if (runs.size() % pair != 0) return false;
    for (size_t at = 0; at < runs.size(); at += pair) {
      uint32_t count = 0;
      for (size_t b = 0; b < 4; ++b)
        count |= static_cast<uint32_t>(static_cast<unsigned char>(runs[at + run_sample + b])) << (8 * b);
      if (count == 0 || bytes->size() + uint64_t{count} * run_sample > expected) return false;
      const size_t end = bytes->size();
      bytes->resize(end + size_t{count} * run_sample);
      char* out = bytes->data() + end;
      if (run_sample == 1) {
        std::memset(out, runs[at], count);
      } else {
        for (uint32_t c = 0; c < count; ++c) std::memcpy(out + size_t{c} * run_sample, runs.data() + at, run_sample);
      }
    }
    return true;
  }
  bool complete() const { return bytes->size() == expected; }
};

}  // namespace

size_t sample_bytes(v1::PixelType type) {
  switch (type) {
    case v1::PIXEL_TYPE_UINT8:
    case v1::PIXEL_TYPE_INT8: return 1;
    case v1::PIXEL_TYPE_UINT16:
    case v1::PIXEL_TYPE_INT16: return 2;
    case v1::PIXEL_TYPE_UINT32:
    case v1::PIXEL_TYPE_INT32:
    case v1::PIXEL_TYPE_FLOAT32: return 4;
    case v1::PIXEL_TYPE_FLOAT64: return 8;
    default: return 0;
  }
}

grpc::Status read_pose(grpc::ClientContext& context, grpc::ClientReaderInterface<v1::PoseResponse>& reader,
                       PoseAnswer* answer, const PoseProgress& progress) {
  *answer = PoseAnswer{};
  Incoming labels{&answer->labels}, ct{&answer->ct}, inverse{&answer->inverse_field}, forward{&answer->forward_field};
  bool in_order = true;
  v1::PoseResponse part;
  while (in_order && reader.Read(&part)) {
    switch (part.part_case()) {
      case v1::PoseResponse::kHeader:
        answer->header = part.header();
        labels.expected = answer->header.label_bytes();
        if (answer->header.label_encoding() == v1::LABEL_ENCODING_RUNS) {
          labels.run_sample = sample_bytes(answer->header.label_sample_type());
          in_order = labels.run_sample > 0 || labels.expected == 0;  // runs of samples of a known type
        }
        ct.expected = answer->header.ct_bytes();
        inverse.expected = answer->header.inverse_field_bytes();
        forward.expected = answer->header.forward_field_bytes();
        break;
      case v1::PoseResponse::kLabels: in_order = labels.add(part.labels()); break;
      case v1::PoseResponse::kCt: in_order = ct.add(part.ct()); break;
      case v1::PoseResponse::kInverseField: in_order = inverse.add(part.inverse_field()); break;
      case v1::PoseResponse::kForwardField: in_order = forward.add(part.forward_field()); break;
      case v1::PoseResponse::kSurface: answer->surfaces.push_back(part.surface()); break;
      case v1::PoseResponse::kReport: answer->report = part.report(); break;
      default: break;
    }
    if (progress) progress(answer->labels.size() + answer->ct.size(), labels.expected + ct.expected);
  }
  if (!in_order) {
    context.TryCancel();
    (void)reader.Finish();
    return grpc::Status(grpc::StatusCode::DATA_LOSS,
                        "the server sent a chunk out of order or malformed; run the pose again");
  }
  grpc::Status status = reader.Finish();
  if (status.ok() && !(labels.complete() && ct.complete() && inverse.complete() && forward.complete())) {
    return grpc::Status(grpc::StatusCode::DATA_LOSS, "the server's answer ended early; run the pose again");
  }
  return status;
}

CallError pose(const Connection& connection, const v1::PoseRequest& request, PoseAnswer* answer,
               const PoseProgress& progress) {
  return connection.error_of(connection.with_retries([&] {
    const auto context = connection.context(request.rig_id());
    auto reader = connection.stub().Pose(context.get(), request);
    return read_pose(*context, *reader, answer, progress);
  }));
}

}  // namespace posewarp::client
