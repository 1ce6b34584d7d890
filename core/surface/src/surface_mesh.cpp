// VTK behind the surface stage: discrete flying edges, smoothing, decimation, readers and writers.
#include "posewarp/surface/surface_mesh.h"

#include <vtkCellArray.h>
#include <vtkCleanPolyData.h>
#include <vtkDiscreteFlyingEdges3D.h>
#include <vtkIdList.h>
#include <vtkImageData.h>
#include <vtkNew.h>
#include <vtkOBJReader.h>
#include <vtkOBJWriter.h>
#include <vtkPLYReader.h>
#include <vtkPLYWriter.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkPolyDataNormals.h>
#include <vtkQuadricDecimation.h>
#include <vtkSTLReader.h>
#include <vtkSTLWriter.h>
#include <vtkSmartPointer.h>
#include <vtkTriangleFilter.h>
#include <vtkUnsignedCharArray.h>
#include <vtkPointData.h>
#include <vtkWindowedSincPolyDataFilter.h>
#include <vtkXMLPolyDataReader.h>
#include <vtkXMLPolyDataWriter.h>

#include <unistd.h>

#include <algorithm>
#include <filesystem>
#include <map>

namespace posewarp::surface {
namespace {

namespace fs = std::filesystem;

bool ends_with(const std::string& s, const std::string& suffix) {
  if (s.size() < suffix.size()) return false;
  return std::equal(suffix.rbegin(), suffix.rend(), s.rbegin(),
                    [](char a, char b) { return a == std::tolower(static_cast<unsigned char>(b)); });
}

void quiet_vtk() {
  static const bool done = [] {
    vtkObject::GlobalWarningDisplayOff();
    return true;
  }();
  (void)done;
}

// Triangles of a poly data (strips and polygons triangulated first).
SurfaceMesh from_polydata(vtkPolyData* poly) {
  vtkNew<vtkTriangleFilter> triangles;
  triangles->SetInputData(poly);
  triangles->PassLinesOff();
  triangles->PassVertsOff();
  triangles->Update();
  vtkPolyData* out = triangles->GetOutput();
  SurfaceMesh mesh;
  const vtkIdType nv = out->GetNumberOfPoints();
  mesh.vertices.resize(nv, 3);
  for (vtkIdType v = 0; v < nv; ++v) {
    double p[3];
    out->GetPoint(v, p);
    mesh.vertices.row(v) << p[0], p[1], p[2];
  }
  vtkCellArray* polys = out->GetPolys();
  mesh.triangles.resize(polys->GetNumberOfCells(), 3);
  vtkNew<vtkIdList> ids;
  polys->InitTraversal();
  vtkIdType f = 0;
  while (polys->GetNextCell(ids)) {
    if (ids->GetNumberOfIds() != 3) continue;
    for (int c = 0; c < 3; ++c) mesh.triangles(f, c) = static_cast<int>(ids->GetId(c));
    ++f;
  }
  mesh.triangles.conservativeResize(f, 3);
  return mesh;
}

vtkSmartPointer<vtkPolyData> to_polydata(const SurfaceMesh& mesh) {
  auto poly = vtkSmartPointer<vtkPolyData>::New();
  vtkNew<vtkPoints> points;
  points->SetDataTypeToDouble();
  points->SetNumberOfPoints(mesh.vertices.rows());
  for (Eigen::Index v = 0; v < mesh.vertices.rows(); ++v) {
    points->SetPoint(v, mesh.vertices(v, 0), mesh.vertices(v, 1), mesh.vertices(v, 2));
  }
  vtkNew<vtkCellArray> cells;
  for (Eigen::Index f = 0; f < mesh.triangles.rows(); ++f) {
    const vtkIdType ids[3] = {mesh.triangles(f, 0), mesh.triangles(f, 1), mesh.triangles(f, 2)};
    cells->InsertNextCell(3, ids);
  }
  poly->SetPoints(points);
  poly->SetPolys(cells);
  return poly;
}

}  // namespace

Status validate(const SurfaceParams& params) {
  if (params.smoothing_iterations < 0) return invalid_argument_error("surface smoothing_iterations must be >= 0");
  if (!(params.pass_band > 0.0) || params.pass_band > 2.0) return invalid_argument_error("surface pass_band must lie in (0, 2]");
  if (params.decimation < 0.0 || params.decimation >= 1.0) return invalid_argument_error("surface decimation must lie in [0, 1)");
  return ok_status();
}

Result<std::vector<SurfaceMesh>> extract_label_surfaces(const LabelVolume& labels,
                                                        const std::vector<std::pair<Label, std::string>>& wanted,
                                                        const SurfaceParams& params, const ProgressHooks& hooks) {
  POSEWARP_RETURN_IF_ERROR(validate(params));
  quiet_vtk();
  StageProgress progress(hooks, "surfaces");
  const ImageGeometry& g = labels.geometry();
  // Bounding box of each wanted label, so each surface is extracted from its own small crop.
  std::map<Label, std::pair<Index3, Index3>> boxes;
  for (const auto& [value, name] : wanted) boxes[value] = {{g.size[0], g.size[1], g.size[2]}, {-1, -1, -1}};
  for (int64_t k = 0; k < g.size[2]; ++k)
    for (int64_t j = 0; j < g.size[1]; ++j)
      for (int64_t i = 0; i < g.size[0]; ++i) {
        auto it = boxes.find(labels.at(i, j, k));
        if (it == boxes.end()) continue;
        auto& [lo, hi] = it->second;
        lo = {std::min(lo[0], i), std::min(lo[1], j), std::min(lo[2], k)};
        hi = {std::max(hi[0], i), std::max(hi[1], j), std::max(hi[2], k)};
      }
  std::vector<SurfaceMesh> surfaces;
  size_t done = 0;
  for (const auto& [value, name] : wanted) {
    const auto& [lo, hi] = boxes[value];
    ++done;
    if (hi[0] < 0) continue;  // absent
    // A crop one voxel larger on each side, so the surface closes.
    Index3 first{}, size{};
    for (int a = 0; a < 3; ++a) first[a] = lo[a] - 1, size[a] = hi[a] - lo[a] + 3;
    vtkNew<vtkImageData> image;
    image->SetDimensions(static_cast<int>(size[0]), static_cast<int>(size[1]), static_cast<int>(size[2]));
    image->AllocateScalars(VTK_UNSIGNED_CHAR, 1);
    auto* mask = static_cast<unsigned char*>(image->GetScalarPointer());
    for (int64_t k = 0; k < size[2]; ++k)
      for (int64_t j = 0; j < size[1]; ++j)
        for (int64_t i = 0; i < size[0]; ++i) {
          const int64_t x = first[0] + i, y = first[1] + j, z = first[2] + k;
          mask[i + size[0] * (j + size[1] * k)] = labels.contains(x, y, z) && labels.at(x, y, z) == value ? 1 : 0;
        }
    vtkNew<vtkDiscreteFlyingEdges3D> contour;
    contour->SetInputData(image);
    contour->SetValue(0, 1);
    contour->ComputeNormalsOff();
    contour->ComputeGradientsOff();
    vtkSmartPointer<vtkAlgorithm> last = contour;
    vtkNew<vtkWindowedSincPolyDataFilter> smooth;
    if (params.smoothing_iterations > 0) {
      smooth->SetInputConnection(last->GetOutputPort());
      smooth->SetNumberOfIterations(params.smoothing_iterations);
      smooth->SetPassBand(params.pass_band);
      smooth->BoundarySmoothingOff();
      smooth->FeatureEdgeSmoothingOff();
      smooth->NonManifoldSmoothingOn();
      smooth->NormalizeCoordinatesOn();
      last = smooth;
    }
    vtkNew<vtkQuadricDecimation> decimate;
    if (params.decimation > 0.0) {
      decimate->SetInputConnection(last->GetOutputPort());
      decimate->SetTargetReduction(params.decimation);
      last = decimate;
    }
    vtkNew<vtkPolyDataNormals> orient;  // consistent, outward-facing triangles
    orient->SetInputConnection(last->GetOutputPort());
    orient->ConsistencyOn();
    orient->AutoOrientNormalsOn();
    orient->SplittingOff();
    orient->ComputeCellNormalsOff();
    orient->Update();
    SurfaceMesh mesh = from_polydata(orient->GetOutput());
    // Crop index -> physical.
    for (Eigen::Index v = 0; v < mesh.vertices.rows(); ++v) {
      const Vec3 p = g.index_to_physical({mesh.vertices(v, 0) + static_cast<double>(first[0]),
                                          mesh.vertices(v, 1) + static_cast<double>(first[1]),
                                          mesh.vertices(v, 2) + static_cast<double>(first[2])});
      mesh.vertices.row(v) << p[0], p[1], p[2];
    }
    // A left-handed grid mirrors the triangles: flip them back to outward.
    const double* d = g.direction.data();
    const double det = d[0] * (d[4] * d[8] - d[5] * d[7]) - d[1] * (d[3] * d[8] - d[5] * d[6]) + d[2] * (d[3] * d[7] - d[4] * d[6]);
    if (det < 0.0) mesh.triangles.col(1).swap(mesh.triangles.col(2));
    mesh.name = name;
    mesh.label = value;
    if (mesh.triangles.rows() > 0) surfaces.push_back(std::move(mesh));
    progress.update(static_cast<double>(done) / static_cast<double>(wanted.size()));
    POSEWARP_RETURN_IF_ERROR(progress.check_cancel());
  }
  progress.finish();
  return surfaces;
}

Result<SurfaceMesh> read_surface(const std::string& path) {
  quiet_vtk();
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) return not_found_error("cannot read surface '" + path + "': no such file");
  if (fs::file_size(path, ec) == 0) return invalid_argument_error("surface file '" + path + "' is empty");
  vtkSmartPointer<vtkPolyData> poly;
  if (ends_with(path, ".stl")) {
    vtkNew<vtkSTLReader> r;
    r->SetFileName(path.c_str());
    r->Update();
    poly = r->GetOutput();
  } else if (ends_with(path, ".obj")) {
    vtkNew<vtkOBJReader> r;
    r->SetFileName(path.c_str());
    r->Update();
    poly = r->GetOutput();
  } else if (ends_with(path, ".ply")) {
    vtkNew<vtkPLYReader> r;
    r->SetFileName(path.c_str());
    r->Update();
    poly = r->GetOutput();
  } else if (ends_with(path, ".vtp")) {
    vtkNew<vtkXMLPolyDataReader> r;
    r->SetFileName(path.c_str());
    r->Update();
    poly = r->GetOutput();
  } else {
    return invalid_argument_error("cannot tell the format of surface '" + path + "': use .stl, .obj, .ply or .vtp");
  }
  if (poly == nullptr || poly->GetNumberOfPoints() == 0) {
    return invalid_argument_error("surface file '" + path + "' holds no points (corrupt or not a mesh of its extension)");
  }
  SurfaceMesh mesh = from_polydata(poly);
  if (mesh.triangles.rows() == 0) return invalid_argument_error("surface file '" + path + "' holds no triangles");
  if (!mesh.vertices.allFinite()) return invalid_argument_error("surface file '" + path + "' has non-finite vertices");
  mesh.name = fs::path(path).stem().string();
  return mesh;
}

Status write_surface(const SurfaceMesh& mesh, const std::string& path) {
  quiet_vtk();
  const vtkSmartPointer<vtkPolyData> poly = to_polydata(mesh);
  const fs::path target(path);
  const fs::path temporary =
      target.parent_path() / (".posewarp-partial-" + std::to_string(::getpid()) + "-" + target.filename().string());
  int ok = 0;
  if (ends_with(path, ".stl")) {
    vtkNew<vtkSTLWriter> w;
    w->SetInputData(poly);
    w->SetFileName(temporary.c_str());
    w->SetFileTypeToBinary();
    ok = w->Write();
  } else if (ends_with(path, ".obj")) {
    vtkNew<vtkOBJWriter> w;
    w->SetInputData(poly);
    w->SetFileName(temporary.c_str());
    ok = w->Write();
  } else if (ends_with(path, ".ply")) {
    vtkNew<vtkPLYWriter> w;
    w->SetInputData(poly);
    w->SetFileName(temporary.c_str());
    w->SetFileTypeToBinary();
    ok = w->Write();
  } else if (ends_with(path, ".vtp")) {
    vtkNew<vtkXMLPolyDataWriter> w;
    w->SetInputData(poly);
    w->SetFileName(temporary.c_str());
    ok = w->Write();
  } else {
    return invalid_argument_error("cannot tell the format of surface '" + path + "': use .stl, .obj, .ply or .vtp");
  }
  std::error_code ec;
  if (!ok) {
    fs::remove(temporary, ec);
    return invalid_argument_error("writing surface '" + path + "' failed (directory missing or not writable?)");
  }
  fs::rename(temporary, target, ec);
  if (ec) return internal_error("could not move surface into place at '" + path + "': " + ec.message());
  return ok_status();
}

}  // namespace posewarp::surface
