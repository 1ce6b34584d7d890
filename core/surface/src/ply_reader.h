// posewarp's own PLY reader: VTK 9.1's vtkPLYReader frees memory twice or frees wild pointers on truncated or
// damaged files, so PLY files never reach it. Private to core/surface.
#pragma once

#include <string>

#include "posewarp/common/result.h"
#include "posewarp/surface/surface_mesh.h"

namespace posewarp::surface::detail {

// Vertices (the x, y, z properties of element "vertex") and faces (list "vertex_indices" or "vertex_index" of
// element "face", polygons split into fans) of a whole PLY file in `bytes`: ASCII or binary, either byte order,
// any scalar types; other elements and properties are skipped. INVALID_ARGUMENT naming `path` for a malformed
// header, a body shorter than the header promises, indices out of range or non-finite coordinates.
Result<SurfaceMesh> parse_ply(const std::string& bytes, const std::string& path);

}  // namespace posewarp::surface::detail
