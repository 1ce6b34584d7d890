// A Pose stream read whole and checked (its parts put together by PoseAssembler).
#include "posewarp_client/pose_answer.h"

#include <new>

namespace posewarp::client {

grpc::Status read_pose(grpc::ClientContext& context, grpc::ClientReaderInterface<v1::PoseResponse>& reader,
                       PoseAnswer* answer, const PoseProgress& progress) {
  PoseAssembler assembler(answer);
  bool in_order = true;
  v1::PoseResponse part;
  try {
    while (in_order && reader.Read(&part)) {
      in_order = assembler.add(part);
      if (progress) progress(assembler.received(), assembler.expected());
    }
  } catch (const std::bad_alloc&) {
    context.TryCancel();
    (void)reader.Finish();
    *answer = PoseAnswer{};
    return grpc::Status(grpc::StatusCode::RESOURCE_EXHAUSTED,
                        "the pose's answer does not fit in this machine's memory; ask for fewer outputs or a smaller "
                        "grid");
  }
  if (!in_order) {
    context.TryCancel();
    (void)reader.Finish();
    return grpc::Status(grpc::StatusCode::DATA_LOSS,
                        "the server sent a chunk out of order or malformed; run the pose again");
  }
  grpc::Status status = reader.Finish();
  if (status.ok() && !assembler.complete()) {
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
