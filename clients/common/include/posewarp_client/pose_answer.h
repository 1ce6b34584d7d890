// A Pose answer as it comes over the wire: the header, each volume's chunks put together in order, the surfaces and
// the report, checked whole.
#pragma once

#include <grpcpp/grpcpp.h>

#include <cstdint>
#include <functional>

#include "posewarp/v1/posewarp.grpc.pb.h"
#include "posewarp_client/connection.h"
#include "posewarp_client/pose_assembler.h"

namespace posewarp::client {

// Called after each part with the volume bytes received so far and those expected (0 until the server has said).
using PoseProgress = std::function<void(uint64_t received, uint64_t expected)>;

// Reads one Pose stream to its end into `answer` (cleared first). A chunk that does not continue its volume where the
// last one ended cancels the call: DATA_LOSS. So does a volume or field that ends short of the size the header (raw
// samples) or its first chunk (a file format) gave.
grpc::Status read_pose(grpc::ClientContext& context, grpc::ClientReaderInterface<v1::PoseResponse>& reader,
                       PoseAnswer* answer, const PoseProgress& progress = {});

// A whole Pose call on `connection`, with its retries: each try starts the answer anew.
CallError pose(const Connection& connection, const v1::PoseRequest& request, PoseAnswer* answer,
               const PoseProgress& progress = {});

}  // namespace posewarp::client
