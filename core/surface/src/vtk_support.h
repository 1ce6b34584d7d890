// What the surface stage needs around VTK: a silent output window that keeps VTK's errors for the Status, and
// conversions between SurfaceMesh and vtkPolyData. Private to core/surface.
#pragma once

#include <vtkPolyData.h>
#include <vtkSmartPointer.h>

#include <string>

#include "posewarp/surface/surface_mesh.h"

namespace posewarp::surface::detail {

// Routes VTK's error, warning and text output away from stderr, into per-thread buffers (installed once per
// process; VTK's global warning display stays on so that errors still reach the buffers).
void install_quiet_vtk_output();

// Forgets what VTK reported on this thread so far.
void clear_vtk_messages();

// VTK's error messages on this thread since the last clear, joined by "; ", without VTK's file and line prefixes.
// Empty when there were none.
std::string vtk_errors();
// The same for errors and warnings together (for explaining an empty read that reported no error).
std::string vtk_messages();

// Vertices and triangles of `poly` (polygons and strips triangulated; lines and vertices dropped). INVALID_ARGUMENT
// when a polygon or strip refers to a point `poly` does not have (checked before VTK touches those points).
Result<SurfaceMesh> from_polydata(vtkPolyData* poly);

// A poly data with double-precision points and one triangle cell per row of mesh.triangles.
vtkSmartPointer<vtkPolyData> to_polydata(const SurfaceMesh& mesh);

}  // namespace posewarp::surface::detail
