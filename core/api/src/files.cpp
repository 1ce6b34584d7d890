// The files clients read and write, through the stages that read and write them.
#include "posewarp/api/files.h"

#include "posewarp/api/rig.h"
#include "posewarp/io/itk_reference.h"
#include "posewarp/io/volume_io.h"
#include "posewarp/labels/label_map.h"
#include "posewarp/labels/presets.h"
#include "posewarp/labels/volume_kind.h"
#include "posewarp/pose/animation.h"
#include "posewarp/pose/bvh.h"
#include "posewarp/pose/bvh_map.h"
#include "posewarp/pose/pose.h"
#include "posewarp/rig/skeleton.h"
#include "posewarp/surface/surface_mesh.h"

namespace posewarp::api {

std::string_view format_name(VolumeFormat format) { return io::format_name(format); }

Result<VolumeHeader> read_header(const std::string& path, const ReadOptions& options) {
  return io::read_header(path, options);
}

Result<LabelVolume> read_label_volume(const std::string& path, const ReadOptions& options) {
  return io::read_label_volume(path, options);
}

Result<IntensityVolume> read_intensity_volume(const std::string& path, const ReadOptions& options) {
  return io::read_intensity_volume(path, options);
}

Status write_volume(const LabelVolume& volume, const std::string& path, const WriteOptions& options) {
  return io::write_volume(volume, path, options);
}

Status write_volume(const IntensityVolume& volume, const std::string& path, const WriteOptions& options) {
  return io::write_volume(volume, path, options);
}

Result<std::string> encode_volume(const LabelVolume& volume, VolumeFormat format, bool gzip,
                                  std::optional<PixelType> type) {
  return io::encode_volume(volume, format, gzip, type);
}

Result<std::string> encode_volume(const IntensityVolume& volume, VolumeFormat format, bool gzip,
                                  std::optional<PixelType> type) {
  return io::encode_volume(volume, format, gzip, type);
}

Status write_displacement_field(const std::vector<float>& field, const ImageGeometry& geometry,
                                const std::string& path) {
  return io::write_displacement_field(field, geometry, path);
}

Result<LabelMap> label_map_from_json(std::string_view json_text, std::string_view source) {
  return labels::label_map_from_json(json_text, source);
}

std::string label_map_to_json(const LabelMap& map) { return labels::label_map_to_json(map); }

Result<LabelMap> read_label_map(const std::string& path) { return labels::read_label_map(path); }

Status write_label_map(const LabelMap& map, const std::string& path) { return labels::write_label_map(map, path); }

std::vector<std::string> preset_names() { return labels::preset_names(); }

Result<LabelMap> preset_by_name(std::string_view name) { return labels::preset_by_name(name); }

Result<LabelMap> load_label_map(const std::string& path, const std::string& preset) {
  if (!path.empty() && !preset.empty()) return invalid_argument_error("give either --label-map or --preset, not both");
  if (!path.empty()) return labels::read_label_map(path);
  return labels::preset_by_name(preset.empty() ? "totalsegmentator" : preset);
}

Status check_labels_look_like_labels(const LabelVolume& labels, const std::string& labels_name,
                                     const std::string& ct_name) {
  return labels::check_labels_look_like_labels(labels, labels_name, ct_name);
}

Result<Pose> pose_from_json(const std::string& text, const std::string& source) {
  return pose::pose_from_json(text, source);
}

Result<Pose> read_pose(const std::string& path) { return pose::read_pose(path); }

std::string pose_to_json(const Pose& pose) { return pose::pose_to_json(pose); }

Result<Animation> read_animation(const std::string& path) { return pose::read_animation(path); }

Result<BvhMap> read_bvh_map(const std::string& path) { return pose::read_bvh_map(path); }

Result<Animation> read_bvh(const std::string& path, const BvhMap& map, const Rig& rig, int first, int last) {
  return pose::read_bvh(path, map, rig.skeleton, first, last);
}

Result<RigSpec> rig_spec_from_json(const std::string& text, const std::string& source) {
  return rig::rig_spec_from_json(text, source);
}

Result<RigSpec> read_rig_spec(const std::string& path) { return rig::read_rig_spec(path); }

Result<SurfaceMesh> read_surface(const std::string& path) { return surface::read_surface(path); }

Status write_surface(const SurfaceMesh& mesh, const std::string& path) { return surface::write_surface(mesh, path); }

Result<std::string> surface_to_vtp_bytes(const SurfaceMesh& mesh) { return surface::surface_to_vtp_bytes(mesh); }

}  // namespace posewarp::api
