// posewarp's own OBJ reader: VTK 9.1's vtkOBJReader reads out of bounds on a face that names a texture coordinate
// or normal the file does not have, so OBJ files never reach it. Private to core/surface.
#pragma once

#include <string>

#include "posewarp/common/result.h"
#include "posewarp/surface/surface_mesh.h"

namespace posewarp::surface::detail {

// Vertices ("v x y z [w]") and faces ("f" with v, v/vt, v//vn or v/vt/vn corners, 1-based or negative = relative)
// of an OBJ text; polygons are split into fans of triangles; other statements are ignored. INVALID_ARGUMENT naming
// `path` and the line for malformed numbers, corners that name a missing vertex, binary content, or no triangles.
Result<SurfaceMesh> parse_obj(const std::string& text, const std::string& path);

}  // namespace posewarp::surface::detail
