// Per-tet affine maps rest -> posed: A_t = E_posed E_rest^-1 with E the 3x3 edge matrix [v1-v0, v2-v0, v3-v0].
#pragma once

#include <Eigen/Core>

#include <vector>

#include "posewarp/common/tet_mesh.h"

namespace posewarp::skinning {

// Inverse rest edge matrices, computed once per rig. rest_inverse is #T x 9 (row-major 3x3 per tet).
struct RestTetFrames {
  Eigen::Matrix<double, Eigen::Dynamic, 9, Eigen::RowMajor> rest_inverse;
  Eigen::VectorXd rest_volume;  // #T, mm^3
};

RestTetFrames rest_tet_frames(const TetMesh& rest);

// det(A_t) per tet for a posed vertex set (#V x 3): 1 keeps volume, <= 0 is an inverted tet.
Eigen::VectorXd tet_determinants(const TetMesh& rest, const RestTetFrames& frames, const Eigen::MatrixXd& posed);

}  // namespace posewarp::skinning
