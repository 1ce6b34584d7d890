// What the fem stage's two solvers share: the inputs' check, the tissue a pose bends, a tet's gradient rows and the
// signed SVD of a 3 x 3 deformation gradient.
#pragma once

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <functional>
#include <utility>
#include <vector>

#include "posewarp/common/progress.h"
#include "posewarp/common/stopwatch.h"
#include "posewarp/fem/soft_tissue.h"

namespace posewarp::fem::internal {

// INVALID_ARGUMENT naming the parameter when an iteration limit, tolerance or margin is out of range.
Status validate_iterations(int max_iterations, double tolerance_mm, double margin_mm);

// INVALID_ARGUMENT when the inputs do not fit the mesh or each other.
Status check_inputs(const SolveInputs& in);

// The vertices a solve moves, ascending: no bone vertex, but every vertex whose influences move it to different
// places and the tissue within `margin_mm` of one along mesh edges (rest mm).
std::vector<int32_t> free_vertices(const SolveInputs& in, double margin_mm);

// Vertex c's gradient row in tet t: F = sum_c x_c g_c^T.
Eigen::Vector3d gradient(const skinning::RestTetFrames& frames, int64_t t, int c);

// F = U diag(sigma) V^T with U and V rotations; sigma's last entry is negative when F is inverted.
void signed_svd(const Eigen::Matrix3d& f, Eigen::Matrix3d& u, Eigen::Vector3d& sigma, Eigen::Matrix3d& v);

using Positions = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;  // one row per solve vertex, mm

// A solve's tets packed with their corners' solve vertices (the free ones, numbered first, then the fixed
// corners), gradient rows and rest volumes, and each free vertex's (tet, corner) pairs.
struct PackedTets {
  const std::vector<std::array<int32_t, 4>>& corners;
  const std::vector<Eigen::Matrix<double, 3, 4>>& gradients;
  const std::vector<double>& volume;
  const std::vector<int64_t>& vertex_start;                     // free count + 1
  const std::vector<std::pair<int32_t, int32_t>>& vertex_tets;  // (tet, corner)
};

// Turns back the inverted soft tets the solve left (fem::FemStats names the figures). The free vertices within
// `rings` edges of an inverted tet's free corner minimise a foldover-free hyperelastic energy with every other vertex
// held, after Garanzha et al. 2021 ("Foldover-free maps in 50 lines of code"): per tet, weighted by rest volume,
//   (1 - theta) |F|^2 / chi(D)^(2/3) + theta ((D - 1)^2 + (D^2 + 1) / chi(D)),   D = det F,
// with chi(D) = (D + sqrt(eps^2 + D^2)) / 2 a regularised det whose eps shrinks as the tets turn back (L-BFGS at each
// eps). The first term keeps shape; the second keeps volume, a barrier where D nears 0 and the square of the change
// elsewhere, so that tissue pressed on one side and stretched on the other keeps its mean volume (the paper's
// (D^2 + 1) / D alone is symmetric in log D and made bent tissue grow). Tets whose corners are all held stay as they
// are. The positions that folded the least tissue are kept; when none folded less than the solve's own, those stay.
// `cancel` is checked every round.
struct UntangleParams {
  int rings = 3;
  double volume_share = 0.9;  // theta: keeping volume counts nine times keeping shape
  int max_iterations = 1000;
};
struct UntangleStats {
  int64_t inverted_before = 0, inverted_after = 0;  // tets with a free corner and det F <= 0
  bool undone = false;                              // no round folded less tissue: the solve's result stays
  int64_t vertices = 0;                             // the untangled region's free vertices
  int iterations = 0;
  double seconds = 0.0;
};
Result<UntangleStats> untangle(const PackedTets& tets, Eigen::Index free_count, Positions& x,
                               const UntangleParams& params, const std::function<Status()>& cancel);

// Both solvers' frame: the parameters and inputs checked, the stats (the caller's, or a local) cleared, the clock
// started and the vertices the solve moves found; none is the warm start itself (the rest pose, or only rigid
// motions), else `steady_state(in, params, free_vertices, progress, stats, clock)` solves.
template <typename Params, typename SteadyState>
Result<Eigen::MatrixXd> run_solve(const SolveInputs& in, const Params& params, const ProgressHooks& hooks,
                                  FemStats* stats, const SteadyState& steady_state) {
  POSEWARP_RETURN_IF_ERROR(validate(params));
  POSEWARP_RETURN_IF_ERROR(check_inputs(in));
  StageProgress progress(hooks, "fem");
  FemStats local_stats;
  FemStats& st = stats ? *stats : local_stats;
  st = FemStats{};
  const Stopwatch start;
  std::vector<int32_t> free = free_vertices(in, params.margin_mm);
  st.free_vertices = static_cast<Eigen::Index>(free.size());
  if (free.empty()) return in.warm;
  return steady_state(in, params, std::move(free), progress, st, start);
}

}  // namespace posewarp::fem::internal
