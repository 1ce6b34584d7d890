// The files clients read and write, named through the engine facade: a client includes posewarp/api only.
#pragma once

#include <string>

#include "posewarp/api/support.h"
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

// Files in general (atomic writes, bounded reads, content ids): posewarp/api/support.h.

// Volumes (NIfTI, NRRD, MetaImage, DICOM series) and displacement fields.
using io::encode_volume;
using io::format_name;
using io::read_header;
using io::read_intensity_volume;
using io::read_label_volume;
using io::ReadOptions;
using io::VolumeFormat;
using io::VolumeHeader;
using io::write_displacement_field;
using io::write_volume;
using io::WriteOptions;

// Label maps and presets.
using labels::joint_kind_name;
using labels::label_map_from_json;
using labels::LabelEntry;
using labels::LabelMap;
using labels::LabelRole;
using labels::role_name;
using labels::label_map_to_json;
using labels::preset_by_name;
using labels::preset_names;
using labels::read_label_map;
using labels::write_label_map;

// What a volume is for: labels that look like labels, a CT that is not a label volume (build_rig checks both).
using labels::check_ct_is_not_labels;
using labels::check_labels_look_like_labels;
using labels::kMaxDistinctLabels;

// Poses, animations and BVH motion.
using pose::Animation;
using pose::BvhMap;
using pose::read_animation;
using pose::read_bvh;
using pose::read_bvh_map;
using pose::Pose;
using pose::pose_from_json;
using pose::pose_to_json;
using pose::read_pose;

struct Rig;  // posewarp/api/rig.h

// BVH motion retargeted onto a rig's skeleton (its joints named by the BVH map).
Result<pose::Animation> read_bvh(const std::string& path, const pose::BvhMap& map, const Rig& rig, int first,
                                 int last);

// Rig specs.
using rig::read_rig_spec;
using rig::rig_spec_from_json;
using rig::RigSpec;

// Surface meshes (STL, OBJ, PLY, VTP).
using surface::read_surface;
using surface::SurfaceMesh;
using surface::surface_to_vtp_bytes;
using surface::write_surface;

// A study's label map: the JSON file at `path`, else the preset named `preset` (default "totalsegmentator").
// Giving both is INVALID_ARGUMENT.
Result<labels::LabelMap> load_label_map(const std::string& path, const std::string& preset);

}  // namespace posewarp::api
