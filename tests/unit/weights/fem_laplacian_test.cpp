#include "posewarp/weights/fem_laplacian.h"

#include <gtest/gtest.h>

#include <Eigen/Dense>

#include "weights/grid_mesh.h"

namespace posewarp::weights {
namespace {

using testing::grid_mesh;

TetMesh jittered_block() {
  return grid_mesh(
      4, 3, 5, 2.0, [](const Eigen::Vector3d&) { return kSoftTissueClass; }, 1, 0.15, 7);
}

TEST(FemLaplacian, OfOneTetIsItsVolumeTimesTheGradientProducts) {
  TetMesh tet;
  tet.vertices.resize(4, 3);
  tet.vertices << 0, 0, 0, 2, 0, 0, 0, 2, 0, 0, 0, 2;  // mm
  tet.tets.resize(1, 4);
  tet.tets << 0, 1, 2, 3;
  tet.tet_class.setConstant(1, kSoftTissueClass);
  // Volume 8/6 mm^3; gradients (-1,-1,-1)/2, (1,0,0)/2, (0,1,0)/2, (0,0,1)/2 per mm.
  Eigen::Matrix4d expected;
  expected << 3, -1, -1, -1, -1, 1, 0, 0, -1, 0, 1, 0, -1, 0, 0, 1;
  expected *= (8.0 / 6.0) / 4.0;
  const Eigen::MatrixXd k = Eigen::MatrixXd(fem_laplacian(tet));
  EXPECT_LT((k - expected).cwiseAbs().maxCoeff(), 1e-14) << k;
}

TEST(FemLaplacian, RowsSumToZero) {
  const Eigen::SparseMatrix<double> k = fem_laplacian(jittered_block());
  const Eigen::VectorXd row_sums = k * Eigen::VectorXd::Ones(k.cols());
  EXPECT_LT(row_sums.cwiseAbs().maxCoeff(), 1e-12);
}

TEST(FemLaplacian, IsSymmetricAndPositiveSemiDefinite) {
  const Eigen::MatrixXd k = Eigen::MatrixXd(fem_laplacian(jittered_block()));
  EXPECT_EQ((k - k.transpose()).cwiseAbs().maxCoeff(), 0.0);
  const Eigen::SelfAdjointEigenSolver<Eigen::MatrixXd> eigen(k);
  EXPECT_GT(eigen.eigenvalues().minCoeff(), -1e-12);
  // One connected block: exactly one zero eigenvalue (the constants).
  EXPECT_GT(eigen.eigenvalues()[1], 1e-6);
}

TEST(FemLaplacian, GivesTheDirichletEnergyOfALinearFunctionExactly) {
  // f(x) = a . x has |grad f|^2 = |a|^2 everywhere, so f^T K f = |a|^2 * volume, on any mesh.
  const TetMesh mesh = jittered_block();
  const Eigen::Vector3d a(0.3, -1.2, 0.7);
  const Eigen::VectorXd f = mesh.vertices * a;
  double volume = 0.0;
  for (Eigen::Index t = 0; t < mesh.tets.rows(); ++t) {
    Eigen::Matrix3d edges;
    for (int c = 0; c < 3; ++c)
      edges.col(c) = (mesh.vertices.row(mesh.tets(t, c + 1)) - mesh.vertices.row(mesh.tets(t, 0))).transpose();
    volume += edges.determinant() / 6.0;
  }
  const Eigen::SparseMatrix<double> k = fem_laplacian(mesh);
  EXPECT_NEAR(f.dot(k * f), a.squaredNorm() * volume, 1e-10 * volume);
}

TEST(FemLaplacian, SkipsTetsItCannotUse) {
  TetMesh mesh = grid_mesh(
      1, 1, 1, 1.0, [](const Eigen::Vector3d&) { return kSoftTissueClass; }, 1);
  const Eigen::MatrixXd good = Eigen::MatrixXd(fem_laplacian(mesh));
  TetMesh bad = mesh;
  bad.tets.conservativeResize(mesh.tets.rows() + 2, 4);
  bad.tets.row(mesh.tets.rows()) << mesh.tets(0, 0), mesh.tets(0, 2), mesh.tets(0, 1), mesh.tets(0, 3);  // inverted
  bad.tets.row(mesh.tets.rows() + 1) << 0, 1, 2, 99;                                                     // out of range
  EXPECT_EQ((Eigen::MatrixXd(fem_laplacian(bad)) - good).cwiseAbs().maxCoeff(), 0.0);
}

}  // namespace
}  // namespace posewarp::weights
