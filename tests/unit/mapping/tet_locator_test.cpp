#include "posewarp/mapping/tet_locator.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <random>

namespace posewarp::mapping {
namespace {

// A block of n^3 unit cubes, each split into 5 tets (alternating so faces match), scaled to mm.
TetMesh cube_block(int n, double size) {
  TetMesh mesh;
  const int m = n + 1;
  mesh.vertices.resize(m * m * m, 3);
  auto id = [m](int i, int j, int k) { return i + m * (j + m * k); };
  for (int k = 0; k < m; ++k)
    for (int j = 0; j < m; ++j)
      for (int i = 0; i < m; ++i) mesh.vertices.row(id(i, j, k)) << i * size, j * size, k * size;
  std::vector<std::array<int, 4>> tets;
  for (int k = 0; k < n; ++k)
    for (int j = 0; j < n; ++j)
      for (int i = 0; i < n; ++i) {
        const int c[8] = {id(i, j, k),         id(i + 1, j, k),         id(i, j + 1, k),         id(i + 1, j + 1, k),
                          id(i, j, k + 1),     id(i + 1, j, k + 1),     id(i, j + 1, k + 1),     id(i + 1, j + 1, k + 1)};
        if ((i + j + k) % 2 == 0) {
          tets.push_back({c[0], c[1], c[2], c[4]});
          tets.push_back({c[1], c[3], c[2], c[7]});
          tets.push_back({c[1], c[4], c[5], c[7]});
          tets.push_back({c[2], c[4], c[7], c[6]});
          tets.push_back({c[1], c[2], c[4], c[7]});
        } else {
          tets.push_back({c[0], c[1], c[3], c[5]});
          tets.push_back({c[0], c[3], c[2], c[6]});
          tets.push_back({c[0], c[5], c[4], c[6]});
          tets.push_back({c[3], c[5], c[6], c[7]});
          tets.push_back({c[0], c[3], c[6], c[5]});
        }
      }
  mesh.tets.resize(static_cast<Eigen::Index>(tets.size()), 4);
  mesh.tet_class = Eigen::VectorXi::Ones(static_cast<Eigen::Index>(tets.size()));
  for (size_t t = 0; t < tets.size(); ++t) {
    std::array<int, 4> tet = tets[t];
    Eigen::Matrix3d e;
    for (int c = 0; c < 3; ++c) e.col(c) = mesh.vertices.row(tet[c + 1]) - mesh.vertices.row(tet[0]);
    if (e.determinant() < 0) std::swap(tet[2], tet[3]);
    for (int c = 0; c < 4; ++c) mesh.tets(static_cast<Eigen::Index>(t), c) = tet[static_cast<size_t>(c)];
  }
  return mesh;
}

TEST(TetLocator, InsidePointsReproduceTheirRestPositionFromBarycentrics) {
  const TetMesh mesh = cube_block(6, 10.0);
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> inside(0.01, 59.99);
  Eigen::MatrixXd points(500, 3);
  for (int i = 0; i < 500; ++i) points.row(i) << inside(rng), inside(rng), inside(rng);
  Result<Embedding> e = embed_points(mesh, points, {});
  ASSERT_TRUE(e.ok());
  EXPECT_EQ(e->outside_count, 0);
  const Eigen::MatrixXd back = deform_points(*e, mesh, mesh.vertices);
  EXPECT_LT((back - points).cwiseAbs().maxCoeff(), 1e-9);
  for (int i = 0; i < 500; ++i) {
    EXPECT_NEAR(e->barycentric.row(i).sum(), 1.0, 1e-12);
    EXPECT_GE(e->barycentric.row(i).minCoeff(), -1e-9);
  }
}

TEST(TetLocator, OutsidePointsGetTheTrulyNearestTet) {
  const TetMesh mesh = cube_block(4, 10.0);
  Result<TetLocator> locator = TetLocator::build(mesh);
  ASSERT_TRUE(locator.ok());
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> around(-15.0, 55.0);
  for (int trial = 0; trial < 300; ++trial) {
    const Eigen::Vector3d p(around(rng), around(rng), around(rng));
    const TetLocator::Location l = locator->locate(p);
    // Brute force: distance from p to the block (its tets' union) is the distance to the box [0, 40]^3.
    const Eigen::Vector3d clamped = p.cwiseMax(0.0).cwiseMin(40.0);
    ASSERT_GE(l.tet, 0);
    EXPECT_NEAR(l.distance_mm, (p - clamped).norm(), 1e-9) << p.transpose();
    EXPECT_EQ(l.inside, (p - clamped).norm() == 0.0);
    // Extrapolated barycentrics still reproduce the point.
    Eigen::Vector3d q = Eigen::Vector3d::Zero();
    for (int c = 0; c < 4; ++c) q += l.barycentric(c) * mesh.vertices.row(mesh.tets(l.tet, c)).transpose();
    EXPECT_LT((q - p).norm(), 1e-9);
  }
}

TEST(TetLocator, EmbeddedPointsMoveWithARigidlyMovedMesh) {
  const TetMesh mesh = cube_block(3, 10.0);
  Eigen::MatrixXd points(3, 3);
  points << 5, 5, 5, 12, 25, 7, 29, 1, 16;
  Result<Embedding> e = embed_points(mesh, points, {});
  ASSERT_TRUE(e.ok());
  const Eigen::Matrix3d r = Eigen::AngleAxisd(0.8, Eigen::Vector3d(1, 1, 0).normalized()).toRotationMatrix();
  const Eigen::MatrixXd posed = (mesh.vertices * r.transpose()).rowwise() + Eigen::RowVector3d(1, 2, 3);
  const Eigen::MatrixXd moved = deform_points(*e, mesh, posed);
  const Eigen::MatrixXd expected = (points * r.transpose()).rowwise() + Eigen::RowVector3d(1, 2, 3);
  EXPECT_LT((moved - expected).cwiseAbs().maxCoeff(), 1e-9);
}

TEST(TetLocator, EmptyMeshIsRefused) {
  TetMesh empty;
  EXPECT_EQ(TetLocator::build(empty).status().code(), StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace posewarp::mapping
