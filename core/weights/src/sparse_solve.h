// The weights' linear solves of K_ff X = B (internal to weights/): both fill the stats' ordering, factor and solve
// figures and move the progress to `factored_fraction` once factored.
#pragma once

#include <Eigen/Core>
#include <Eigen/SparseCore>

#include <string>

#include "posewarp/common/progress.h"
#include "posewarp/common/status.h"
#include "posewarp/weights/laplace_weights.h"

namespace posewarp::weights::detail {

using SparseMatrix = Eigen::SparseMatrix<double>;

// CHOLMOD supernodal LL^T (METIS ordering from 5000 rows on). OK with *solution filled; CANCELLED; or OK with
// *solution empty and *failure saying why CHOLMOD failed (the caller falls back to solve_simplicial).
Status solve_cholmod(const SparseMatrix& k_ff, const Eigen::MatrixXd& rhs, StageProgress& progress,
                     double factored_fraction, WeightStats* stats, Eigen::MatrixXd* solution, std::string* failure);
// Eigen's SimplicialLDLT with AMD ordering: slower on 3D meshes, but needs nothing outside Eigen.
// FAILED_PRECONDITION when K_ff cannot be factored or the solution is not finite.
Status solve_simplicial(const SparseMatrix& k_ff, const Eigen::MatrixXd& rhs, StageProgress& progress,
                        double factored_fraction, WeightStats* stats, Eigen::MatrixXd* solution);

}  // namespace posewarp::weights::detail
