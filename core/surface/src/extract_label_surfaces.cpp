// Per-label surfaces at rest: a cropped mask per label through discrete flying edges, windowed-sinc smoothing and
// quadric decimation, then into physical LPS mm and turned to face out of the label.
#include "posewarp/surface/surface_mesh.h"

#include <vtkAlgorithm.h>
#include <vtkCallbackCommand.h>
#include <vtkCommand.h>
#include <vtkDiscreteFlyingEdges3D.h>
#include <vtkImageData.h>
#include <vtkNew.h>
#include <vtkQuadricDecimation.h>
#include <vtkSmartPointer.h>
#include <vtkWindowedSincPolyDataFilter.h>

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <exception>
#include <limits>
#include <mutex>
#include <new>
#include <string>
#include <unordered_map>

#include "posewarp/common/exception_wall.h"
#include "posewarp/common/parallel.h"
#include "vtk_support.h"

namespace posewarp::surface {
namespace {

// Voxel index box of one label: lo > hi while the label has not been seen.
struct IndexBox {
  Index3 lo{std::numeric_limits<int64_t>::max(), std::numeric_limits<int64_t>::max(),
            std::numeric_limits<int64_t>::max()};
  Index3 hi{-1, -1, -1};

  bool empty() const { return hi[0] < 0; }
  void add(int64_t i, int64_t j, int64_t k) {
    lo = {std::min(lo[0], i), std::min(lo[1], j), std::min(lo[2], k)};
    hi = {std::max(hi[0], i), std::max(hi[1], j), std::max(hi[2], k)};
  }
  void add(const IndexBox& other) {
    if (other.empty()) return;
    add(other.lo[0], other.lo[1], other.lo[2]);
    add(other.hi[0], other.hi[1], other.hi[2]);
  }
};

// Maps a label value to its slot among the wanted labels, or -1.
class LabelSlots {
 public:
  explicit LabelSlots(const std::vector<Label>& values) {
    const auto [lo, hi] = std::minmax_element(values.begin(), values.end());
    if (static_cast<int64_t>(*hi) - *lo < (int64_t{1} << 20)) {
      offset_ = *lo;
      dense_.assign(static_cast<size_t>(static_cast<int64_t>(*hi) - *lo + 1), -1);
      for (size_t s = 0; s < values.size(); ++s) dense_[static_cast<size_t>(values[s] - offset_)] = static_cast<int>(s);
    } else {
      for (size_t s = 0; s < values.size(); ++s) sparse_[values[s]] = static_cast<int>(s);
    }
  }
  int operator()(Label value) const {
    if (!dense_.empty()) {
      const int64_t at = static_cast<int64_t>(value) - offset_;
      return at >= 0 && at < static_cast<int64_t>(dense_.size()) ? dense_[static_cast<size_t>(at)] : -1;
    }
    const auto it = sparse_.find(value);
    return it == sparse_.end() ? -1 : it->second;
  }

 private:
  Label offset_ = 0;
  std::vector<int> dense_;
  std::unordered_map<Label, int> sparse_;
};

std::vector<IndexBox> label_boxes(const LabelVolume& labels, const std::vector<Label>& values) {
  const LabelSlots slot(values);
  const Index3 size = labels.size();
  std::vector<IndexBox> boxes(values.size());
  std::mutex mutex;
  parallel_for(0, size[2], 1, [&](int64_t k_begin, int64_t k_end) {
    std::vector<IndexBox> local(values.size());
    for (int64_t k = k_begin; k < k_end; ++k) {
      for (int64_t j = 0; j < size[1]; ++j) {
        const Label* row = labels.data() + labels.geometry().offset(0, j, k);
        for (int64_t i = 0; i < size[0]; ++i) {
          const int s = slot(row[i]);
          if (s >= 0) local[static_cast<size_t>(s)].add(i, j, k);
        }
      }
    }
    std::lock_guard<std::mutex> lock(mutex);
    for (size_t s = 0; s < boxes.size(); ++s) boxes[s].add(local[s]);
  });
  return boxes;
}

// Reports a VTK filter's progress as a slice [base, base + span] of the stage, and aborts it on cancellation.
struct FilterProgress {
  StageProgress* progress = nullptr;
  double base = 0.0;
  double span = 0.0;
};

void on_vtk_progress(vtkObject* caller, unsigned long, void* client, void* call_data) {
  auto* state = static_cast<FilterProgress*>(client);
  const double fraction = call_data ? *static_cast<double*>(call_data) : 0.0;
  state->progress->update(state->base + state->span * fraction);
  if (state->progress->cancel_requested()) {
    if (auto* algorithm = vtkAlgorithm::SafeDownCast(caller)) algorithm->SetAbortExecute(1);
  }
}

// Removes vertices no triangle uses.
void drop_unused_vertices(SurfaceMesh& mesh) {
  std::vector<int> remap(static_cast<size_t>(mesh.vertices.rows()), -1);
  for (Eigen::Index f = 0; f < mesh.triangles.rows(); ++f) {
    for (int c = 0; c < 3; ++c) remap[static_cast<size_t>(mesh.triangles(f, c))] = 0;
  }
  int used = 0;
  for (int& r : remap) {
    if (r == 0) r = used++;
  }
  if (used == mesh.vertices.rows()) return;
  Eigen::MatrixXd vertices(used, 3);
  for (Eigen::Index v = 0; v < mesh.vertices.rows(); ++v) {
    if (remap[static_cast<size_t>(v)] >= 0) vertices.row(remap[static_cast<size_t>(v)]) = mesh.vertices.row(v);
  }
  for (Eigen::Index f = 0; f < mesh.triangles.rows(); ++f) {
    for (int c = 0; c < 3; ++c) mesh.triangles(f, c) = remap[static_cast<size_t>(mesh.triangles(f, c))];
  }
  mesh.vertices = std::move(vertices);
}

// Six times the signed volume enclosed by the triangles: positive when they face outward.
double signed_volume6(const SurfaceMesh& mesh) {
  double sum = 0.0;
  for (Eigen::Index f = 0; f < mesh.triangles.rows(); ++f) {
    const Eigen::Vector3d a = mesh.vertices.row(mesh.triangles(f, 0)).transpose();
    const Eigen::Vector3d b = mesh.vertices.row(mesh.triangles(f, 1)).transpose();
    const Eigen::Vector3d c = mesh.vertices.row(mesh.triangles(f, 2)).transpose();
    sum += a.dot(b.cross(c));
  }
  return sum;
}

// The surface of one label, in physical mm. `box` is the label's voxel box.
Result<SurfaceMesh> extract_one(const LabelVolume& labels, Label value, const std::string& name, const IndexBox& box,
                                const SurfaceParams& params, StageProgress& progress, double base, double span) {
  const ImageGeometry& g = labels.geometry();
  // The crop reaches one voxel past the label on every side, so that the surface closes where the label touches
  // the edge of the volume.
  Index3 first{}, size{};
  for (int a = 0; a < 3; ++a) {
    first[a] = box.lo[a] - 1;
    size[a] = box.hi[a] - box.lo[a] + 3;
  }
  vtkNew<vtkImageData> mask;
  mask->SetDimensions(static_cast<int>(size[0]), static_cast<int>(size[1]), static_cast<int>(size[2]));
  // VTK works in scaled index space, spacing * index, so that smoothing and decimation see millimetres.
  mask->SetSpacing(g.spacing[0], g.spacing[1], g.spacing[2]);
  mask->SetOrigin(g.spacing[0] * static_cast<double>(first[0]), g.spacing[1] * static_cast<double>(first[1]),
                  g.spacing[2] * static_cast<double>(first[2]));
  mask->AllocateScalars(VTK_UNSIGNED_CHAR, 1);
  auto* voxels = static_cast<unsigned char*>(mask->GetScalarPointer());
  parallel_for(0, size[2], 1, [&](int64_t k_begin, int64_t k_end) {
    for (int64_t k = k_begin; k < k_end; ++k) {
      for (int64_t j = 0; j < size[1]; ++j) {
        unsigned char* row = voxels + size[0] * (j + size[1] * k);
        for (int64_t i = 0; i < size[0]; ++i) {
          const int64_t x = first[0] + i, y = first[1] + j, z = first[2] + k;
          row[i] = labels.contains(x, y, z) && labels.at(x, y, z) == value ? 1 : 0;
        }
      }
    }
  });

  const bool smooth = params.smoothing_iterations > 0;
  const bool decimate = params.decimation > 0.0;
  const int phases = 1 + (smooth ? 1 : 0) + (decimate ? 1 : 0);
  std::vector<FilterProgress> states;
  states.reserve(3);
  std::vector<vtkSmartPointer<vtkCallbackCommand>> observers;
  auto watch = [&](vtkAlgorithm* algorithm) {
    const double phase = static_cast<double>(states.size());
    states.push_back({&progress, base + span * phase / phases, span / phases});
    auto observer = vtkSmartPointer<vtkCallbackCommand>::New();
    observer->SetCallback(on_vtk_progress);
    observer->SetClientData(&states.back());
    algorithm->AddObserver(vtkCommand::ProgressEvent, observer);
    observers.push_back(observer);
  };

  vtkNew<vtkDiscreteFlyingEdges3D> contour;
  contour->SetInputData(mask);
  contour->SetValue(0, 1.0);
  contour->ComputeNormalsOff();
  contour->ComputeGradientsOff();
  contour->ComputeScalarsOff();
  watch(contour);
  vtkAlgorithm* last = contour;
  vtkNew<vtkWindowedSincPolyDataFilter> smoother;
  if (smooth) {
    smoother->SetInputConnection(last->GetOutputPort());
    smoother->SetNumberOfIterations(params.smoothing_iterations);
    smoother->SetPassBand(params.pass_band);
    smoother->NormalizeCoordinatesOn();
    smoother->BoundarySmoothingOff();
    smoother->FeatureEdgeSmoothingOff();
    smoother->NonManifoldSmoothingOn();
    watch(smoother);
    last = smoother;
  }
  vtkNew<vtkQuadricDecimation> decimator;
  if (decimate) {
    decimator->SetInputConnection(last->GetOutputPort());
    decimator->SetTargetReduction(params.decimation);
    decimator->VolumePreservationOn();
    watch(decimator);
    last = decimator;
  }
  detail::clear_vtk_messages();
  last->Update();
  POSEWARP_RETURN_IF_ERROR(progress.check_cancel());
  if (const std::string errors = detail::vtk_errors(); !errors.empty()) {
    return internal_error("VTK failed on the surface of label " + std::to_string(value) + " ('" + name +
                          "'): " + errors);
  }
  Result<SurfaceMesh> extracted = detail::from_polydata(vtkPolyData::SafeDownCast(last->GetOutputDataObject(0)));
  if (!extracted.ok())
    return internal_error("VTK gave a broken surface for label " + std::to_string(value) + ": " +
                          extracted.status().message());
  SurfaceMesh mesh = std::move(extracted).value();
  drop_unused_vertices(mesh);
  mesh.name = name;
  mesh.label = value;

  // Scaled index space -> physical: physical = origin + direction * (spacing * index).
  Eigen::Matrix3d direction;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) direction(r, c) = g.direction[static_cast<size_t>(3 * r + c)];
  }
  const Eigen::RowVector3d origin(g.origin[0], g.origin[1], g.origin[2]);
  mesh.vertices = (mesh.vertices * direction.transpose()).rowwise() + origin;
  // Flying edges orients every triangle the same way relative to the label, and smoothing and decimation keep
  // that; a mirroring direction matrix may flip it. The material enclosed must come out positive.
  if (signed_volume6(mesh) < 0.0) mesh.triangles.col(1).swap(mesh.triangles.col(2));
  return mesh;
}

}  // namespace

Status validate(const SurfaceParams& params) {
  if (params.smoothing_iterations < 0 || params.smoothing_iterations > 1000) {
    return invalid_argument_error("surface smoothing_iterations must lie in [0, 1000] (0 = no smoothing), got " +
                                  std::to_string(params.smoothing_iterations));
  }
  if (!(params.pass_band > 0.0 && params.pass_band <= 2.0)) {
    return invalid_argument_error("surface pass_band must lie in (0, 2] (smaller smooths more; 0.1 is usual), got " +
                                  std::to_string(params.pass_band));
  }
  if (!(params.decimation >= 0.0 && params.decimation < 1.0)) {
    return invalid_argument_error(
        "surface decimation is the fraction of triangles removed and must lie in [0, 1), got " +
        std::to_string(params.decimation));
  }
  return ok_status();
}

static Result<std::vector<SurfaceMesh>> extract_label_surfaces_unguarded(const LabelVolume& labels,
                                                        const std::vector<std::pair<Label, std::string>>& wanted,
                                                        const SurfaceParams& params, const ProgressHooks& hooks) {
  POSEWARP_RETURN_IF_ERROR(validate(params));
  std::vector<SurfaceMesh> surfaces;
  if (labels.empty() || wanted.empty()) return surfaces;
  POSEWARP_RETURN_IF_ERROR(labels.geometry().validate().with_context("cannot extract surfaces"));
  for (int a = 0; a < 3; ++a) {
    if (labels.size()[a] + 2 > std::numeric_limits<int>::max()) {
      return invalid_argument_error("the label volume is too large for surface extraction (" +
                                    labels.geometry().describe() + ")");
    }
  }
  detail::install_quiet_vtk_output();
  StageProgress progress(hooks, "surfaces");
  const Status extracted = guarded("extracting label surfaces from " + labels.geometry().describe(),
                                   "ask for fewer labels or decimate more", [&]() -> Status {
    std::vector<Label> values;
    std::vector<std::string> names;
    for (const auto& [value, name] : wanted) {
      if (std::find(values.begin(), values.end(), value) != values.end()) continue;
      values.push_back(value);
      names.push_back(name);
    }
    const std::vector<IndexBox> boxes = label_boxes(labels, values);
    POSEWARP_RETURN_IF_ERROR(progress.check_cancel());
    // Progress in proportion to the crop each label needs.
    std::vector<double> work(values.size(), 0.0);
    double total = 0.0;
    for (size_t s = 0; s < values.size(); ++s) {
      if (boxes[s].empty()) continue;
      work[s] = 1.0;
      for (int a = 0; a < 3; ++a) work[s] *= static_cast<double>(boxes[s].hi[a] - boxes[s].lo[a] + 3);
      total += work[s];
    }
    double done = 0.0;
    for (size_t s = 0; s < values.size(); ++s) {
      if (boxes[s].empty()) continue;
      POSEWARP_ASSIGN_OR_RETURN(SurfaceMesh mesh, extract_one(labels, values[s], names[s], boxes[s], params, progress,
                                                              done / total, work[s] / total));
      done += work[s];
      if (mesh.triangles.rows() > 0) surfaces.push_back(std::move(mesh));
    }
    return ok_status();
  });
  if (!extracted.ok()) return extracted;
  progress.finish();
  return surfaces;
}

Result<std::vector<SurfaceMesh>> extract_label_surfaces(const LabelVolume& labels,
                                                        const std::vector<std::pair<Label, std::string>>& wanted,
                                                        const SurfaceParams& params, const ProgressHooks& hooks) {
  return guarded("extracting label surfaces", [&] {
    return extract_label_surfaces_unguarded(labels, wanted, params, hooks);
  });
}

}  // namespace posewarp::surface
