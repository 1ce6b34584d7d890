// posewarp-view's files: written to NAME.partial, then renamed, so a crash leaves no half file under NAME.
#include "files.h"

#include <vtkCellArray.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkSmartPointer.h>
#include <vtkXMLPolyDataWriter.h>

#include <cctype>
#include <filesystem>
#include <fstream>

namespace posewarp::view {
namespace fs = std::filesystem;
namespace {

// A surface name from the server as a file name: letters, digits, '-', '_' and '.', nothing that leaves `dir`.
std::string file_name(const std::string& name, size_t index) {
  std::string safe;
  for (char c : name) safe += (std::isalnum(static_cast<unsigned char>(c)) || c == '-' || c == '_') ? c : '_';
  return safe.empty() ? "surface_" + std::to_string(index) : safe;
}

bool commit(const fs::path& partial, const fs::path& path, std::string* error) {
  std::error_code ec;
  fs::rename(partial, path, ec);
  if (ec) {
    fs::remove(partial, ec);
    *error = "cannot write '" + path.string() + "': " + ec.message();
    return false;
  }
  return true;
}

bool write_surface(const v1::Surface& surface, const fs::path& path, std::string* error) {
  auto points = vtkSmartPointer<vtkPoints>::New();
  for (int i = 0; i + 2 < surface.vertices_size(); i += 3) {
    points->InsertNextPoint(surface.vertices(i), surface.vertices(i + 1), surface.vertices(i + 2));
  }
  auto triangles = vtkSmartPointer<vtkCellArray>::New();
  for (int i = 0; i + 2 < surface.triangles_size(); i += 3) {
    const vtkIdType ids[3] = {surface.triangles(i), surface.triangles(i + 1), surface.triangles(i + 2)};
    triangles->InsertNextCell(3, ids);
  }
  auto mesh = vtkSmartPointer<vtkPolyData>::New();
  mesh->SetPoints(points);
  mesh->SetPolys(triangles);
  const fs::path partial = path.string() + ".partial";
  auto writer = vtkSmartPointer<vtkXMLPolyDataWriter>::New();
  writer->SetInputData(mesh);
  writer->SetDataModeToBinary();
  writer->SetFileName(partial.c_str());
  if (writer->Write() == 0) {
    std::error_code ec;
    fs::remove(partial, ec);
    *error = "cannot write '" + path.string() + "' (disk full or directory not writable?)";
    return false;
  }
  return commit(partial, path, error);
}

}  // namespace

bool write_file(const std::string& path, const std::string& text, std::string* error) {
  const fs::path partial = path + ".partial";
  {
    std::ofstream out(partial, std::ios::binary | std::ios::trunc);
    out.write(text.data(), static_cast<std::streamsize>(text.size()));
    out.flush();
    if (!out) {
      std::error_code ec;
      fs::remove(partial, ec);
      *error = "cannot write '" + path + "' (disk full or directory not writable?)";
      return false;
    }
  }
  return commit(partial, path, error);
}

bool save_posed(const PosedVolumes& posed, const std::string& dir, std::string* error) {
  std::error_code ec;
  fs::create_directories(fs::path(dir) / "surfaces", ec);
  if (ec) {
    *error = "cannot make the directory '" + dir + "': " + ec.message();
    return false;
  }
  const fs::path root(dir);
  if (!write_file((root / "labels.nii.gz").string(), posed.labels, error) ||
      !write_file((root / "ct.nii.gz").string(), posed.ct, error) ||
      !write_file((root / "report.json").string(), posed.report.json(), error) ||
      !write_file((root / "pose.json").string(), posed.pose_json, error)) {
    return false;
  }
  for (size_t i = 0; i < posed.surfaces.size(); ++i) {
    const v1::Surface& s = posed.surfaces[i];
    if (!write_surface(s, root / "surfaces" / (file_name(s.name(), i) + ".vtp"), error)) return false;
  }
  return true;
}

}  // namespace posewarp::view
