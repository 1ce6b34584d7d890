// The linear-FEM Laplacian (stiffness matrix) of a tet mesh, the operator of Sujar et al. 2018 section 3.3.
#pragma once

#include <Eigen/SparseCore>

#include "posewarp/common/tet_mesh.h"

namespace posewarp::weights {

// Stiffness matrix of piecewise-linear FEM on tets (the cotangent Laplacian's 3D analogue):
//   K = sum_t V_t G_t^T G_t,
// G_t the 3 x 4 gradients (1/mm) of tet t's barycentric basis functions and V_t its volume (mm^3), so entries are
// in mm. K is #V x #V, symmetric positive semi-definite, every row sums to zero (constants are harmonic), and its
// columns are sorted and compressed. Rows are assembled independently in parallel, so the result is the same for
// every thread count.
//
//   mesh  #V x 3 vertices (LPS mm), #T x 4 positively oriented tets; tet_class and segment_count are not used
//
// Tets with an out-of-range index or a non-positive or non-finite volume add nothing (laplace_weights rejects such
// meshes before it gets here). Throws std::bad_alloc when out of memory.
Eigen::SparseMatrix<double> fem_laplacian(const TetMesh& mesh);

}  // namespace posewarp::weights
