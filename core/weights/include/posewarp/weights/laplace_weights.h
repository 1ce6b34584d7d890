// Laplace skinning weights: harmonic functions on the tet mesh with the bones as Dirichlet boundary.
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <string>

#include "posewarp/common/progress.h"
#include "posewarp/common/result.h"
#include "posewarp/common/rig_params.h"
#include "posewarp/common/status.h"
#include "posewarp/common/tet_mesh.h"

namespace posewarp::weights {

using posewarp::IslandPolicy;  // posewarp/common/rig_params.h
using posewarp::WeightsParams;

// OK, or INVALID_ARGUMENT naming the field, its valid range and its default.
Status validate(const WeightsParams& params);

// What laplace_weights did. Raw weights are the solution of the linear system, before clamping.
struct WeightStats {
  int64_t free_vertices = 0;             // unknowns of the solve
  int64_t fixed_vertices = 0;            // vertices of bone tets (Dirichlet boundary)
  int segments = 0;                      // mesh.segment_count, the columns of the right-hand side
  double min_raw_weight = 0.0;           // smallest raw weight; below 0 where linear FEM broke the maximum principle
  double max_raw_weight = 0.0;           // largest raw weight; above 1 likewise
  double max_partition_error_raw = 0.0;  // max over vertices of |sum_j w_j - 1| of the raw weights
  // max over vertices of |sum_j w_j - 1| after clamping, pruning, top-k and renormalizing, on the double values
  // before they are stored as float (<= 1e-9 or the stage has a bug)
  double max_partition_error = 0.0;
  double max_partition_error_float = 0.0;  // the same on the stored float weights, summed in double (~1e-7)
  // max over free rows i and segments k of |(K_ff W_f + K_fb W_b)_ik| / max_i sum_j |K_ij|: the solve's relative
  // residual before clamping and sparsification
  double max_laplace_residual = 0.0;
  int islands_attached = 0;            // pieces without bone that were attached to their nearest segment
  int64_t island_vertices = 0;         // vertices in those pieces (vertices in no tet count as one-vertex pieces)
  int64_t multi_segment_vertices = 0;  // vertices of bone tets of two or more segments, given one owner
  std::string solver;                  // "cholmod-supernodal-llt" or "simplicial-ldlt"
  std::string cholmod_failure;         // why CHOLMOD was not used although preferred; empty otherwise
  std::string ordering;                // fill-reducing ordering CHOLMOD chose ("amd", "metis", "nesdis", ...), or "amd"
  int64_t factor_nonzeros = 0;         // entries of the Cholesky factor L
  double factor_flops = 0.0;           // floating-point operations of the factorization (CHOLMOD only; 0 otherwise)
  double assemble_seconds = 0.0;       // checks, ownership, components, K, K_ff and right-hand side
  double factor_seconds = 0.0;         // ordering and numeric factorization of K_ff
  double ordering_seconds = 0.0;       // the part of factor_seconds spent choosing the ordering (symbolic analysis)
  double solve_seconds = 0.0;          // triangular solves for all segments at once
  double finish_seconds = 0.0;         // residual, clamping, top-k
};

// Laplace (harmonic) skinning weights, Sujar et al. 2018 section 3.3 (after Baran & Popovic 2007 and Jacobson's
// bounded biharmonic weights without the bounds): the vertices of tets of bone segment k are fixed to w_k = 1,
// w_j = 0 for j != k; every other vertex solves K_ff W_f = -K_fb W_b, K = fem_laplacian(mesh), for all segments at
// once (one factorization, one right-hand side column per segment). A vertex touched by bone tets of several
// segments belongs to the segment with the most incident bone tets (ties: lowest segment index). Linear FEM
// breaks the discrete maximum principle on obtuse tets, so raw weights are clamped to [0, 1], renormalized, pruned,
// cut to the largest max_influences and renormalized again; the worst deviations are reported in stats.
//
//   mesh    #V x 3 vertices (LPS mm), #T x 4 positively oriented tets, #T classes (1 soft tissue, 2 + k bone k),
//           segment_count >= 1
//   params  checked with validate()
//   hooks   progress (stage "weights") and cancellation, checked between assembly, factorization and solve
//   stats   optional
// Returns #V x influences segments and weights, each row descending and summing to 1.
// INVALID_ARGUMENT on bad parameters or a malformed mesh (shapes, indices, classes, inverted or flat tets);
// FAILED_PRECONDITION when no tet is bone, or (kFail) when a piece of the mesh holds no bone; CANCELLED;
// RESOURCE_EXHAUSTED when out of memory.
Result<SkinWeights> laplace_weights(const TetMesh& mesh, const WeightsParams& params, const ProgressHooks& hooks,
                                    WeightStats* stats);

// The same solve, returned dense and raw: #V x segment_count weights before clamping, pruning and top-k (bone and
// island vertices one-hot). For tests and analysis; #V x segment_count doubles can be large on a body mesh.
// max_influences and prune_below are validated but not used; the stats about them stay 0.
Result<Eigen::MatrixXd> laplace_weights_dense(const TetMesh& mesh, const WeightsParams& params,
                                              const ProgressHooks& hooks, WeightStats* stats);

}  // namespace posewarp::weights
