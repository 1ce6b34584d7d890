// The files clients read and write: volumes, displacement fields, label maps, poses, motion, rig specs and surfaces.
// Each function is the stage's own (io/, labels/, pose/, rig/, surface/), named here so a client includes
// posewarp/api only; the stage header says every case in full.
#pragma once

#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "posewarp/api/support.h"
#include "posewarp/common/animation.h"
#include "posewarp/common/label_map.h"
#include "posewarp/common/pose.h"
#include "posewarp/common/result.h"
#include "posewarp/common/skeleton.h"
#include "posewarp/common/surface_mesh.h"
#include "posewarp/common/volume.h"
#include "posewarp/common/volume_file.h"

namespace posewarp::api {

// Files in general (atomic writes, bounded reads, content ids): posewarp/api/support.h.

// The vocabulary clients name through the api.
using posewarp::Animation;
using posewarp::BvhMap;
using posewarp::LabelCensus;
using posewarp::LabelEntry;
using posewarp::LabelMap;
using posewarp::LabelRole;
using posewarp::Pose;
using posewarp::ReadOptions;
using posewarp::RigSpec;
using posewarp::role_name;
using posewarp::SurfaceMesh;
using posewarp::VolumeFormat;
using posewarp::VolumeHeader;
using posewarp::WriteOptions;

// Volumes: NIfTI (.nii, .nii.gz), NRRD (.nrrd, .nhdr), MetaImage (.mha, .mhd) and DICOM series (a directory).
// Limits (ReadOptions) are checked against the header before any voxel is allocated; a label file in a
// floating-point type is accepted only when every value is an integer. Writes go to a temporary file renamed into
// place. encode_volume makes a file's bytes in memory (NIfTI or inline NRRD, gzip at level 1).
std::string_view format_name(VolumeFormat format);
Result<VolumeHeader> read_header(const std::string& path, const ReadOptions& options = {});
Result<LabelVolume> read_label_volume(const std::string& path, const ReadOptions& options = {});
Result<IntensityVolume> read_intensity_volume(const std::string& path, const ReadOptions& options = {});
Status write_volume(const LabelVolume& volume, const std::string& path, const WriteOptions& options = {});
Status write_volume(const IntensityVolume& volume, const std::string& path, const WriteOptions& options = {});
Result<std::string> encode_volume(const LabelVolume& volume, VolumeFormat format, bool gzip,
                                  std::optional<PixelType> type = std::nullopt);
Result<std::string> encode_volume(const IntensityVolume& volume, VolumeFormat format, bool gzip,
                                  std::optional<PixelType> type = std::nullopt);
// A displacement field (3 floats per voxel, mm) as an ITK vector image (.nii.gz, .nrrd, .mha), what ITK's
// DisplacementFieldTransform, ANTs and elastix read.
Status write_displacement_field(const std::vector<float>& field, const ImageGeometry& geometry,
                                const std::string& path);

// Label maps: the JSON form (`source` names the text's origin in messages), files, and the built-in presets.
Result<LabelMap> label_map_from_json(std::string_view json_text, std::string_view source);
std::string label_map_to_json(const LabelMap& map);
Result<LabelMap> read_label_map(const std::string& path);
Status write_label_map(const LabelMap& map, const std::string& path);
std::vector<std::string> preset_names();
Result<LabelMap> preset_by_name(std::string_view name);
// A study's label map: the JSON file at `path`, else the preset named `preset` (default "totalsegmentator").
// Giving both is INVALID_ARGUMENT.
Result<LabelMap> load_label_map(const std::string& path, const std::string& preset);

// INVALID_ARGUMENT when `labels` looks like an intensity volume given as the labels (more distinct values than any
// segmentation holds), naming `labels_name` and, when given, `ct_name` (the two may be swapped). build_rig checks it
// and that the CT is not labels.
Status check_labels_look_like_labels(const LabelVolume& labels, const std::string& labels_name,
                                     const std::string& ct_name = {});

// Poses (JSON, version 1: the format is described in posewarp/pose/pose.h and the README), animations and BVH motion.
Result<Pose> pose_from_json(const std::string& text, const std::string& source);
Result<Pose> read_pose(const std::string& path);
std::string pose_to_json(const Pose& pose);
Result<Animation> read_animation(const std::string& path);
Result<BvhMap> read_bvh_map(const std::string& path);

struct Rig;  // posewarp/api/rig.h

// BVH motion retargeted onto a rig's skeleton (its joints named by the BVH map).
Result<Animation> read_bvh(const std::string& path, const BvhMap& map, const Rig& rig, int first, int last);

// Rig specs: a user's corrections to the automatic skeleton (JSON).
Result<RigSpec> rig_spec_from_json(const std::string& text, const std::string& source);
Result<RigSpec> read_rig_spec(const std::string& path);

// Surface meshes by extension: .stl, .obj, .ply, .vtp (written under a temporary name and renamed into place);
// surface_to_vtp_bytes makes the .vtp file's bytes in memory.
Result<SurfaceMesh> read_surface(const std::string& path);
Status write_surface(const SurfaceMesh& mesh, const std::string& path);
Result<std::string> surface_to_vtp_bytes(const SurfaceMesh& mesh);

}  // namespace posewarp::api
