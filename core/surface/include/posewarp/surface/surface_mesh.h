// Triangle surfaces: per-label surfaces at rest (discrete flying edges, windowed-sinc smoothing, quadric
// decimation; Sujar et al. 2018 section 3.4) and mesh files (STL, OBJ, PLY, VTP). VTK stays inside src/.
#pragma once

#include <Eigen/Core>

#include <string>
#include <utility>
#include <vector>

#include "posewarp/common/progress.h"
#include "posewarp/common/result.h"
#include "posewarp/common/rig_params.h"
#include "posewarp/common/surface_mesh.h"
#include "posewarp/common/volume.h"

namespace posewarp::surface {

// The mesh itself is vocabulary (posewarp/common/surface_mesh.h), under the name the stage has always used.
using posewarp::SurfaceMesh;

using posewarp::SurfaceParams;  // posewarp/common/rig_params.h

// INVALID_ARGUMENT naming the field and its valid range.
Status validate(const SurfaceParams& params);

// One surface per wanted label value present in `labels` (absent values are skipped, repeated values extracted
// once), in the order of `wanted`, named by its string: discrete flying edges on the label's mask (the surface
// passes half-way between label and non-label voxel centres), then smoothing and decimation in mm. Vertices are in
// physical LPS mm (spacing, origin and direction applied), triangles face out of the label, so the inner wall of
// a hollow label faces its cavity. INVALID_ARGUMENT for bad params or geometry, CANCELLED when the hooks ask,
// INTERNAL when VTK reports a failure.
Result<std::vector<SurfaceMesh>> extract_label_surfaces(const LabelVolume& labels,
                                                        const std::vector<std::pair<Label, std::string>>& wanted,
                                                        const SurfaceParams& params, const ProgressHooks& hooks);

// Reads a triangle mesh by extension (case-insensitive): .stl (ASCII or binary; coincident vertices merged), .obj,
// .ply, .vtp. Polygons and strips are triangulated; lines and points are dropped. name = the file's stem,
// label = 0. NOT_FOUND for a missing file, INVALID_ARGUMENT naming the file for an unknown extension or an empty,
// corrupt or triangle-free file. VTK's messages never reach stderr; its errors end up in the Status message.
Result<SurfaceMesh> read_surface(const std::string& path);

// Writes by extension: .stl (binary, float32, vertices repeated per triangle as STL requires), .obj (ASCII),
// .ply (binary, float32), .vtp (XML, binary, float64). The file is written under a temporary name in the same
// directory and renamed into place, so readers never see half a file. INVALID_ARGUMENT for an unknown extension
// or a mesh with no triangles, non-finite vertices or indices out of range; NOT_FOUND when the directory does not
// exist; INVALID_ARGUMENT naming the file when writing fails.
Status write_surface(const SurfaceMesh& mesh, const std::string& path);

// The same .vtp file's bytes in memory (XML, binary, float64), for a network stream. INVALID_ARGUMENT as above.
Result<std::string> surface_to_vtp_bytes(const SurfaceMesh& mesh);

}  // namespace posewarp::surface
