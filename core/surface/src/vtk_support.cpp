// A silent, recording vtkOutputWindow and the SurfaceMesh <-> vtkPolyData conversions.
#include "vtk_support.h"

#include <vtkCellArray.h>
#include <vtkCellArrayIterator.h>
#include <vtkLogger.h>
#include <vtkNew.h>
#include <vtkObjectFactory.h>
#include <vtkOutputWindow.h>
#include <vtkPoints.h>
#include <vtkTriangleFilter.h>

#include <algorithm>
#include <mutex>
#include <regex>
#include <vector>

namespace posewarp::surface::detail {
namespace {

struct ThreadMessages {
  std::vector<std::string> errors;
  std::vector<std::string> warnings;
};

ThreadMessages& thread_messages() {
  thread_local ThreadMessages messages;
  return messages;
}

// "ERROR: In /build/vtk/IO/XML/vtkXMLReader.cxx, line 321\nvtkXMLPolyDataReader (0x5581...): Error parsing ...\n\n"
// becomes "vtkXMLPolyDataReader: Error parsing ...".
std::string tidy(const char* text) {
  std::string message = text ? text : "";
  static const std::regex location("^[A-Za-z ]*: In [^\\n]*, line [0-9]+\\n");
  static const std::regex address(" \\(0x[0-9a-fA-F]+\\)");
  message = std::regex_replace(message, location, "", std::regex_constants::format_first_only);
  message = std::regex_replace(message, address, "");
  while (!message.empty() && (message.back() == '\n' || message.back() == ' ')) message.pop_back();
  // Messages may quote bytes of a corrupt file: keep them printable and short.
  for (char& c : message) {
    const auto byte = static_cast<unsigned char>(c);
    if (byte == '\n' || byte == '\t')
      c = ' ';
    else if (byte < 0x20 || byte >= 0x7f)
      c = '?';
  }
  constexpr size_t kLongest = 300;
  if (message.size() > kLongest) message = message.substr(0, kLongest) + "...";
  return message;
}

// The executive's "Algorithm ... returned failure for request" repeats what the algorithm said; it is kept only
// when nothing else was said.
bool is_pipeline_echo(const std::string& message) {
  return message.find("returned failure for request") != std::string::npos;
}

std::string join(const std::vector<std::string>& parts) {
  const bool only_echoes = std::all_of(parts.begin(), parts.end(), is_pipeline_echo);
  std::string out;
  for (const std::string& part : parts) {
    if (part.empty() || (!only_echoes && is_pipeline_echo(part))) continue;
    if (!out.empty()) out += "; ";
    out += part;
  }
  return out;
}

}  // namespace

// Keeps every message off the terminal; errors and warnings go to the calling thread's buffers.
class RecordingOutputWindow : public vtkOutputWindow {
 public:
  static RecordingOutputWindow* New();
  vtkTypeMacro(RecordingOutputWindow, vtkOutputWindow)

      void DisplayText(const char*) override {}
  void DisplayErrorText(const char* text) override { thread_messages().errors.push_back(tidy(text)); }
  void DisplayWarningText(const char* text) override { thread_messages().warnings.push_back(tidy(text)); }
  void DisplayGenericWarningText(const char* text) override { thread_messages().warnings.push_back(tidy(text)); }
  void DisplayDebugText(const char*) override {}

 protected:
  RecordingOutputWindow() = default;
};

vtkStandardNewMacro(RecordingOutputWindow);

void install_quiet_vtk_output() {
  static std::once_flag once;
  std::call_once(once, [] {
    vtkNew<RecordingOutputWindow> window;
    vtkOutputWindow::SetInstance(window);
    // VTK also logs errors through loguru, which prints to stderr unless told otherwise.
    vtkLogger::SetStderrVerbosity(vtkLogger::VERBOSITY_OFF);
  });
}

void clear_vtk_messages() {
  thread_messages().errors.clear();
  thread_messages().warnings.clear();
}

std::string vtk_errors() {
  return join(thread_messages().errors);
}

std::string vtk_messages() {
  std::vector<std::string> all = thread_messages().errors;
  all.insert(all.end(), thread_messages().warnings.begin(), thread_messages().warnings.end());
  return join(all);
}

Result<SurfaceMesh> from_polydata(vtkPolyData* poly) {
  SurfaceMesh mesh;
  if (poly == nullptr) return mesh;
  const vtkIdType point_limit = poly->GetNumberOfPoints();
  for (vtkCellArray* cells : {poly->GetPolys(), poly->GetStrips()}) {
    if (cells == nullptr) continue;
    auto it = vtk::TakeSmartPointer(cells->NewIterator());
    for (it->GoToFirstCell(); !it->IsDoneWithTraversal(); it->GoToNextCell()) {
      vtkIdType size = 0;
      const vtkIdType* ids = nullptr;
      it->GetCurrentCell(size, ids);
      for (vtkIdType c = 0; c < size; ++c) {
        if (ids[c] < 0 || ids[c] >= point_limit) {
          return invalid_argument_error("a polygon refers to point " + std::to_string(ids[c]) + " of " +
                                        std::to_string(point_limit));
        }
      }
    }
  }
  vtkNew<vtkTriangleFilter> triangulate;
  triangulate->SetInputData(poly);
  triangulate->PassVertsOff();
  triangulate->PassLinesOff();
  triangulate->Update();
  vtkPolyData* triangles = triangulate->GetOutput();
  const vtkIdType point_count = triangles->GetNumberOfPoints();
  mesh.vertices.resize(point_count, 3);
  for (vtkIdType v = 0; v < point_count; ++v) {
    double p[3];
    triangles->GetPoint(v, p);
    mesh.vertices.row(v) << p[0], p[1], p[2];
  }
  vtkCellArray* polys = triangles->GetPolys();
  mesh.triangles.resize(polys->GetNumberOfCells(), 3);
  Eigen::Index f = 0;
  auto cells = vtk::TakeSmartPointer(polys->NewIterator());
  for (cells->GoToFirstCell(); !cells->IsDoneWithTraversal(); cells->GoToNextCell()) {
    vtkIdType size = 0;
    const vtkIdType* ids = nullptr;
    cells->GetCurrentCell(size, ids);
    if (size != 3) continue;
    for (int c = 0; c < 3; ++c) mesh.triangles(f, c) = static_cast<int>(ids[c]);
    ++f;
  }
  mesh.triangles.conservativeResize(f, 3);
  return mesh;
}

vtkSmartPointer<vtkPolyData> to_polydata(const SurfaceMesh& mesh) {
  vtkNew<vtkPoints> points;
  points->SetDataTypeToDouble();
  points->SetNumberOfPoints(mesh.vertices.rows());
  for (Eigen::Index v = 0; v < mesh.vertices.rows(); ++v) {
    points->SetPoint(v, mesh.vertices(v, 0), mesh.vertices(v, 1), mesh.vertices(v, 2));
  }
  vtkNew<vtkCellArray> cells;
  cells->AllocateExact(mesh.triangles.rows(), 3 * mesh.triangles.rows());
  for (Eigen::Index f = 0; f < mesh.triangles.rows(); ++f) {
    const vtkIdType ids[3] = {mesh.triangles(f, 0), mesh.triangles(f, 1), mesh.triangles(f, 2)};
    cells->InsertNextCell(3, ids);
  }
  auto poly = vtkSmartPointer<vtkPolyData>::New();
  poly->SetPoints(points);
  poly->SetPolys(cells);
  return poly;
}

}  // namespace posewarp::surface::detail
