// posewarp-view's files, written whole or not at all (core/common's AtomicFile and AtomicDirectory): a crash leaves
// no half file under the name asked for.
#include "files.h"

#include <vtkCellArray.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkSmartPointer.h>
#include <vtkXMLPolyDataWriter.h>

#include <cctype>
#include <filesystem>
#include <set>

#include "posewarp/common/atomic_file.h"

namespace posewarp::view {
namespace fs = std::filesystem;
namespace {

// A surface name from the server as a file name: letters, digits, '-' and '_' (anything else becomes '_', so
// nothing leaves the directory).
std::string file_name(const std::string& name, size_t index) {
  std::string safe;
  for (char c : name) safe += (std::isalnum(static_cast<unsigned char>(c)) || c == '-' || c == '_') ? c : '_';
  return safe.empty() ? "surface_" + std::to_string(index) : safe;
}

// False with the status's message in `error` unless it is OK.
bool succeeded(const Status& status, std::string* error) {
  if (!status.ok()) *error = status.message();
  return status.ok();
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
  Result<AtomicFile> file = AtomicFile::create(path.string(), "surface");
  if (!file.ok()) return succeeded(file.status(), error);
  auto writer = vtkSmartPointer<vtkXMLPolyDataWriter>::New();
  writer->SetInputData(mesh);
  writer->SetDataModeToBinary();
  writer->SetFileName(file->partial_path().c_str());
  if (writer->Write() == 0) {
    *error = "cannot write '" + path.string() + "' (disk full or directory not writable?)";
    return false;
  }
  return succeeded(file->commit(), error);
}

}  // namespace

bool write_file(const std::string& path, const std::string& text, std::string* error) {
  return succeeded(write_file_atomically(path, text, "file"), error);
}

bool save_posed(const PosedVolumes& posed, const std::string& dir, std::string* error) {
  // Everything goes into a partial directory that becomes DIR once whole: a failed save leaves no DIR that looks done.
  Result<AtomicDirectory> directory = AtomicDirectory::create(dir, "posed files", AtomicDirectory::Existing::kRefuse);
  if (!directory.ok()) return succeeded(directory.status(), error);
  const fs::path partial(directory->partial_path());
  std::error_code ec;
  fs::create_directories(partial / "surfaces", ec);
  if (ec) {
    *error = "cannot make the directory '" + (partial / "surfaces").string() + "': " + ec.message();
    return false;
  }
  bool ok = write_file((partial / "labels.nii.gz").string(), posed.labels, error) &&
            write_file((partial / "ct.nii.gz").string(), posed.ct, error) &&
            write_file((partial / "report.json").string(), posed.report.json(), error) &&
            write_file((partial / "pose.json").string(), posed.pose_json, error);
  std::set<std::string> used;
  for (size_t i = 0; ok && i < posed.surfaces.size(); ++i) {
    std::string name = file_name(posed.surfaces[i].name(), i);
    if (!used.insert(name).second) {  // two names alike once cleaned
      name.push_back('_');
      name.append(std::to_string(i));
      used.insert(name);
    }
    ok = write_surface(posed.surfaces[i], partial / "surfaces" / (name + ".vtp"), error);
  }
  return ok && succeeded(directory->commit(), error);
}

}  // namespace posewarp::view
