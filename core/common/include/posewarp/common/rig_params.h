// The knobs of a rig build, one struct per stage (each stage validates its own): the body mask (labels/), the
// skeleton and skin contacts (rig/), the mesher (mesh/), the weights (weights/), the centres of rotation (cor/) and
// the surfaces (surface/). Vocabulary, so the api's BuildParams can hold them without including a stage.
#pragma once

#include <array>
#include <cstdint>
#include <vector>

namespace posewarp {

// Body mask (labels::body_mask).
struct BodyMaskParams {
  // Join a CT threshold mask to the labelled voxels when a CT is given (segmentations rarely label skin and fat).
  bool use_ct = true;
  float ct_threshold_hu = -500.0f;  // voxels above this are body candidates
  // Keep only the largest 6-connected component of the CT mask (drops the table, blankets, cables).
  bool keep_largest_component = true;
  // Fill enclosed holes slice by slice along the grid axis closest to superior-inferior (bowel gas, airways).
  bool fill_holes = true;
};

// Skeleton (rig::build_skeleton).
// The largest contact distance accepted (SkeletonParams, rig spec): far above any joint space, small enough to keep
// the contact search bounded (it visits a ball of this radius around every surface voxel).
inline constexpr double kMaxContactDistanceMm = 50.0;

struct SkeletonParams {
  // Voxels of two segments closer than this (centre to centre) are in contact; 0 = 3.5 x the largest spacing.
  double contact_distance_mm = 0.0;
  // Sphere and cylinder fits are accepted when rms / radius is below this (after trimming outliers such as the
  // femoral neck or the shaft).
  double sphere_max_relative_rms = 0.15;
  int sphere_min_points = 20;
  // A joint centre further than this from the voxels where its two bones meet (and inside neither) is refused:
  // the contact centroid is used and a note says so. 0 = max(10 mm, 2 x the largest spacing).
  double max_centre_offset_mm = 0.0;
};

// Skin contacts (rig::cut_skin_contacts).
struct SkinContactParams {
  // Cut where two separated regions meet within this depth below the skin, mm; 0 = no cut.
  double depth_mm = 30.0;
};

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
  // Split every edge between two bone segments' vertices at its midpoint (mesh::split_bone_gaps): the tissue in the
  // gap between two bones gets vertices that a solve can move, where otherwise bones hold every corner of its tets.
  bool split_bone_gaps = true;
  // Cut each joint's gap along its middle once weights and centres are made (fem::cut_joint_gaps): its two sides
  // then slide past each other in the fem method instead of folding the tissue between them. The other methods move
  // both sides alike, so their results do not change.
  bool slide_joint_gaps = true;
  // The joint centres (LPS mm) the rig build fills from its skeleton (every joint not declared a plane joint, such
  // as the spine's) when joint_cell_size_mm is set: derived from the labels, so not part of the parameters' JSON.
  std::vector<std::array<double, 3>> joint_centres_lps;
};

// What to do with a connected piece of the mesh that holds no bone vertex: the Laplace problem has no boundary
// condition there (K_ff is singular on it).
enum class IslandPolicy {
  kAttachNearest,  // every vertex of the piece follows, with weight 1, the segment of the nearest bone vertex
  kFail,           // FAILED_PRECONDITION naming the piece
};

// Knobs of the weight computation. Weights are unitless.
struct WeightsParams {
  // Segments kept per vertex (the largest weights), 1..8. Default 4; SkinWeights::influences is
  // min(max_influences, segment_count).
  int max_influences = 4;
  // Weights below this, after clamping to [0, 1] and renormalizing, are dropped before the top-k selection, so a
  // bone that only reaches a vertex through a long narrow passage (weight 1e-8, and rounding noise) does not take
  // a slot. In [0, 0.01]; default 1e-6; 0 keeps every positive weight.
  double prune_below = 1e-6;
  // Default kAttachNearest.
  IslandPolicy islands = IslandPolicy::kAttachNearest;
  // Default true: CHOLMOD's supernodal LL^T (BLAS-3; METIS ordering from 5000 free vertices on, CHOLMOD's own
  // choice below). Its speed is the BLAS's: link an optimized one (OpenBLAS) in production. Falls back to Eigen's
  // SimplicialLDLT (AMD ordering; minutes on a 200k-vertex mesh) when false or when CHOLMOD fails.
  bool prefer_cholmod = true;
};

// Knobs of the centre computation. Weights are unitless, in [0, 1].
struct CorParams {
  // Width of the similarity kernel of eq. 6, exp(-(w_pi w_tj - w_ti w_pj)^2 / sigma^2). Sujar et al. use a value
  // below 0.1; smaller values make the centre depend only on tets with nearly the same weight ratios.
  double sigma = 0.1;
  // A vertex whose largest weight is at least this follows one segment rigidly and gets no centre.
  double rigid_threshold = 0.999;
  // Tets are clustered, per pair of bones, on a grid of 1 / quantization in that pair's two weights. Larger is
  // slower and closer to the brute-force sum: on the unit-test bars 64 stays within 0.06% of the bounding-box
  // diagonal of it (32 within 0.12%, about 2.5x faster).
  int quantization = 64;
};

// Surfaces (surface::extract_label_surfaces).
struct SurfaceParams {
  int smoothing_iterations = 20;  // windowed-sinc smoothing passes (vtkWindowedSincPolyDataFilter), 0 = none
  double pass_band = 0.1;         // windowed-sinc pass band in (0, 2]; smaller smooths more
  double decimation = 0.5;        // fraction of triangles removed by quadric decimation, in [0, 1); 0 = none
};

}  // namespace posewarp
