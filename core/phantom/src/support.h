// What the phantoms share beyond rasterizing: tissue HU, parameter checks, the grid around a body (internals).
#pragma once

#include <array>
#include <vector>

#include "posewarp/common/label_map.h"
#include "posewarp/common/result.h"
#include "posewarp/common/volume.h"
#include "raster.h"

namespace posewarp::phantom::detail {

// Hounsfield units of the phantom tissues.
constexpr float kAirHu = -1000.0f;
constexpr float kFatHu = -100.0f;
constexpr float kSoftHu = 40.0f;
constexpr float kLiverHu = 60.0f;
constexpr float kBrainHu = 35.0f;
constexpr float kBoneHu = 700.0f;

// The tissue labels every phantom uses (its bones number from 10).
constexpr Label kSoftLabel = 1, kFatLabel = 2, kLiverLabel = 3, kBrainLabel = 4;
// The first entries of every phantom's label map: the background and the four tissues.
std::vector<LabelEntry> tissue_entries();
// The lumbar vertebrae L5 to L1, each its own segment, valued l5_value, l5_value + 1, ...
std::vector<LabelEntry> lumbar_entries(Label l5_value);

// INVALID_ARGUMENT unless `d` (row-major, columns = index axes in LPS) is a rotation.
Status validate_direction(const std::array<double, 9>& d);
// INVALID_ARGUMENT unless value > 0 and finite; `name` says which parameter in the message.
Status check_positive(double value, const char* name);
// RESOURCE_EXHAUSTED when the grid would hold more voxels than a phantom may.
Status check_size(const ImageGeometry& g);

// The grid with the given spacing and direction that holds the union of the shapes' bounds plus a margin.
ImageGeometry grid_for(const std::vector<Shape>& shapes, const Vec3& spacing, const std::array<double, 9>& direction,
                       double margin);

}  // namespace posewarp::phantom::detail
