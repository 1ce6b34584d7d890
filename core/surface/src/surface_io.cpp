// read_surface and write_surface: STL, OBJ, PLY and VTP through VTK's readers and writers, with VTK's silent
// failures (warnings and empty outputs) turned into Status errors that name the file.
#include "posewarp/surface/surface_mesh.h"
#include "posewarp/common/atomic_file.h"
#include "posewarp/common/exception_wall.h"
#include "posewarp/common/input_file.h"

#include <vtkNew.h>
#include <vtkOBJWriter.h>
#include <vtkPLYWriter.h>
#include <vtkSTLWriter.h>
#include <vtkXMLPolyDataReader.h>
#include <vtkXMLPolyDataWriter.h>


#include <algorithm>
#include <cctype>
#include <exception>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <new>
#include <string>

#include "obj_reader.h"
#include "ply_reader.h"
#include "stl_reader.h"
#include "vtk_support.h"

namespace posewarp::surface {
namespace {

namespace fs = std::filesystem;

enum class MeshFormat { kUnknown, kStl, kObj, kPly, kVtp };

MeshFormat format_of(const std::string& path) {
  std::string extension = fs::path(path).extension().string();
  std::transform(extension.begin(), extension.end(), extension.begin(),
                 [](unsigned char c) { return static_cast<char>(std::tolower(c)); });
  if (extension == ".stl") return MeshFormat::kStl;
  if (extension == ".obj") return MeshFormat::kObj;
  if (extension == ".ply") return MeshFormat::kPly;
  if (extension == ".vtp") return MeshFormat::kVtp;
  return MeshFormat::kUnknown;
}

const char* format_name(MeshFormat format) {
  switch (format) {
    case MeshFormat::kStl: return "STL";
    case MeshFormat::kObj: return "OBJ";
    case MeshFormat::kPly: return "PLY";
    case MeshFormat::kVtp: return "VTK XML poly data (VTP)";
    case MeshFormat::kUnknown: break;
  }
  return "unknown";
}

std::string quoted(const std::string& path) {
  return "'" + path + "'";
}

Status unknown_format(const std::string& path) {
  return invalid_argument_error("cannot tell the mesh format of " + quoted(path) +
                                " from its extension; use .stl, .obj, .ply or .vtp");
}

// Runs a reader (any VTK poly data reader) and returns its output, or why there is none.
template <typename Reader>
Result<SurfaceMesh> run_reader(Reader* reader, const std::string& path, MeshFormat format) {
  reader->SetFileName(path.c_str());
  detail::clear_vtk_messages();
  reader->Update();
  const std::string errors = detail::vtk_errors();
  const std::string what = std::string(" as ") + format_name(format);
  if (!errors.empty()) {
    return invalid_argument_error("cannot read " + quoted(path) + what + " (corrupt or not that format): " + errors);
  }
  vtkPolyData* poly = reader->GetOutput();
  if (poly == nullptr || poly->GetNumberOfPoints() == 0) {
    const std::string messages = detail::vtk_messages();
    return invalid_argument_error(quoted(path) + " holds no vertices when read" + what +
                                  " (corrupt or not that format)" + (messages.empty() ? "" : ": " + messages));
  }
  Result<SurfaceMesh> mesh = detail::from_polydata(poly);
  if (!mesh.ok()) return mesh.status().with_context("cannot read " + quoted(path) + what);
  return mesh;
}

Result<std::string> file_bytes(const std::string& path) {
  constexpr int64_t kMaxMeshBytes = int64_t{2} << 30;
  return read_text_input(path, "mesh", kMaxMeshBytes);
}

// The counts a VTP file declares (NumberOfPoints, NumberOfComponents, NumberOfPolys, ...) must be plain whole numbers
// of sane size before VTK's XML reader sees them: it looped without end on NumberOfComponents="\n" (found by
// fuzzing) and allocates whatever a count says.
Status check_vtp_counts(const std::string& bytes, const std::string& path) {
  for (size_t at = bytes.find("NumberOf"); at != std::string::npos; at = bytes.find("NumberOf", at + 8)) {
    const size_t eq = bytes.find('=', at);
    const size_t open = eq == std::string::npos ? eq : bytes.find_first_not_of(" \t", eq + 1);
    if (open == std::string::npos || (bytes[open] != '"' && bytes[open] != '\'')) continue;  // text, not an attribute
    const size_t close = bytes.find(bytes[open], open + 1);
    const std::string value = bytes.substr(open + 1, close == std::string::npos ? 0 : close - open - 1);
    const bool components = bytes.compare(at, 18, "NumberOfComponents") == 0;
    const bool whole = !value.empty() && value.size() <= 10 &&
                       std::all_of(value.begin(), value.end(), [](char c) { return c >= '0' && c <= '9'; });
    if (!whole || std::stoll(value) > (components ? 16LL : 100'000'000LL)) {
      return invalid_argument_error("cannot read mesh " + quoted(path) + ": it declares " +
                                    bytes.substr(at, std::min<size_t>(eq - at, 40)) + "=\"" + value.substr(0, 20) +
                                    "\", which is not a whole number of sane size (the file is damaged)");
    }
  }
  return ok_status();
}

// VTP goes through VTK's reader, which survives damaged files; OBJ, PLY and STL through posewarp's own, because
// VTK 9.1's crash or allocate without bound on some damaged files (see obj_reader.h, ply_reader.h, stl_reader.h).
Result<SurfaceMesh> read_by_format(const std::string& path, MeshFormat format) {
  switch (format) {
    case MeshFormat::kStl: {
      POSEWARP_ASSIGN_OR_RETURN(const std::string bytes, file_bytes(path));
      return detail::parse_stl(bytes, path);
    }
    case MeshFormat::kObj: {
      POSEWARP_ASSIGN_OR_RETURN(const std::string text, file_bytes(path));
      return detail::parse_obj(text, path);
    }
    case MeshFormat::kPly: {
      POSEWARP_ASSIGN_OR_RETURN(const std::string bytes, file_bytes(path));
      return detail::parse_ply(bytes, path);
    }
    case MeshFormat::kVtp: {
      POSEWARP_ASSIGN_OR_RETURN(const std::string bytes, file_bytes(path));
      POSEWARP_RETURN_IF_ERROR(check_vtp_counts(bytes, path));
      detail::install_quiet_vtk_output();
      vtkNew<vtkXMLPolyDataReader> reader;
      return run_reader(reader.GetPointer(), path, format);
    }
    case MeshFormat::kUnknown: break;
  }
  return unknown_format(path);
}

Status check_mesh(const SurfaceMesh& mesh, const std::string& path) {
  const std::string where = "cannot write " + quoted(path) + ": ";
  if (mesh.triangles.rows() == 0) return invalid_argument_error(where + "the mesh has no triangles");
  if (mesh.vertices.cols() != 3 || mesh.triangles.cols() != 3) {
    return invalid_argument_error(where + "the mesh needs #V x 3 vertices and #F x 3 triangles");
  }
  if (!mesh.vertices.allFinite()) return invalid_argument_error(where + "the mesh has non-finite vertices");
  if (mesh.triangles.minCoeff() < 0 || mesh.triangles.maxCoeff() >= mesh.vertices.rows()) {
    return invalid_argument_error(where + "triangles refer to vertices the mesh does not have");
  }
  return ok_status();
}

}  // namespace

static Result<SurfaceMesh> read_surface_unguarded(const std::string& path) {
  const MeshFormat format = format_of(path);
  if (format == MeshFormat::kUnknown) return unknown_format(path);
  POSEWARP_RETURN_IF_ERROR(check_input_file(path, "mesh"));
  std::error_code ec;
  if (fs::file_size(path, ec) == 0) {
    return invalid_argument_error("mesh " + quoted(path) + " is empty (0 bytes); the file was not written completely");
  }
  SurfaceMesh mesh;
  try {
    Result<SurfaceMesh> read = read_by_format(path, format);
    if (!read.ok()) return read.status();
    mesh = std::move(read).value();
  } catch (const std::bad_alloc&) {
    return resource_exhausted_error("out of memory reading mesh " + quoted(path) + " (corrupt counts in the file?)");
  } catch (const std::exception& error) {
    return invalid_argument_error("cannot read mesh " + quoted(path) + ": " + error.what());
  }
  if (mesh.triangles.rows() == 0) {
    return invalid_argument_error("mesh " + quoted(path) +
                                  " holds vertices but no triangles (a point cloud or lines?)");
  }
  if (!mesh.vertices.allFinite()) {
    return invalid_argument_error("mesh " + quoted(path) + " has non-finite vertices (corrupt or not " +
                                  format_name(format) + "?)");
  }
  if (mesh.triangles.minCoeff() < 0 || mesh.triangles.maxCoeff() >= mesh.vertices.rows()) {
    return invalid_argument_error("mesh " + quoted(path) + " has triangles that refer to missing vertices");
  }
  mesh.name = fs::path(path).stem().string();
  mesh.label = 0;
  return mesh;
}

Result<SurfaceMesh> read_surface(const std::string& path) {
  return guarded("reading mesh " + quoted(path), [&] { return read_surface_unguarded(path); });
}

static Status write_surface_unguarded(const SurfaceMesh& mesh, const std::string& path) {
  const MeshFormat format = format_of(path);
  if (format == MeshFormat::kUnknown) return unknown_format(path);
  POSEWARP_RETURN_IF_ERROR(check_mesh(mesh, path));
  const fs::path target(path);
  const fs::path directory = target.has_parent_path() ? target.parent_path() : fs::path(".");
  std::error_code ec;
  if (!fs::is_directory(directory, ec)) {
    return not_found_error("cannot write mesh " + quoted(path) + ": directory " + quoted(directory.string()) +
                           " does not exist");
  }
  if (fs::is_directory(target, ec)) {
    return invalid_argument_error("cannot write mesh " + quoted(path) + ": a directory has that name");
  }
  POSEWARP_ASSIGN_OR_RETURN(AtomicFile file, AtomicFile::create(path, "mesh"));
  const std::string temporary = file.partial_path();
  detail::install_quiet_vtk_output();
  int written = 0;
  std::string errors;
  try {
    const vtkSmartPointer<vtkPolyData> poly = detail::to_polydata(mesh);
    detail::clear_vtk_messages();
    switch (format) {
      case MeshFormat::kStl: {
        vtkNew<vtkSTLWriter> writer;
        writer->SetInputData(poly);
        writer->SetFileName(temporary.c_str());
        writer->SetFileTypeToBinary();
        written = writer->Write();
        break;
      }
      case MeshFormat::kObj: {
        vtkNew<vtkOBJWriter> writer;
        writer->SetInputData(poly);
        writer->SetFileName(temporary.c_str());
        written = writer->Write();
        break;
      }
      case MeshFormat::kPly: {
        vtkNew<vtkPLYWriter> writer;
        writer->SetInputData(poly);
        writer->SetFileName(temporary.c_str());
        writer->SetFileTypeToBinary();
        written = writer->Write();
        break;
      }
      case MeshFormat::kVtp: {
        vtkNew<vtkXMLPolyDataWriter> writer;
        writer->SetInputData(poly);
        writer->SetFileName(temporary.c_str());
        writer->SetDataModeToBinary();
        written = writer->Write();
        break;
      }
      case MeshFormat::kUnknown: break;
    }
    errors = detail::vtk_errors();
  } catch (const std::exception& error) {
    errors = error.what();
    written = 0;
  }
  if (!written || !errors.empty()) {
    return invalid_argument_error("writing mesh " + quoted(path) + " failed (disk full or directory not writable?)" +
                                  (errors.empty() ? "" : ": " + errors));
  }
  return file.commit();
}

Status write_surface(const SurfaceMesh& mesh, const std::string& path) {
  return guarded("writing mesh " + quoted(path), [&] { return write_surface_unguarded(mesh, path); });
}

Result<std::string> surface_to_vtp_bytes(const SurfaceMesh& mesh) {
  return guarded("encoding mesh '" + mesh.name + "' as VTP", [&]() -> Result<std::string> {
    if (mesh.triangles.rows() == 0) return invalid_argument_error("mesh '" + mesh.name + "' has no triangles");
    detail::install_quiet_vtk_output();
    const vtkSmartPointer<vtkPolyData> poly = detail::to_polydata(mesh);
    detail::clear_vtk_messages();
    vtkNew<vtkXMLPolyDataWriter> writer;
    writer->SetInputData(poly);
    writer->SetDataModeToBinary();
    writer->WriteToOutputStringOn();
    const int written = writer->Write();
    const std::string errors = detail::vtk_errors();
    if (!written || !errors.empty()) {
      return invalid_argument_error("encoding mesh '" + mesh.name + "' as VTP failed" +
                                    (errors.empty() ? "" : ": " + errors));
    }
    return writer->GetOutputString();
  });
}

}  // namespace posewarp::surface
