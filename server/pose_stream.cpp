// The pose's stream: engine request, memory estimate, header, and the volumes, fields, surfaces and report in chunks.
#include "pose_stream.h"

#include <algorithm>
#include <cstring>
#include <future>
#include <memory>
#include <string>
#include <type_traits>
#include <utility>

#include "call.h"
#include "convert.h"

namespace posewarp::server {
namespace {

using ChunkField = v1::VolumeChunk* (v1::PoseResponse::*)();

// n samples as `type` (or n bytes of a file, T = char), in chunks of about chunk_bytes, each converted straight into
// its message (no extra copy).
template <typename T>
Status write_samples(const PoseWrite& write, const T* data, int64_t n, PixelType type, uint64_t chunk_bytes,
                     ChunkField field) {
  const int64_t sample = pixel_type_bytes(type);
  const int64_t per_chunk = std::max<int64_t>(1, static_cast<int64_t>(chunk_bytes) / sample);
  for (int64_t first = 0; first < n; first += per_chunk) {
    const int64_t count = std::min(per_chunk, n - first);
    v1::PoseResponse message;
    v1::VolumeChunk* part = (message.*field)();
    part->set_offset(static_cast<uint64_t>(first * sample));
    if (first == 0) part->set_total_bytes(static_cast<uint64_t>(n * sample));
    std::string* bytes = part->mutable_data();
    bytes->resize(static_cast<size_t>(count * sample));
    if constexpr (std::is_same_v<T, char>) {
      std::memcpy(bytes->data(), data + first, static_cast<size_t>(count));  // a file's bytes, as they are
    } else if (!convert_samples(data + first, count, type, bytes->data())) {
      return internal_error("a posed value does not fit the study's voxel type " + std::string(pixel_type_name(type)) +
                            "; ask for computed samples");
    }
    if (!write(message)) return client_gone();
  }
  return ok_status();
}

// n labels as runs of equal values, (value as `type`, count as uint32) pairs little-endian, in chunks of whole runs
// of about chunk_bytes; each chunk's offset and the first's total_bytes count the decoded samples' bytes.
Status write_runs(const PoseWrite& write, const Label* data, int64_t n, PixelType type, uint64_t chunk_bytes) {
  const int64_t sample = pixel_type_bytes(type);
  const size_t pair = static_cast<size_t>(sample) + 4;
  const size_t per_chunk = std::max<size_t>(pair, static_cast<size_t>(chunk_bytes) / pair * pair);
  for (int64_t first = 0; first < n;) {
    v1::PoseResponse message;
    v1::VolumeChunk* part = message.mutable_labels();
    part->set_offset(static_cast<uint64_t>(first * sample));
    if (first == 0) part->set_total_bytes(static_cast<uint64_t>(n * sample));
    std::string* bytes = part->mutable_data();
    while (first < n && bytes->size() + pair <= per_chunk) {
      int64_t end = first + 1;
      while (end < n && data[end] == data[first] && end - first < int64_t{0xffffffff}) ++end;
      const size_t at = bytes->size();
      bytes->resize(at + pair);
      if (!convert_samples(data + first, 1, type, bytes->data() + at)) {
        return internal_error("a posed label does not fit the study's voxel type " +
                              std::string(pixel_type_name(type)) + "; ask for computed samples");
      }
      const uint32_t count = static_cast<uint32_t>(end - first);
      for (int b = 0; b < 4; ++b) (*bytes)[at + static_cast<size_t>(sample + b)] = static_cast<char>(count >> (8 * b));
      first = end;
    }
    if (!write(message)) return client_gone();
  }
  return ok_status();
}

// The posed volumes of one call, written to its stream from a thread of their own while the engine goes on. Each
// volume waits for the one before it, and the call writes nothing else until wait(): one writer at a time.
class VolumeSender {
 public:
  VolumeSender(PoseWrite write, VolumeEncoding encoding, uint64_t chunk_bytes)
      : write_(std::move(write)), encoding_(std::move(encoding)), chunk_bytes_(chunk_bytes) {}
  ~VolumeSender() { (void)wait(); }

  template <typename T>
  void send(std::shared_ptr<const Volume<T>> volume, PixelType type, ChunkField field) {
    last_ =
        std::async(std::launch::async,
                   [this, before = std::move(last_), volume = std::move(volume), type, field]() mutable -> Status {
                     if (before.valid()) {
                       if (Status s = before.get(); !s.ok()) return s;
                     }
                     if constexpr (std::is_same_v<T, Label>) {
                       if (encoding_.label_runs)
                         return write_runs(write_, volume->data(), volume->voxel_count(), type, chunk_bytes_);
                     }
                     if (!encoding_.format)
                       return write_samples(write_, volume->data(), volume->voxel_count(), type, chunk_bytes_, field);
                     Result<std::string> bytes = api::encode_volume(*volume, *encoding_.format, encoding_.gzip, type);
                     if (!bytes.ok())
                       return internal_error("encoding a posed volume failed: " + bytes.status().message());
                     return write_samples(write_, bytes->data(), static_cast<int64_t>(bytes->size()), PixelType::kUInt8,
                                          chunk_bytes_, field);
                   });
  }

  // Waits for every volume handed over; OK, or why one was not sent.
  Status wait() {
    if (!last_.valid()) return status_;
    status_ = last_.get();
    return status_;
  }

 private:
  PoseWrite write_;
  VolumeEncoding encoding_;
  uint64_t chunk_bytes_;
  std::future<Status> last_;
  Status status_;
};

// The fields, the surfaces and the report, after the volumes.
Status send_rest(const api::PoseResult& result, bool want_fields, uint64_t chunk, const PoseWrite& write) {
  if (want_fields) {
    POSEWARP_RETURN_IF_ERROR(write_samples(write, result.inverse_field.data(),
                                           static_cast<int64_t>(result.inverse_field.size()), PixelType::kFloat32,
                                           chunk, &v1::PoseResponse::mutable_inverse_field));
    POSEWARP_RETURN_IF_ERROR(write_samples(write, result.forward_field.data(),
                                           static_cast<int64_t>(result.forward_field.size()), PixelType::kFloat32,
                                           chunk, &v1::PoseResponse::mutable_forward_field));
  }
  for (const SurfaceMesh& s : result.surfaces) {
    v1::PoseResponse m;
    put_surface(s, true, m.mutable_surface());
    if (!write(m)) return client_gone();
  }
  v1::PoseResponse last;
  put_report(result.report, last.mutable_report());
  write(last);
  return ok_status();
}

}  // namespace

Result<VolumeEncoding> volume_encoding(const v1::PoseRequest& request, const api::Rig& rig) {
  VolumeEncoding e;
  switch (request.format()) {
    case v1::FILE_FORMAT_UNSPECIFIED:
    case v1::FILE_FORMAT_RAW: break;
    case v1::FILE_FORMAT_NIFTI_GZ: e.format = api::VolumeFormat::kNifti, e.gzip = true; break;
    case v1::FILE_FORMAT_NIFTI: e.format = api::VolumeFormat::kNifti; break;
    case v1::FILE_FORMAT_NRRD: e.format = api::VolumeFormat::kNrrd, e.gzip = true; break;
    default:
      return invalid_argument_error(
          "a pose's volumes come as raw samples, NIfTI (.nii, .nii.gz) or NRRD bytes; "
          "ask for one of those (MHA is not offered)");
  }
  if (request.samples() == v1::SAMPLE_TYPE_STORED) {
    // The study's own types, as the CLI writes them; the wire carries no 64-bit integers (labels fit int32).
    const PixelType labels = rig.labels.source_type();
    e.label_type = wire_pixel_type(labels) != v1::PIXEL_TYPE_UNSPECIFIED ? labels : PixelType::kInt32;
    if (rig.ct) {
      const PixelType ct = rig.ct->source_type();
      e.ct_type = wire_pixel_type(ct) != v1::PIXEL_TYPE_UNSPECIFIED ? ct : PixelType::kFloat32;
    }
  } else if (request.samples() != v1::SAMPLE_TYPE_COMPUTED) {
    return invalid_argument_error("samples is SAMPLE_TYPE_STORED or SAMPLE_TYPE_COMPUTED");
  }
  if (request.label_encoding() == v1::LABEL_ENCODING_RUNS) {
    if (e.format) {
      return invalid_argument_error(
          "label_encoding LABEL_ENCODING_RUNS is for raw samples (FILE_FORMAT_RAW); a file format compresses "
          "its own bytes: leave label_encoding out");
    }
    e.label_runs = true;
  } else if (request.label_encoding() != v1::LABEL_ENCODING_SAMPLES) {
    return invalid_argument_error("label_encoding is LABEL_ENCODING_SAMPLES or LABEL_ENCODING_RUNS");
  }
  return e;
}

api::PoseRequest engine_request(CheckedPose checked, const v1::PoseRequest& request, const api::Rig& rig) {
  api::PoseRequest core;
  core.pose = std::move(checked.pose);
  core.method = method_of(checked.method);
  core.fem.max_iterations = static_cast<int>(std::min<uint32_t>(request.fem().max_iterations(), 1u << 30));
  core.fem.volume_weight = request.fem().volume_weight();  // the engine refuses what is out of range
  core.fem.contact = request.fem().contact();
  if (request.fem().has_refine_iterations()) {  // absent: the engine's default
    core.fem.refine_iterations = static_cast<int>(std::min<uint32_t>(request.fem().refine_iterations(), 1u << 30));
  }
  core.grid = checked.grid == v1::GRID_POLICY_GROW    ? api::GridPolicy::kGrow
              : checked.grid == v1::GRID_POLICY_GIVEN ? api::GridPolicy::kGiven
                                                      : api::GridPolicy::kInput;
  core.given_grid = checked.given_grid;
  core.ct_interpolation = request.nearest_ct() ? api::Interpolation::kNearest : api::Interpolation::kLinear;
  core.want_labels = request.want_labels();
  core.want_ct = request.want_ct() && rig.ct.has_value();
  core.want_surfaces = request.want_surfaces();
  core.want_fields = request.want_fields();
  core.extra_surfaces = std::move(checked.meshes);
  return core;
}

int64_t pose_memory_estimate(const api::PosePlan& plan, const api::Rig& rig, const api::PoseRequest& core,
                             const VolumeEncoding& encoding) {
  const int64_t output_voxels = plan.output_grid.voxel_count();
  int64_t estimate = plan.output_bytes + rig.mesh.vertex_count() * 96 + rig.mesh.tet_count() * 48 + (int64_t{16} << 20);
  if (encoding.format) {
    if (core.want_labels) estimate += output_voxels * pixel_type_bytes(encoding.label_type);
    if (core.want_ct) estimate += output_voxels * pixel_type_bytes(encoding.ct_type);
  }
  return estimate;
}

v1::PoseResponse pose_header(const api::PosePlan& plan, const api::Rig& rig, const api::PoseRequest& core,
                             const VolumeEncoding& encoding, v1::FileFormat format) {
  v1::PoseResponse message;
  v1::PoseHeader* header = message.mutable_header();
  put_grid(plan.output_grid, header->mutable_grid());
  const uint64_t voxels = static_cast<uint64_t>(plan.output_grid.voxel_count());
  const bool raw = !encoding.format.has_value();
  if (core.want_labels && raw)
    header->set_label_bytes(voxels * static_cast<uint64_t>(pixel_type_bytes(encoding.label_type)));
  if (core.want_ct && raw) header->set_ct_bytes(voxels * static_cast<uint64_t>(pixel_type_bytes(encoding.ct_type)));
  header->set_surface_count(core.want_surfaces ? static_cast<int32_t>(rig.surfaces.size() + core.extra_surfaces.size())
                                               : 0);
  header->set_label_pixel_type(std::string(pixel_type_name(rig.labels.source_type())));
  if (rig.ct) header->set_ct_pixel_type(std::string(pixel_type_name(rig.ct->source_type())));
  if (core.want_labels) header->set_label_sample_type(wire_pixel_type(encoding.label_type));
  if (core.want_ct) header->set_ct_sample_type(wire_pixel_type(encoding.ct_type));
  header->set_format(format);
  if (core.want_labels && encoding.label_runs) header->set_label_encoding(v1::LABEL_ENCODING_RUNS);
  if (core.want_fields) {
    header->set_inverse_field_bytes(voxels * 12);
    header->set_forward_field_bytes(static_cast<uint64_t>(rig.labels.voxel_count()) * 12);
    put_grid(rig.labels.geometry(), header->mutable_source_grid());
  }
  return message;
}

Status stream_pose(const api::PoseEngine& engine, api::PoseRequest core, const ProgressHooks& hooks,
                   const VolumeEncoding& encoding, uint64_t chunk_bytes, const PoseWrite& write,
                   const std::function<void()>& engine_done, const std::function<bool()>& stalled) {
  // Each volume is sent from its own thread as soon as the engine has it, while the engine goes on. A client that
  // stops reading is cancelled by the stall watch, which also stops the engine (its cancel hook).
  VolumeSender sender(write, encoding, chunk_bytes);
  core.labels_ready = [&](std::shared_ptr<const LabelVolume> labels) {
    sender.send(std::move(labels), encoding.label_type, &v1::PoseResponse::mutable_labels);
  };
  core.ct_ready = [&](std::shared_ptr<const IntensityVolume> ct) {
    sender.send(std::move(ct), encoding.ct_type, &v1::PoseResponse::mutable_ct);
  };
  Result<api::PoseResult> result = engine.pose(core, hooks);
  engine_done();
  const Status sent = sender.wait();
  if (stalled()) return client_gone();
  POSEWARP_RETURN_IF_ERROR(result.status());
  POSEWARP_RETURN_IF_ERROR(sent);
  return send_rest(*result, core.want_fields, chunk_bytes, write);
}

}  // namespace posewarp::server
