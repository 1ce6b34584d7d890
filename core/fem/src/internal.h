// What the fem stage's two solvers share: the inputs' check, the tissue a pose bends, a tet's gradient rows and the
// signed SVD of a 3 x 3 deformation gradient.
#pragma once

#include <Eigen/Core>

#include <cstdint>
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
