// A pose's answer as a stream: the request for the engine, the memory it will hold, the header from the plan, then
// the volumes (each sent from a thread of its own as soon as the engine has it), fields, surfaces and the report.
#pragma once

#include <cstdint>
#include <functional>
#include <optional>

#include "posewarp/api/files.h"
#include "posewarp/api/pose_engine.h"
#include "posewarp/v1/posewarp.pb.h"
#include "requests.h"

namespace posewarp::server {

// How a pose's volumes travel: raw samples or a file format's bytes, in the sample types the client chose.
struct VolumeEncoding {
  std::optional<api::VolumeFormat> format;  // none: raw samples
  bool gzip = false;
  PixelType label_type = PixelType::kInt32;
  PixelType ct_type = PixelType::kFloat32;
  bool label_runs = false;  // raw labels as runs of equal values (LABEL_ENCODING_RUNS)
};
Result<VolumeEncoding> volume_encoding(const v1::PoseRequest& request, const api::Rig& rig);

// The engine's request from a checked PoseRequest on `rig` (the output limits are the caller's to set).
api::PoseRequest engine_request(CheckedPose checked, const v1::PoseRequest& request, const api::Rig& rig);
// The memory the pose will hold until its answer is sent: the engine's outputs, a file format's encoded copy of each
// volume, and the skinned mesh with its report.
int64_t pose_memory_estimate(const api::PosePlan& plan, const api::Rig& rig, const api::PoseRequest& core,
                             const VolumeEncoding& encoding);
// The stream's first message, from the plan: the client knows what follows before the engine starts.
v1::PoseResponse pose_header(const api::PosePlan& plan, const api::Rig& rig, const api::PoseRequest& core,
                             const VolumeEncoding& encoding, v1::FileFormat format);

// Writes one message of a pose's stream (under the call's stall watch); false when the client went away.
using PoseWrite = std::function<bool(const v1::PoseResponse&)>;

// Runs the pose on `engine` and streams what it makes through `write` in chunks of `chunk_bytes`: the volumes while
// the engine goes on, then fields, surfaces and the report. `engine_done` is called as soon as the engine returns
// (its slot is given back); `stalled()` tells a stream cancelled by the stall watch.
Status stream_pose(const api::PoseEngine& engine, api::PoseRequest core, const ProgressHooks& hooks,
                   const VolumeEncoding& encoding, uint64_t chunk_bytes, const PoseWrite& write,
                   const std::function<void()>& engine_done, const std::function<bool()>& stalled);

}  // namespace posewarp::server
