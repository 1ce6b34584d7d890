// The checks every request passes where it enters, before any work: ids, enums, sizes and ranges, each refusal naming
// the API field (or the server option) that applies, never a command-line flag of the CLI. Only proto and the core's
// data types here (posewarp/api/files.h, not the engine), so the request fuzzer runs exactly these checks on arbitrary
// messages.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <vector>

#include "posewarp/api/files.h"
#include "posewarp/v1/posewarp.pb.h"

namespace posewarp::server {

// The server's limits that requests are checked against (its options).
struct RequestLimits {
  int64_t max_upload_bytes = int64_t{4} << 30;   // --max-upload-mb
  int64_t max_volume_voxels = int64_t{1} << 28;  // --max-volume-voxels
  int64_t max_output_voxels = int64_t{1} << 28;  // --max-output-voxels
};

// A chunk of an upload smaller than this must be its last (a client sending one byte per message holds an upload
// for minutes); pose chunks (chunk_bytes) lie between the two pose bounds, 0 meaning the default.
inline constexpr uint64_t kMinUploadChunkBytes = 4096;
inline constexpr uint64_t kMinPoseChunkBytes = uint64_t{64} << 10;
inline constexpr uint64_t kMaxPoseChunkBytes = uint64_t{4} << 20;
inline constexpr uint64_t kDefaultPoseChunkBytes = uint64_t{1} << 20;
// Grids from clients (given_grid, raw_grid): per axis 1..65536 voxels of 0.001..1000 mm, origin within 1 km.
inline constexpr int64_t kMaxGridAxis = 65536;
inline constexpr double kMinSpacingMm = 1e-3;
inline constexpr double kMaxSpacingMm = 1e3;
inline constexpr double kMaxOriginMm = 1e6;
// JSON carried in a request (pose, label map, rig spec): far more than any real one.
inline constexpr size_t kMaxRequestJsonBytes = size_t{1} << 20;
inline constexpr int kMaxPoseJoints = 1000;  // joints of a typed pose

// What an upload's header says, checked.
struct UploadPlan {
  bool raw = false;
  std::string extension;  // the stored file's: ".nii.gz" for raw samples
  ImageGeometry raw_grid;
  PixelType raw_type = PixelType::kUInt8;
};
Result<UploadPlan> check_upload_header(const v1::UploadVolumeHeader& header, const RequestLimits& limits);
Status check_rig_upload_header(const v1::UploadRigHeader& header, const RequestLimits& limits);

// A client's grid (`field` names it in messages: "given_grid", "raw_grid"): 3 sizes, spacings and origins, 9
// direction entries, each in range, a valid geometry.
Result<ImageGeometry> grid_from(const v1::Grid& grid, const std::string& field);
// A client's mesh: whole vertices and triangles, finite coordinates within 1 km, indices in range.
Result<api::SurfaceMesh> surface_from(const v1::Surface& message);

// A PoseRequest's fields, checked.
struct CheckedPose {
  api::Pose pose;
  v1::Method method = v1::METHOD_COR;
  v1::GridPolicy grid = v1::GRID_POLICY_INPUT;
  std::optional<ImageGeometry> given_grid;
  uint64_t chunk_bytes = kDefaultPoseChunkBytes;
  std::vector<api::SurfaceMesh> meshes;
};
Result<CheckedPose> check_pose_request(const v1::PoseRequest& request);
// A preview update's pose and method (its rig id is checked where the engine is looked up).
Result<api::Pose> check_preview_request(const v1::PreviewRequest& request);
Status check_build_request(const v1::BuildRigRequest& request);
// A match's rig id, its target volume's id or a standard posture (one of the two), and the target's names.
Status check_match_request(const v1::MatchPostureRequest& request);

// The extension a stored upload of `format` gets, or nullptr for a format that is not a file.
const char* extension_of(v1::FileFormat format);
// RAW samples -> the pixel type, or nullopt.
std::optional<PixelType> pixel_type_of(v1::PixelType type);

// v1::Method: UNSPECIFIED (CoR) or one of the three; anything else INVALID_ARGUMENT naming `field`.
Result<v1::Method> method_from(v1::Method method, const std::string& field);

}  // namespace posewarp::server
