// The hole-free volume warp (Sujar et al. 2018 section 5, Fig. 11): every output voxel inside a posed tet is
// mapped back to rest position through that tet's affine map and sampled there; labels by nearest neighbour
// (never a new value), intensities trilinearly.
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <vector>

#include "posewarp/common/progress.h"
#include "posewarp/common/result.h"
#include "posewarp/common/tet_mesh.h"
#include "posewarp/common/volume.h"

namespace posewarp::resample {

enum class Interpolation { kNearest, kLinear };

enum class GridPolicy {
  kInput,  // the source grid
  kGrow,   // the source grid grown (same spacing and direction) to hold the posed body
  kGiven,  // a grid the caller gives
};

struct ResampleParams {
  // Body voxels just outside the mesh surface (the mesh approximates the skin) take the map of the nearest
  // boundary tet up to this distance, mm; 0 = one and a half voxels of the source grid (the mesher keeps the
  // surface within facet_distance of the label boundary, 1.5 mm by default).
  double shell_mm = 0.0;
  Label label_background = 0;           // label where nothing maps back into the body
  float intensity_background = -1024.f; // intensity where nothing maps back (air in HU)
  int64_t max_output_voxels = int64_t{1} << 29;
  double grow_margin_mm = 10.0;         // extra room around the posed body for kGrow
};

Status validate(const ResampleParams& params);

// The output grid for a policy. posed: #V x 3 posed vertices (LPS mm); given: the grid for kGiven.
// An output grid over max_output_voxels or 65536 voxels along an axis is RESOURCE_EXHAUSTED / INVALID_ARGUMENT.
Result<ImageGeometry> output_geometry(GridPolicy policy, const ImageGeometry& source, const Eigen::MatrixXd& posed,
                                      const ImageGeometry* given, const ResampleParams& params);

// What a rig needs once for every warp: which tets touch the mesh boundary (for the skin shell).
struct RestTopology {
  std::vector<int32_t> boundary_tets;
};
RestTopology rest_topology(const TetMesh& rest);

struct WarpStats {
  int64_t covered_voxels = 0;      // inside a posed tet
  int64_t conflicted_voxels = 0;   // inside posed tets that map back to different places (folds); bones win
  int64_t extrapolated_voxels = 0; // in the skin shell, mapped by the nearest boundary tet
  int64_t background_voxels = 0;   // outside mesh and shell: moved with the background (root) transform
  int64_t degenerate_tets = 0;     // posed tets with no volume, skipped
};

// The map from an output grid back to the source grid for one posed mesh.
class TetWarp {
 public:
  // rest/posed: the rig's tet mesh and its posed vertices (#V x 3). background_*: the rigid transform (rest ->
  // posed) of everything outside the mesh, normally the root segment's. rest_coverage: from coverage() of the
  // identity warp on the source grid; source voxels it marks belong to the meshed body and are never copied by the
  // background transform (so a moved limb leaves no ghost). May be null.
  static Result<TetWarp> build(const TetMesh& rest, const RestTopology& topology, const Eigen::MatrixXd& posed,
                               const ImageGeometry& source, const ImageGeometry& output,
                               const Eigen::Matrix3d& background_rotation, const Eigen::Vector3d& background_translation,
                               const std::vector<uint8_t>* rest_coverage, const ResampleParams& params,
                               const ProgressHooks& hooks);

  const ImageGeometry& output() const { return output_; }
  const WarpStats& stats() const { return stats_; }

  // Labels by nearest neighbour: every output value is a value of the source.
  Result<LabelVolume> warp_labels(const LabelVolume& source) const;
  // Intensities, trilinear or nearest; the result keeps the source's type on disk.
  Result<IntensityVolume> warp_intensities(const IntensityVolume& source, Interpolation interpolation) const;
  // Per output voxel: the covering tet (>= 0), -2 - tet for a skin-shell voxel, -1 for the background.
  const std::vector<int32_t>& owner() const { return owner_; }
  // 1 where the output voxel lies in the mesh or its skin shell.
  std::vector<uint8_t> coverage() const;
  // x_source - x_output in mm for every output voxel (3 floats each, x fastest): the field ITK's
  // DisplacementFieldTransform takes to resample the source onto the output grid.
  std::vector<float> inverse_displacement() const;

 private:
  TetWarp() = default;
  // Source continuous index of output voxel v, or false when it lies outside mesh and shell and must not be copied.
  bool source_index(int64_t v, int64_t i, int64_t j, int64_t k, double s[3]) const;
  // Calls sample(v, s) for every output voxel v that maps to source index s, output slices in parallel.
  template <typename Sample>
  void for_each_mapped_voxel(const Sample& sample) const;

  ImageGeometry source_;
  ImageGeometry output_;
  std::vector<int32_t> owner_;             // per output voxel: tet >= 0, -2 - tet for the shell, -1 background
  std::vector<double> maps_;               // 12 per tet: output index -> source index, s = A u + b
  double background_map_[12] = {};         // the same for the background transform
  const std::vector<uint8_t>* rest_coverage_ = nullptr;
  Label label_background_ = 0;
  float intensity_background_ = 0.0f;
  WarpStats stats_;
};

}  // namespace posewarp::resample
