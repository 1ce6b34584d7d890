// Mesher: labelled image (0 outside, 1 soft tissue, 2 + k bone segment k) -> tetrahedra, behind an interface.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "posewarp/common/progress.h"
#include "posewarp/common/result.h"
#include "posewarp/common/tet_mesh.h"
#include "posewarp/common/volume.h"

namespace posewarp::mesh {

// Knobs of the tetrahedralization (Sujar et al. 2018 section 3.2; CGAL Mesh_3 criteria). Lengths in mm.
struct MeshParams {
  double facet_size_mm = 6.0;          // largest boundary triangle (skin and bone surfaces), circumradius bound
  double facet_distance_mm = 1.5;      // largest distance between a boundary triangle and the label boundary
  double facet_angle_deg = 25.0;       // smallest angle of boundary triangles (<= 30 guarantees termination)
  double bone_cell_size_mm = 6.0;      // largest tet circumradius inside and next to bone
  double soft_cell_size_mm = 14.0;     // largest tet circumradius deep in soft tissue
  double size_growth = 0.5;            // mm of extra cell size per mm of distance from the nearest bone
  double cell_radius_edge_ratio = 3.0; // shape bound of tets
  // Mesher grid voxels at most; a larger class volume is downsampled by an integer factor per axis with a
  // bone-precedence majority vote (a block is bone when at least a quarter of it is bone) so thin bones survive.
  int64_t voxel_budget = 24'000'000;
  bool parallel = true;   // TBB-parallel refinement; false = sequential and reproducible for a given seed
  uint32_t seed = 1;      // random seed of the sequential mode
  bool exude = true;      // sliver exudation after refinement, always sequential (CGAL 5.5's parallel one can hang)
  double exude_time_limit_s = 10.0;
  // The parallel refinement is stopped after this long and the body meshed again sequentially (with a warning in
  // MeshHealth): a build that sometimes never ends is worse than a slow one. 0 = no watchdog.
  double parallel_watchdog_s = 120.0;
  // Refinement stops with RESOURCE_EXHAUSTED at this many vertices (a body at the default sizes has about 100k; each
  // vertex costs CGAL about 1 KB while it refines).
  int64_t max_vertices = 2'000'000;
  // Finer tets around the limbs' joints, where a bent joint folds its tissue in a band one tet thick at the default
  // sizes: within joint_radius_mm of a joint centre at most joint_cell_size_mm, growing by size_growth beyond.
  // 0 = off (the default).
  double joint_cell_size_mm = 0.0;
  double joint_radius_mm = 60.0;
  // The joint centres (LPS mm) the rig build fills from its skeleton (every joint not declared a plane joint, such
  // as the spine's) when joint_cell_size_mm is set: derived from the labels, so not part of the parameters' JSON.
  std::vector<std::array<double, 3>> joint_centres_lps;
};

// INVALID_ARGUMENT naming the field and its valid range.
Status validate(const MeshParams& params);

// What the checks found about a mesh.
struct MeshHealth {
  Index3 downsample_factor{1, 1, 1};
  std::vector<int64_t> tets_per_class;          // index = class (0 unused, 1 soft tissue, 2 + k bone k)
  std::vector<double> voxel_volume_ml;          // per class, from the class volume
  std::vector<double> mesh_volume_ml;           // per class, from the tets
  double max_bone_volume_error = 0.0;           // max over bones of |mesh - voxels| / voxels
  double body_volume_error = 0.0;               // |mesh - voxels| / voxels over the whole body
  int body_components = 0;                      // connected pieces of the mesh (through shared vertices)
  int64_t degenerate_tets = 0;                  // volume quality below 1e-4 (1 = regular tet)
  double min_tet_quality = 1.0;
  std::vector<std::string> lost_segments;       // bone segments without a single tet
  bool sequential_fallback = false;             // the watchdog stopped the parallel mesher
  int64_t estimated_vertices = 0;               // the estimate checked against max_vertices before refining
  std::vector<std::string> warnings;            // what a user should know about how the mesh was made
};

class Mesher {
 public:
  virtual ~Mesher() = default;
  virtual std::string name() const = 0;
  // `classes` holds 0 / 1 / 2 + k; `segment_count` bone segments are expected. The mesh is in physical LPS mm.
  virtual Result<TetMesh> mesh(const LabelVolume& classes, int segment_count, const MeshParams& params,
                               const ProgressHooks& hooks, MeshHealth* health) = 0;
};

// The CGAL Mesh_3 backend (GPL-3.0-or-later).
std::unique_ptr<Mesher> make_cgal_mesher();

// Downsamples a class volume by `factor` per axis with the bone-precedence vote; the grid keeps its physical
// extent (block centres become voxel centres).
LabelVolume downsample_classes(const LabelVolume& classes, const Index3& factor);
// The smallest isotropic-ish integer factor that brings the voxel count within `budget`.
Index3 downsample_factor_for(const ImageGeometry& geometry, int64_t budget);

// Relabels as soft tissue every bone tet that touches a vertex owned by another bone segment (a vertex's owner is
// the segment with most incident tets, ties to the lower index: the rule the weights use). A vertex shared by two
// bones cannot follow both, so without this the tets bridging a thin joint space would tear. Returns the number of
// tets relabelled.
int64_t separate_bone_segments(TetMesh& mesh);

// Checks a finished mesh against its class volume: fills `health` and fails (FAILED_PRECONDITION, naming the
// segments) when a bone segment got no tets, rather than dropping a bone silently.
Status check_mesh_health(const TetMesh& mesh, const LabelVolume& classes, const std::vector<std::string>& segment_names,
                         MeshHealth* health);

}  // namespace posewarp::mesh
