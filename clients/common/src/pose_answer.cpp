// A Pose stream read whole and checked.
#include "posewarp_client/pose_answer.h"

namespace posewarp::client {
namespace {

// One volume or field as its chunks arrive: where the next chunk must start, and its size once known.
struct Incoming {
  std::string* bytes;
  uint64_t expected = 0;
  // False when the chunk does not continue the bytes where they end.
  bool add(const v1::VolumeChunk& chunk) {
    if (chunk.offset() != bytes->size()) return false;
    if (chunk.total_bytes() > 0) expected = chunk.total_bytes();
    if (bytes->empty() && expected > 0) bytes->reserve(expected);
    *bytes += chunk.data();
    return true;
  }
  bool complete() const { return bytes->size() == expected; }
};

}  // namespace

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
    return grpc::Status(grpc::StatusCode::DATA_LOSS, "the server sent a chunk out of order; run the pose again");
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
