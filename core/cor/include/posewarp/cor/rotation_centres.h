// Optimized centres of rotation of tet-mesh vertices (Le & Hodgins 2016, adapted to tets by Sujar et al. 2018).
#pragma once

#include <cstdint>

#include "posewarp/common/progress.h"
#include "posewarp/common/result.h"
#include "posewarp/common/rig_params.h"
#include "posewarp/common/status.h"
#include "posewarp/common/tet_mesh.h"

namespace posewarp::cor {

using posewarp::CorParams;  // posewarp/common/rig_params.h

// OK, or INVALID_ARGUMENT naming the field, its valid range and the default to use.
Status validate(const CorParams& params);

// What rotation_centres did. rigid + centred + unsupported = #V.
struct CorStats {
  int64_t rigid_vertices = 0;        // largest weight >= rigid_threshold, or fewer than two nonzero weights
  int64_t centred_vertices = 0;      // got an optimized centre
  int64_t unsupported_vertices = 0;  // blended, but no tet shares two of its bones: flagged rigid, centre = vertex
  int64_t clusters = 0;              // (bone pair, weight cell) clusters the vertices were evaluated against
  int64_t pair_buckets = 0;          // bone pairs used by at least one blended vertex
  double seconds = 0.0;
};

// Centres of rotation of every vertex, eq. 7 of Sujar et al. 2018:
//   cor_p = sum_t s(w_p, w_t) V_t c_t / sum_t s(w_p, w_t) V_t,
//   s(w_p, w_t) = sum_{i != j} w_pi w_pj w_ti w_tj exp(-(w_pi w_tj - w_ti w_pj)^2 / sigma^2)   (eq. 6, Le & Hodgins)
// with w_t the mean of tet t's four corner weights, V_t its volume (mm^3) and c_t its centroid (mm).
//
// s is a sum over bone pairs, and the (i, j) term depends on the tet only through (w_ti, w_tj). So the tets are
// bucketed by the bone pairs in their support (only pairs some blended vertex uses), and within a bucket
// clustered on a 1/quantization grid in (w_ti, w_tj); a cluster keeps sum V w_ti w_tj, sum V w_ti w_tj c_t and
// its representative (w_ti, w_tj). A vertex visits the clusters of the pairs in its own support only, so each
// tet contributes exactly its eq. 6 value once (one pair term per shared pair), up to the grid's rounding of
// the kernel's argument. Cost: O(#T x pairs per tet + blended #V x pairs per vertex x clusters per pair).
//
//   mesh     #V x 3 vertices (LPS mm), #T x 4 tets
//   weights  #V x k sparse skin weights over weights.segment_count == mesh.segment_count segments
//   hooks    progress (stage "cor") and cancellation, polled per chunk of vertices
//   stats    optional
// Returns #V x 3 centres (LPS mm) and #V rigid flags; rigid vertices get the vertex itself as centre.
// INVALID_ARGUMENT on bad parameters or mismatched inputs, CANCELLED, RESOURCE_EXHAUSTED when out of memory.
Result<RotationCentres> rotation_centres(const TetMesh& mesh, const SkinWeights& weights, const CorParams& params,
                                         const ProgressHooks& hooks, CorStats* stats);

// The same eq. 7 summed over every tet for every blended vertex, O(#V x #T), without clustering. A reference
// for small meshes (tests); same inputs, rigid rules and errors as rotation_centres.
Result<RotationCentres> rotation_centres_brute_force(const TetMesh& mesh, const SkinWeights& weights,
                                                     const CorParams& params);

}  // namespace posewarp::cor
