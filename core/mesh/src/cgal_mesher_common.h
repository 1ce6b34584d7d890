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
  // Distance at a voxel, by its offset in the class volume.
  double at_voxel(int64_t offset) const { return distance_[static_cast<size_t>(offset)]; }

 private:
  ImageGeometry geometry_;
  std::vector<float> distance_;
};

struct MesherInput {
  LabelVolume classes;  // possibly downsampled
  int segment_count = 0;
  GridDistance bone_distance;
  std::vector<std::array<double, 3>> joint_centres_grid;  // MeshParams::joint_centres_lps in grid mm
};

// The largest tet circumradius wanted at a point (grid mm) `bone_mm` from the nearest bone: bone_cell_size_mm at
// bone, growing by size_growth up to soft_cell_size_mm, and near a joint centre at most joint_cell_size_mm (growing
// beyond joint_radius_mm).
double cell_size_at(const MesherInput& input, const MeshParams& params, double x, double y, double z, double bone_mm);

// The number of vertices refinement at these sizes will make, estimated before it starts from the cell size over
// the body. It errs low (0.5-0.8x on the phantoms): it exists to refuse sizes that could never finish (a 0.25 mm
// bone cell in a whole body) before any work, not to predict a mesh; the vertex cap stops the rest.
int64_t estimated_vertex_count(const MesherInput& input, const MeshParams& params);

// Orients every tet positively (swapping two corners where needed) and packs the arrays into a TetMesh.
Result<TetMesh> assemble_mesh(const std::vector<std::array<double, 3>>& points, std::vector<std::array<int, 4>>& tets,
                              const std::vector<int>& tet_class, int segment_count);

// Both stop refining when `stop` is set (DEADLINE_EXCEEDED, or CANCELLED when the hooks asked for it).
Result<TetMesh> run_cgal_sequential(const MesherInput& input, const MeshParams& params, StageProgress& progress,
                                    std::atomic<bool>& stop);
Result<TetMesh> run_cgal_parallel(const MesherInput& input, const MeshParams& params, StageProgress& progress,
                                  std::atomic<bool>& stop);

}  // namespace posewarp::mesh::detail
