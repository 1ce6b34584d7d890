// What the fem stage's two solvers share: the inputs' check, the tissue a pose bends, a tet's gradient rows and the
// signed SVD of a 3 x 3 deformation gradient.
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <vector>

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

}  // namespace posewarp::fem::internal
