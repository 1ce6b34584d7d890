// posewarp-view's files: written to NAME.partial, then renamed, so a crash leaves no half file under NAME.
#include "files.h"

#include <vtkCellArray.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkSmartPointer.h>
#include <vtkXMLPolyDataWriter.h>

#include <fcntl.h>
#include <unistd.h>

#include <cctype>
#include <filesystem>
#include <fstream>
#include <set>

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

// The file's bytes on the disk before it takes its name.
bool flush_to_disk(const fs::path& path) {
  const int fd = ::open(path.c_str(), O_RDONLY);
  if (fd < 0) return false;
  const bool synced = ::fsync(fd) == 0;
  return ::close(fd) == 0 && synced;
}

bool commit(const fs::path& partial, const fs::path& path, std::string* error) {
  std::error_code ec;
  if (flush_to_disk(partial)) fs::rename(partial, path, ec);
  if (ec || fs::exists(partial)) {
    fs::remove(partial, ec);
    *error = "cannot write '" + path.string() + "'" + (ec ? ": " + ec.message() : " (disk full?)");
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
    out.close();
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
  // Everything goes into DIR.partial, which becomes DIR once whole: a failed save leaves no DIR that looks done.
  const fs::path root(dir), partial(dir + ".partial");
  std::error_code ec;
  if (fs::exists(root, ec)) {
    *error = "'" + dir + "' exists already; choose a new directory for the posed files";
    return false;
  }
  fs::remove_all(partial, ec);
  fs::create_directories(partial / "surfaces", ec);
  if (ec) {
    *error = "cannot make the directory '" + partial.string() + "': " + ec.message();
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
  if (ok) {
    fs::rename(partial, root, ec);
    if (ec) *error = "cannot name the posed files '" + dir + "': " + ec.message();
    ok = !ec;
  }
  if (!ok) fs::remove_all(partial, ec);
  return ok;
}

}  // namespace posewarp::view
