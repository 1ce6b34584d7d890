// The soft tissue's steady state under the bones' rigid motion: Sujar et al. 2018 section 5 (Fig. 9), where a
// co-rotational FEM of a nearly incompressible, homogeneous, isotropic material with the bone vertices as boundary
// conditions and the element rotations refined iteratively conserves the volume that skinning loses.
//
// Solved here as the same steady state in its projective form (Bouaziz et al. 2014; ARAP with a volume term): per
// tet, the energy V (w_s |F - R|^2 + w_v |F - S|^2) with F the tet's deformation gradient, R its nearest rotation (the
// co-rotated frame) and S its nearest volume-preserving matrix (det S = 1). The local step finds R and S per tet from
// the current positions, the global step solves one sparse system whose matrix (a tet Laplacian on the free
// vertices) does not change between iterations, so it is factored once per pose and each iteration costs two
// triangular solves. The energy never increases; iterations stop when no vertex moves more than the tolerance.
//
// Bone vertices (every vertex of a bone tet) are fixed where skinning puts them (their segment's rigid motion). Only
// the tissue the pose bends is solved: vertices whose influences move differently, and the tissue within a margin
// of them; beyond it every vertex keeps its warm-start (skinned) position, which there is a rigid motion already.
#pragma once

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <memory>
#include <mutex>
#include <vector>

#include "posewarp/common/progress.h"
#include "posewarp/common/result.h"
#include "posewarp/common/tet_mesh.h"
#include "posewarp/skinning/skinning.h"
#include "posewarp/skinning/tet_maps.h"

namespace posewarp::fem {

struct FemParams {
  // w_v / w_s: how much more keeping volume counts than keeping shape; 100 is the nearly incompressible material of
  // the paper (Poisson's ratio close to 0.5), and also what converges fastest on the bar.
  double volume_weight = 100.0;
  // The untangling that ends a pose does the rest. posewarp_fem_probe on four scripts/body_check rigs at knee, elbow,
  // shoulder and hip 90: 20 iterations leave the tissue within 50 and 100 mm as 50 do (within 0.6 point, volume and
  // folded share alike; the knee on one rig 1.4 points further) but for the elbow, which two rigs kept nearer rest
  // (-7.4 / -10.0% with 2.9 / 2.6% folded at 50, -5.0 / -1.6% with 1.6 / 0.8% at 20: later iterations press tissue into
  // folds the untangling cannot turn back), and the solve takes 10-25% less time.
  int max_iterations = 20;
  double tolerance_mm = 0.02;   // converged once no vertex moves more than this in one iteration
  double margin_mm = 40.0;      // reach of the solve beyond the tissue the pose bends (rest mm, along mesh edges)
  // Start from where the last solve on the same free vertices ended (its correction of the skinned positions,
  // carried to this pose's), when a cache holds it: a slider's previews go on converging from call to call. A pose
  // leaves it off, so that its result depends on its request alone.
  bool continue_from_last = false;
  // A preview's latency: no iteration starts that would end past this many seconds of the solve (the preparation of
  // its system counted), going by the mean of its iterations so far; the first always runs. 0: no limit. A pose
  // leaves it 0, so that its result does not depend on the machine's speed.
  double time_budget_seconds = 0.0;
  // Turn back the tets the steady state leaves inverted (where bending folds a band of tissue that has no room):
  // the free vertices around them minimise a foldover-free energy with everything else held. A preview leaves it off.
  bool untangle = true;
  // The weight with which each connected piece of the untangled tissue keeps its volume as a whole while its folds
  // turn back (0: only each tet's own volume term), so that the crease's skin bulges instead of sinking; see
  // internal.h's UntangleParams for how it was measured.
  double untangle_volume_weight = 100.0;
  // Push the skin that bending drives into the tissue facing it (the back of a bent knee into the calf, the forearm
  // into the belly) back out of it. Off by default: it halves to quarters the skin inside tissue on the body phantom
  // and moves the volume figures little, but adds half to the solve's time. A preview leaves it off.
  bool contact = false;
};

// INVALID_ARGUMENT naming the parameter when one is out of range.
Status validate(const FemParams& params);

struct FemStats {
  int64_t free_vertices = 0;   // solved for
  int64_t fixed_vertices = 0;  // bone vertices and the region's border, in the solved tets
  int64_t tets = 0;            // tets in the solve
  int iterations = 0;
  int restarts = 0;            // accelerated steps dropped because they raised the energy
  double last_step_mm = 0.0;   // largest vertex move of the last iteration
  double factor_seconds = 0.0;
  double iterate_seconds = 0.0;
  bool reused_system = false;  // the cache held the factored system for these free vertices
  bool out_of_time = false;    // the time budget ended the iterations before max_iterations or convergence
  bool continued = false;      // started from the last solve's end (continue_from_last)
  // Inverted soft tets (det F <= 0) with a free corner before and after untangling (a tet whose corners are all
  // bone vertices is not in the solve: no solve can turn it back).
  int64_t inverted_before_untangle = 0;
  int64_t inverted = 0;
  bool untangle_undone = false;  // no round of the untangling folded less tissue: the steady state's result stays
  int64_t untangle_vertices = 0;
  int untangle_iterations = 0;
  double untangle_seconds = 0.0;
  // Free skin vertices pressed against the skin facing them when the solve ended (paired with a face from elsewhere
  // and within 0.2 mm of its plane or behind it), and the seconds spent finding which skin was inside which tissue.
  int64_t contacts = 0;
  double contact_seconds = 0.0;
};

// What does not depend on the pose, computed once per rig.
struct Topology {
  std::vector<int64_t> tet_start;    // #V + 1: vertex v's tets are tets[tet_start[v] .. tet_start[v + 1])
  std::vector<int32_t> tets;
  std::vector<int64_t> edge_start;   // #V + 1: vertex v's neighbours along mesh edges
  std::vector<int32_t> edges;
  std::vector<uint8_t> bone;         // #V, 1 for a vertex of a bone tet
  std::vector<uint8_t> skin;         // #V, 1 on the mesh's boundary and on no bone tet (skin_vertices)
  // The boundary faces whose corners are all skin, each ordered so that (b - a) x (c - a) points out of the body.
  std::vector<std::array<int32_t, 3>> skin_faces;
};

// `skin`: skin_vertices(rest) when the caller has it already (else, or when it does not fit the mesh, made here).
Topology topology(const TetMesh& rest, std::vector<uint8_t> skin = {});

struct SolveSystem;  // the solve's packed tets and factored matrix for one set of free vertices

// What a solve prepares for one set of free vertices, kept between solves on one rig: a slider dragging one joint
// frees the same vertices at every angle, so only its first solve factors the system. A solve takes the system
// out while it runs (a factor is not shared between threads) and puts it back after; solves at once on other
// threads prepare their own.
class SolveCache {
 public:
  SolveCache();
  ~SolveCache();
  SolveCache(const SolveCache&) = delete;
  SolveCache& operator=(const SolveCache&) = delete;
  // The kept system when it was prepared for exactly these free vertices (it leaves the cache), else nothing.
  std::unique_ptr<SolveSystem> take(const std::vector<int32_t>& free_vertices);
  void put(std::unique_ptr<SolveSystem> system);

 private:
  std::mutex mutex_;
  std::unique_ptr<SolveSystem> system_;
};

// The pose's inputs: the rig at rest and the skinned (warm-start) positions.
struct SolveInputs {
  const TetMesh& rest;
  const skinning::RestTetFrames& frames;
  const Topology& topology;
  const SkinWeights& weights;
  const skinning::SegmentTransforms& transforms;
  const Eigen::MatrixXd& warm;  // #V x 3, the skinned vertices (CoR)
  SolveCache* cache = nullptr;  // optional: reuse and keep the system (see SolveCache)
};

// The posed vertices (#V x 3). INVALID_ARGUMENT when the inputs do not fit each other; CANCELLED or
// DEADLINE_EXCEEDED through the hooks (checked every iteration); INTERNAL when the system cannot be factored.
Result<Eigen::MatrixXd> solve(const SolveInputs& inputs, const FemParams& params, const ProgressHooks& hooks,
                              FemStats* stats = nullptr);

// The straightforward co-rotational linear FEM of the paper's section 5 (Mueller and Gross 2004), kept to measure
// the projective solve against: per iteration each tet's rotation from the polar decomposition of its deformation
// gradient, then the linear system sum_e R_e K_e (R_e^T x - X) = 0 assembled and factored anew (3 unknowns per free
// vertex), on the same free vertices with the same bones held. K_e is a homogeneous isotropic linear material whose
// Poisson's ratio sets how nearly incompressible it is. Seconds to minutes on a body: a reference, not a method.
struct CorotationalParams {
  double poisson_ratio = 0.45;
  int max_iterations = 100;
  double tolerance_mm = 0.02;
  double margin_mm = 40.0;
};

Status validate(const CorotationalParams& params);

Result<Eigen::MatrixXd> solve_corotational(const SolveInputs& inputs, const CorotationalParams& params,
                                           const ProgressHooks& hooks, FemStats* stats = nullptr);

// The same steady state by projected Newton on the nonlinear energy (each tet's Hessian made definite through its
// eigensystem, Teran et al. 2005 and Smith et al. 2019; a backtracking line search): per tet
// V (|F - R|^2 + w_t (det F - 1)^2) with R F's nearest rotation, plus per free vertex's star (its tets)
// w_n V_s (J_s - 1)^2 with V_s the star's rest volume and J_s its posed volume over it, plus optionally a barrier
// that keeps each tet the warm start has unfolded from folding. A volume term per tet locks a mesh of linear tets (a
// nearly incompressible material cannot bend without compressing the tets along the bend); the star's term, a nodal
// volume (Bonet and Burton 1998), lets the tets of a star trade volume while the star keeps its own, and without the
// barrier they trade it by folding. The matrix is assembled and factored anew at each iteration (the stars couple
// vertices two edges apart; its memory grows with the square of a star's vertices, and with the margin): a second
// an iteration on a body's bent hip, 0.07-0.1 s on the refinement's region with only its compressed stars held
// (region_below, star_below; 2,000-2,400 vertices, 2026-11-29). Measured against the
// projective solve it is a reference (README: fem); after it, with the star's term, the barrier and the region, it
// is the refinement a pose runs (3 iterations unless it asks otherwise: api::FemOptions). It has no
// contact term: skin that --fem-contact kept out of the tissue facing it may pass back in. INVALID_ARGUMENT naming
// a parameter out of range; INTERNAL when the energy is not finite at the start (a tet flat at rest) or the system
// cannot be factored; CANCELLED or DEADLINE_EXCEEDED through the hooks (every iteration, as the stage
// "fem-refine").
struct NonlinearParams {
  double tet_volume_weight = 1.0;     // w_t, 0 to 1e6
  double star_volume_weight = 100.0;  // w_n, 0 to 1e6 (0: per-tet volume only)
  // kappa, 0 to 1e6 (0: none): the barrier kappa (J - J0)^2 (-log(J / J0)) below J0 = barrier_from on every tet with
  // det F above 0 at the warm start, which then never folds.
  double barrier_weight = 0.0;
  // J0, in (0, 1]. 0.7 so that the Newton step sees the barrier's curvature before a tet's det nears 0 (from 0.3,
  // every cut of the line search on the body phantom's hip was a tet the step carried from above 0.3 past 0), and
  // tissue pressed below 0.7 of its volume, which a nearly incompressible material does not reach, is pushed back.
  // posewarp_fem_probe, hip 90 on out/bc9, the refinement's region as it was then (3 edges, every star held),
  // within 50 mm: from 0.3 -4.5% after 10
  // iterations; 0.5 -5.0% after 5, -3.1% after 10; 0.7 -3.9% after 5, -2.6% after 10; folded 0.9% in each.
  double barrier_from = 0.7;
  bool untangle = false;       // then the projective solve's untangling (FemParams::untangle)
  int max_iterations = 30;     // Newton iterations, 1 to 10000
  double tolerance_mm = 0.02;  // converged once the Newton step moves no vertex more (the line search may take less)
  double margin_mm = 40.0;     // reach of the solve beyond the tissue the pose bends (rest mm, along mesh edges)
  // Only the free vertices within `region_rings` edges (0 to 100) of a vertex whose star's volume is below
  // `region_below` (0 to 1; 0: every free vertex) of its rest volume at the warm start, the rest held there: the
  // refinement works where the solve left tissue compressed: two edges around it, a fifth of the bent tissue at a hip.
  double region_below = 0.0;
  int region_rings = 3;
  // The star term only on the stars whose volume at the warm start is below this fraction (0 to 10) of their rest
  // volume; 0: on every star. At 1 the term gives the tissue the solve compressed its volume back and leaves the
  // tissue it did not to the tets' terms, with a sparser matrix (the stars couple vertices two edges apart).
  double star_below = 0.0;
};

Status validate(const NonlinearParams& params);

Result<Eigen::MatrixXd> solve_nonlinear(const SolveInputs& inputs, const NonlinearParams& params,
                                        const ProgressHooks& hooks, FemStats* stats = nullptr);

// Per vertex: 1 on the mesh's boundary (its tets do not surround it) and on no bone tet: the skin. Vertices at the
// same rest position (the two sides of a joint's gap, cut_joint_gaps) count their tets together: a cut is not skin.
std::vector<uint8_t> skin_vertices(const TetMesh& rest);

// Cuts each joint's gap along its middle so that its two sides slide past each other instead of shearing the tissue
// between them. Where two bones come within a tet or two of each other (an articular space), the soft tets there
// have bone corners on one bone or the other: such a tet is on that bone's side (the bone most of its bone corners
// are on). A vertex shared by tets of two sides gets a copy per side other than its own, at the same rest position
// and with the same weights and centre (every skinning method moves the copies with it; only a solve can part them):
// a bone vertex's own side is its bone's; a soft vertex is cut only where every tet around it has a side and it is
// not on the skin, so tissue open to the rest of the body stays whole. Without the cut a bent joint slides one bone
// surface past the other by up to the joint's radius times its angle (38 mm at a hip bent 90 degrees), which folds
// every tet spanning the gap whatever the solve does. Returns the number of vertices added (0 when the arrays do not
// fit the mesh); a mesh already cut gets none.
int64_t cut_joint_gaps(TetMesh& mesh, SkinWeights& weights, RotationCentres& centres);

// Skin vertices (`skin`, from skin_vertices) of the posed mesh that lie inside tissue or bone from elsewhere in the
// body (no corner of the tet they are in lies within `rest_distance_mm` of them at rest), among those within each
// radius of `centre` at rest: a crease where one part of the body passed into the part facing it instead of
// pressing against it. Counted for any method's posed vertices (the quality report's figure), one entry per radius;
// nothing is counted when the inputs do not fit the mesh.
struct Penetration {
  int64_t skin_vertices = 0;    // looked at
  int64_t inside_tissue = 0;    // inside a soft tet from elsewhere
  int64_t inside_bone = 0;      // inside a bone tet from elsewhere
};
std::vector<Penetration> penetration(const TetMesh& rest, const Eigen::MatrixXd& posed, const std::vector<uint8_t>& skin,
                                     const Eigen::Vector3d& centre, const std::vector<double>& radii_mm,
                                     double rest_distance_mm = 15.0);
// The same about several centres (a pose's moved joints) in one pass over the tets: per centre, per radius.
std::vector<std::vector<Penetration>> penetration(const TetMesh& rest, const Eigen::MatrixXd& posed,
                                                  const std::vector<uint8_t>& skin,
                                                  const std::vector<Eigen::Vector3d>& centres,
                                                  const std::vector<double>& radii_mm, double rest_distance_mm = 15.0);

}  // namespace posewarp::fem
