// Inverse rest edge matrices and per-tet determinants of the rest -> posed affine maps.
#include "posewarp/skinning/tet_maps.h"

#include <Eigen/Dense>

#include "posewarp/common/parallel.h"

namespace posewarp::skinning {

namespace {
Eigen::Matrix3d edges(const Eigen::MatrixXd& v, const Eigen::MatrixXi& tets, int64_t t) {
  Eigen::Matrix3d e;
  const Eigen::Vector3d v0 = v.row(tets(t, 0));
  for (int c = 0; c < 3; ++c) e.col(c) = v.row(tets(t, c + 1)).transpose() - v0;
  return e;
}
}  // namespace

RestTetFrames rest_tet_frames(const TetMesh& rest) {
  RestTetFrames frames;
  const int64_t n = rest.tet_count();
  frames.rest_inverse.resize(n, 9);
  frames.rest_volume.resize(n);
  parallel_for(0, n, 4096, [&](int64_t begin, int64_t end) {
    for (int64_t t = begin; t < end; ++t) {
      const Eigen::Matrix3d e = edges(rest.vertices, rest.tets, t);
      const double det = e.determinant();
      frames.rest_volume(t) = det / 6.0;
      const Eigen::Matrix3d inv = std::abs(det) > 0.0 ? Eigen::Matrix3d(e.inverse()) : Eigen::Matrix3d::Zero();
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) frames.rest_inverse(t, 3 * r + c) = inv(r, c);
    }
  });
  return frames;
}

Eigen::VectorXd tet_determinants(const TetMesh& rest, const RestTetFrames& frames, const Eigen::MatrixXd& posed) {
  const int64_t n = rest.tet_count();
  Eigen::VectorXd det(n);
  parallel_for(0, n, 4096, [&](int64_t begin, int64_t end) {
    for (int64_t t = begin; t < end; ++t) {
      const Eigen::Matrix3d e = edges(posed, rest.tets, t);
      Eigen::Matrix3d inv;
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) inv(r, c) = frames.rest_inverse(t, 3 * r + c);
      det(t) = (e * inv).determinant();
    }
  });
  return det;
}

}  // namespace posewarp::skinning
