// Pieces the CGAL translation units share that do not need CGAL: the mesher input, the bone distance map and the
// conversion of raw arrays into a positively oriented TetMesh.
#pragma once

#include <array>
#include <atomic>
#include <vector>

#include "posewarp/common/progress.h"
#include "posewarp/mesh/mesher.h"

namespace posewarp::mesh::detail {

// Approximate Euclidean distance (mm) from every mesher voxel to the nearest bone voxel (chamfer transform).
class GridDistance {
 public:
  explicit GridDistance(const LabelVolume& classes);
  // Distance at a point given in grid mm (index * spacing).
  double at_grid_mm(double x, double y, double z) const;

 private:
  ImageGeometry geometry_;
  std::vector<float> distance_;
};

struct MesherInput {
  LabelVolume classes;  // possibly downsampled
  int segment_count = 0;
  GridDistance bone_distance;
};

// Orients every tet positively (swapping two corners where needed) and packs the arrays into a TetMesh.
Result<TetMesh> assemble_mesh(const std::vector<std::array<double, 3>>& points, std::vector<std::array<int, 4>>& tets,
                              const std::vector<int>& tet_class, int segment_count);

// Both stop refining when `stop` is set (DEADLINE_EXCEEDED, or CANCELLED when the hooks asked for it).
Result<TetMesh> run_cgal_sequential(const MesherInput& input, const MeshParams& params, StageProgress& progress,
                                    std::atomic<bool>& stop);
Result<TetMesh> run_cgal_parallel(const MesherInput& input, const MeshParams& params, StageProgress& progress,
                                  std::atomic<bool>& stop);

}  // namespace posewarp::mesh::detail
