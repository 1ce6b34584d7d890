// posewarp's own STL reader: VTK 9.1's vtkSTLReader takes a text file with one non-ASCII byte for a binary one and
// allocates whatever triangle count bytes 80-83 then say (4 GB from a 480-byte file, found by fuzzing), so STL
// files never reach it. Private to core/surface.
#pragma once

#include <string>

#include "posewarp/common/result.h"
#include "posewarp/surface/surface_mesh.h"

namespace posewarp::surface::detail {

// A whole STL file in `bytes`: binary when its size is exactly 84 + 50 bytes per triangle it declares, else ASCII
// ("solid", then "vertex x y z" lines, three per facet). Coincident vertices are merged (as VTK's MergingOn did).
// INVALID_ARGUMENT naming `path` for anything else.
Result<SurfaceMesh> parse_stl(const std::string& bytes, const std::string& path);

}  // namespace posewarp::surface::detail
