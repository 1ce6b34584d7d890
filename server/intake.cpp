// Intake of volumes: a known file answered after its header, raw samples stored as NIfTI, files read before they are
// stored.
#include "intake.h"

#include "convert.h"
#include "status_map.h"

namespace posewarp::server {
namespace {

std::string kind_of(const v1::UploadVolumeHeader& header) {
  return header.kind() == v1::VOLUME_KIND_LABELS ? "labels" : "intensity";
}

}  // namespace

std::optional<v1::Volume> Intake::stored(const v1::UploadVolumeHeader& header) const {
  Result<VolumeRecord> existing = store_.volume(header.sha256());
  if (!existing.ok() || existing->kind != kind_of(header)) return std::nullopt;
  Result<api::VolumeHeader> stored = api::read_header(existing->path, read_options_);
  if (!stored.ok()) return std::nullopt;
  v1::Volume volume;
  volume.set_id(existing->id);
  volume.set_kind(header.kind());
  put_grid(stored->geometry, volume.mutable_grid());
  volume.set_pixel_type(std::string(pixel_type_name(stored->pixel_type)));
  volume.set_size_bytes(existing->size_bytes);
  volume.set_already_stored(true);
  return volume;
}

Result<v1::Volume> Intake::store_raw(Call& call, const v1::UploadVolumeHeader& header, const UploadPlan& plan,
                                     const StagedUpload& staged) {
  const bool labels = header.kind() == v1::VOLUME_KIND_LABELS;
  const std::string kind = kind_of(header);
  const std::string id = api::sha256_hex(header.sha256() + header.raw_grid().SerializeAsString() +
                                         std::to_string(header.raw_pixel_type()) + kind);
  v1::Volume volume;
  volume.set_id(id);
  volume.set_kind(header.kind());
  put_grid(plan.raw_grid, volume.mutable_grid());
  if (Result<VolumeRecord> existing = store_.volume(id); existing.ok()) {
    volume.set_size_bytes(existing->size_bytes);
    return volume;
  }
  // The samples, the volume made of them and its .nii.gz, all in memory at once.
  const int64_t voxels = plan.raw_grid.voxel_count();
  POSEWARP_ASSIGN_OR_RETURN(
      const MemoryBudget::Reservation memory,
      call.reserve(memory_, static_cast<int64_t>(header.size_bytes()) * 2 + voxels * 4, "this upload"));
  POSEWARP_ASSIGN_OR_RETURN(const std::string bytes,
                            api::read_text_input(staged.path, "upload", static_cast<int64_t>(header.size_bytes())));
  std::string encoded;
  if (labels) {
    POSEWARP_ASSIGN_OR_RETURN(const LabelVolume v, labels_from_raw(bytes, plan.raw_type, plan.raw_grid));
    POSEWARP_RETURN_IF_ERROR(api::check_labels_look_like_labels(v, "the uploaded label volume"));
    POSEWARP_ASSIGN_OR_RETURN(encoded, api::encode_volume(v, api::VolumeFormat::kNifti, true));
  } else {
    POSEWARP_ASSIGN_OR_RETURN(const IntensityVolume v, intensity_from_raw(bytes, plan.raw_type, plan.raw_grid));
    POSEWARP_ASSIGN_OR_RETURN(encoded, api::encode_volume(v, api::VolumeFormat::kNifti, true));
  }
  POSEWARP_ASSIGN_OR_RETURN(const VolumeRecord stored, store_.put_volume(id, plan.extension, kind, encoded));
  volume.set_pixel_type(std::string(pixel_type_name(plan.raw_type)));
  volume.set_size_bytes(stored.size_bytes);
  return volume;
}

Result<api::VolumeHeader> Intake::read_staged(Call& call, bool labels, const std::string& path) {
  POSEWARP_ASSIGN_OR_RETURN(const api::VolumeHeader h, api::read_header(path, read_options_));
  const int64_t voxels = h.geometry.voxel_count();
  POSEWARP_ASSIGN_OR_RETURN(
      const MemoryBudget::Reservation memory,
      call.reserve(memory_, voxels * (pixel_type_bytes(h.pixel_type) + 4), "reading this upload"));
  if (labels) {
    POSEWARP_ASSIGN_OR_RETURN(const LabelVolume volume, api::read_label_volume(path, read_options_));
    POSEWARP_RETURN_IF_ERROR(api::check_labels_look_like_labels(volume, "the uploaded label volume"));
  } else {
    POSEWARP_RETURN_IF_ERROR(api::read_intensity_volume(path, read_options_).status());
  }
  return h;
}

Result<v1::Volume> Intake::store_file(Call& call, const v1::UploadVolumeHeader& header, const UploadPlan& plan,
                                      const StagedUpload& staged) {
  Result<api::VolumeHeader> read = read_staged(call, header.kind() == v1::VOLUME_KIND_LABELS, staged.path);
  if (!read.ok()) {
    // Named as the client knows it; a path a reader quotes (the store's) never reaches the client.
    const std::string message = without_path(read.status().message(), staged.path, "the uploaded volume");
    return Status(read.status().code(), without_path(message, staged.directory->path(), "the upload"));
  }
  POSEWARP_ASSIGN_OR_RETURN(const VolumeRecord stored,
                            store_.put_volume_file(header.sha256(), plan.extension, kind_of(header), staged.path));
  v1::Volume volume;
  volume.set_id(stored.id);
  volume.set_kind(header.kind());
  put_grid(read->geometry, volume.mutable_grid());
  volume.set_pixel_type(std::string(pixel_type_name(read->pixel_type)));
  volume.set_size_bytes(stored.size_bytes);
  return volume;
}

}  // namespace posewarp::server
