// Synthetic bodies with exactly known geometry (label + CT volumes and true joint centres) for tests and benchmarks.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "posewarp/common/phantom.h"
#include "posewarp/common/result.h"
#include "posewarp/common/volume.h"
#include "posewarp/labels/label_map.h"

namespace posewarp::phantom {

// The phantoms and their knobs are vocabulary (posewarp/common/phantom.h).
using BodyParams = posewarp::BodyPhantomParams;
using posewarp::BarParams;
using posewarp::JointTruth;
using posewarp::MannequinParams;
using posewarp::Phantom;
using posewarp::rotation_direction;

Status validate(const BarParams& params);
Status validate(const MannequinParams& params);
Status validate(const BodyParams& params);

Result<Phantom> make_bar(const BarParams& params);
Result<Phantom> make_mannequin(const MannequinParams& params);
Result<Phantom> make_body(const BodyParams& params);

// The grid make_body would fill (validated, size checked), without rasterizing anything.
Result<ImageGeometry> body_grid(const BodyParams& params);

// The isotropic spacing that gives a mannequin of about `target_voxels` voxels with the other parameters kept.
double mannequin_spacing_for_voxels(const MannequinParams& params, int64_t target_voxels);

// The spacing, in the ratios of params.spacing_mm, that gives a body of about `target_voxels` voxels.
Vec3 body_spacing_for_voxels(const BodyParams& params, int64_t target_voxels);

// {"phantom": ..., "root_segment": ..., "joint_gap_mm": ..., "space": "LPS, mm",
//  "joints": [{"name", "parent", "child", "centre_mm": [x, y, z], "kind", "axis": [x, y, z] (hinges only)}],
//  "skin_contacts": [["arm_left", "trunk"], ...]}
std::string joints_to_json(const Phantom& phantom);

}  // namespace posewarp::phantom
