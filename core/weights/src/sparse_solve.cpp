// The weights' linear solves: CHOLMOD's supernodal LL^T, and Eigen's simplicial LDL^T where CHOLMOD fails.
#include "sparse_solve.h"

#include <Eigen/CholmodSupport>
#include <Eigen/SparseCholesky>

#include <string>
#include <utility>

#include "posewarp/common/stopwatch.h"

namespace posewarp::weights::detail {
namespace {

// Free vertices from which CHOLMOD orders with METIS only (nested dissection), skipping its AMD trial.
constexpr int64_t kMetisOnlyRows = 5000;

const char* cholmod_ordering_name(int ordering) {
  switch (ordering) {
    case CHOLMOD_NATURAL: return "natural";
    case CHOLMOD_GIVEN: return "given";
    case CHOLMOD_AMD: return "amd";
    case CHOLMOD_METIS: return "metis";
    case CHOLMOD_NESDIS: return "nesdis";
    case CHOLMOD_COLAMD: return "colamd";
    case CHOLMOD_POSTORDERED: return "postordered";
    default: return "unknown";
  }
}

}  // namespace

// CHOLMOD supernodal LL^T. OK with *solution filled; CANCELLED; or OK with *solution empty and *failure set.
Status solve_cholmod(const SparseMatrix& k_ff, const Eigen::MatrixXd& rhs, StageProgress& progress,
                     double factored_fraction, WeightStats* stats, Eigen::MatrixXd* solution, std::string* failure) {
  Stopwatch start;
  Eigen::CholmodSupernodalLLT<SparseMatrix, Eigen::Lower> llt;
  cholmod_common& common = llt.cholmod();
  common.print = 0;  // failures are reported through the Status and stats, not on stdout
  if (k_ff.rows() >= kMetisOnlyRows) {
    // Tet meshes fill in badly under AMD (a body mesh of 300k vertices: 2.4 Tflop against METIS's 0.3), and
    // CHOLMOD's default tries AMD first and METIS only past a fill threshold that small meshes miss.
    common.nmethods = 1;
    common.method[0].ordering = CHOLMOD_METIS;
  }
  llt.analyzePattern(k_ff);
  if (common.status == CHOLMOD_NOT_INSTALLED && common.nmethods == 1) {
    // A CHOLMOD built without its Partition module (no METIS): let it choose among what it has.
    common.status = CHOLMOD_OK;
    common.nmethods = 0;
    llt.analyzePattern(k_ff);
  }
  if (common.status < CHOLMOD_OK) {
    *failure = "CHOLMOD analysis failed with status " + std::to_string(common.status);
    return ok_status();
  }
  stats->ordering_seconds = start.seconds();
  POSEWARP_RETURN_IF_ERROR(progress.check_cancel());
  llt.factorize(k_ff);
  if (common.status < CHOLMOD_OK || llt.info() != Eigen::Success) {
    *failure = "CHOLMOD factorization failed with status " + std::to_string(common.status) +
               (llt.info() != Eigen::Success ? " (K_ff not numerically positive definite)" : "");
    return ok_status();
  }
  stats->factor_seconds = start.seconds();
  stats->ordering = cholmod_ordering_name(common.method[common.selected].ordering);
  stats->factor_nonzeros = static_cast<int64_t>(common.lnz);
  stats->factor_flops = common.fl;
  progress.update(factored_fraction);
  POSEWARP_RETURN_IF_ERROR(progress.check_cancel());

  start.restart();
  Eigen::MatrixXd x = llt.solve(rhs);
  if (llt.info() != Eigen::Success || !x.allFinite()) {
    *failure = "CHOLMOD solve failed with status " + std::to_string(common.status);
    return ok_status();
  }
  stats->solve_seconds = start.seconds();
  *solution = std::move(x);
  return ok_status();
}

// Eigen's SimplicialLDLT with AMD ordering: slower on 3D meshes, but needs nothing outside Eigen.
Status solve_simplicial(const SparseMatrix& k_ff, const Eigen::MatrixXd& rhs, StageProgress& progress,
                        double factored_fraction, WeightStats* stats, Eigen::MatrixXd* solution) {
  Stopwatch start;
  Eigen::SimplicialLDLT<SparseMatrix, Eigen::Lower> ldlt;
  ldlt.analyzePattern(k_ff);
  stats->ordering_seconds = start.seconds();
  ldlt.factorize(k_ff);
  if (ldlt.info() != Eigen::Success) {
    return failed_precondition_error(
        "the stiffness matrix of the free vertices could not be factored (not numerically positive definite); "
        "the mesh probably holds near-degenerate tets: re-mesh with sliver exudation on");
  }
  stats->factor_seconds = start.seconds();
  stats->ordering = "amd";
  stats->factor_nonzeros = static_cast<int64_t>(ldlt.matrixL().nestedExpression().nonZeros());
  stats->factor_flops = 0.0;
  progress.update(factored_fraction);
  POSEWARP_RETURN_IF_ERROR(progress.check_cancel());

  start.restart();
  Eigen::MatrixXd x = ldlt.solve(rhs);
  if (ldlt.info() != Eigen::Success || !x.allFinite()) {
    return failed_precondition_error(
        "solving for the weights gave non-finite values; the mesh probably holds near-degenerate tets: re-mesh "
        "with sliver exudation on");
  }
  stats->solve_seconds = start.seconds();
  *solution = std::move(x);
  return ok_status();
}

}  // namespace posewarp::weights::detail
