#include "posewarp/mapping/tet_locator.h"

#include <gtest/gtest.h>

#include <Eigen/Dense>
#include <Eigen/Geometry>

#include <array>
#include <chrono>
#include <cmath>
#include <functional>
#include <iostream>
#include <limits>
#include <random>
#include <vector>

namespace posewarp::mapping {
namespace {

// A block of n^3 cubes of `size` mm, each split into 5 tets (the split alternates so that faces match). Cubes
// where `keep` says false are left out; vertices move by up to `jitter` mm so that no face is axis-aligned.
TetMesh cube_block(int n, double size, double jitter = 0.0, const std::function<bool(int, int, int)>& keep = {},
                   uint32_t seed = 1) {
  TetMesh mesh;
  const int m = n + 1;
  mesh.vertices.resize(m * m * m, 3);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> wobble(-jitter, jitter);
  auto id = [m](int i, int j, int k) { return i + m * (j + m * k); };
  for (int k = 0; k < m; ++k) {
    for (int j = 0; j < m; ++j) {
      for (int i = 0; i < m; ++i) {
        mesh.vertices.row(id(i, j, k)) << i * size + wobble(rng), j * size + wobble(rng), k * size + wobble(rng);
      }
    }
  }
  std::vector<std::array<int, 4>> tets;
  for (int k = 0; k < n; ++k) {
    for (int j = 0; j < n; ++j) {
      for (int i = 0; i < n; ++i) {
        if (keep && !keep(i, j, k)) continue;
        const int c[8] = {id(i, j, k),     id(i + 1, j, k),     id(i, j + 1, k),     id(i + 1, j + 1, k),
                          id(i, j, k + 1), id(i + 1, j, k + 1), id(i, j + 1, k + 1), id(i + 1, j + 1, k + 1)};
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
    }
  }
  mesh.tets.resize(static_cast<Eigen::Index>(tets.size()), 4);
  mesh.tet_class = Eigen::VectorXi::Ones(static_cast<Eigen::Index>(tets.size()));
  for (size_t t = 0; t < tets.size(); ++t) {
    std::array<int, 4> tet = tets[t];
    Eigen::Matrix3d e;
    for (int c = 0; c < 3; ++c) e.col(c) = (mesh.vertices.row(tet[c + 1]) - mesh.vertices.row(tet[0])).transpose();
    if (e.determinant() < 0) std::swap(tet[2], tet[3]);
    for (int c = 0; c < 4; ++c) mesh.tets(static_cast<Eigen::Index>(t), c) = tet[static_cast<size_t>(c)];
  }
  return mesh;
}

Eigen::Vector3d vertex(const TetMesh& mesh, int32_t tet, int corner) {
  return mesh.vertices.row(mesh.tets(tet, corner)).transpose();
}

Eigen::Vector3d from_barycentric(const TetMesh& mesh, int32_t tet, const Eigen::Vector4d& b) {
  Eigen::Vector3d q = Eigen::Vector3d::Zero();
  for (int c = 0; c < 4; ++c) q += b(c) * vertex(mesh, tet, c);
  return q;
}

// Reference distances, written differently from the locator's (projection onto the face plane, then edges).
double segment_distance(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b) {
  const double t = std::clamp((p - a).dot(b - a) / (b - a).squaredNorm(), 0.0, 1.0);
  return (p - (a + t * (b - a))).norm();
}

double triangle_distance(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                         const Eigen::Vector3d& c) {
  const Eigen::Vector3d normal = (b - a).cross(c - a).normalized();
  const double height = normal.dot(p - a);
  const Eigen::Vector3d q = p - height * normal;
  const bool inside = normal.dot((b - a).cross(q - a)) >= 0 && normal.dot((c - b).cross(q - b)) >= 0 &&
                      normal.dot((a - c).cross(q - c)) >= 0;
  if (inside) return std::abs(height);
  return std::min({segment_distance(p, a, b), segment_distance(p, b, c), segment_distance(p, c, a)});
}

double tet_distance(const TetMesh& mesh, int32_t tet, const Eigen::Vector3d& p) {
  Eigen::Vector3d v[4];
  for (int c = 0; c < 4; ++c) v[c] = vertex(mesh, tet, c);
  auto volume = [](const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c,
                   const Eigen::Vector3d& d) { return (b - a).dot((c - a).cross(d - a)); };
  const double whole = volume(v[0], v[1], v[2], v[3]);
  const bool inside = volume(p, v[1], v[2], v[3]) / whole >= -1e-12 && volume(v[0], p, v[2], v[3]) / whole >= -1e-12 &&
                      volume(v[0], v[1], p, v[3]) / whole >= -1e-12 && volume(v[0], v[1], v[2], p) / whole >= -1e-12;
  if (inside) return 0.0;
  return std::min({triangle_distance(p, v[1], v[2], v[3]), triangle_distance(p, v[0], v[2], v[3]),
                   triangle_distance(p, v[0], v[1], v[3]), triangle_distance(p, v[0], v[1], v[2])});
}

double brute_force_distance(const TetMesh& mesh, const Eigen::Vector3d& p) {
  double best = std::numeric_limits<double>::infinity();
  for (int32_t t = 0; t < mesh.tet_count(); ++t) best = std::min(best, tet_distance(mesh, t, p));
  return best;
}

TEST(TetLocator, FindsTheTetContainingEveryInsidePointWithBarycentricsThatReproduceIt) {
  const TetMesh mesh = cube_block(6, 10.0, 1.0);
  Result<TetLocator> locator = TetLocator::build(mesh);
  ASSERT_TRUE(locator.ok()) << locator.status().to_string();
  std::mt19937 rng(3);
  std::uniform_real_distribution<double> inside(1.01, 58.99);  // clear of the jittered outer faces
  for (int trial = 0; trial < 2000; ++trial) {
    const Eigen::Vector3d p(inside(rng), inside(rng), inside(rng));
    const TetLocator::Location l = locator->locate(p);
    ASSERT_GE(l.tet, 0);
    EXPECT_TRUE(l.inside) << p.transpose();
    EXPECT_EQ(l.distance_mm, 0.0);
    EXPECT_NEAR(l.barycentric.sum(), 1.0, 1e-12);
    EXPECT_GE(l.barycentric.minCoeff(), -1e-9);
    EXPECT_EQ(tet_distance(mesh, l.tet, p), 0.0) << "the tet found does not contain " << p.transpose();
    EXPECT_LT((from_barycentric(mesh, l.tet, l.barycentric) - p).norm(), 1e-9);
  }
}

TEST(TetLocator, AMappedVertexReproducesItsRestPositionFromItsBarycentrics) {
  const TetMesh mesh = cube_block(6, 10.0, 1.5);
  std::mt19937 rng(4);
  std::uniform_real_distribution<double> around(-20.0, 80.0);  // inside and outside the block
  Eigen::MatrixXd points(3000, 3);
  for (int i = 0; i < points.rows(); ++i) points.row(i) << around(rng), around(rng), around(rng);
  Result<Embedding> e = embed_points(mesh, points, {});
  ASSERT_TRUE(e.ok()) << e.status().to_string();
  EXPECT_GT(e->outside_count, 0);
  EXPECT_LT(e->outside_count, points.rows());
  const Eigen::MatrixXd back = deform_points(*e, mesh, mesh.vertices);
  EXPECT_LT((back - points).cwiseAbs().maxCoeff(), 1e-9);
  for (int i = 0; i < points.rows(); ++i) {
    EXPECT_NEAR(e->barycentric.row(i).sum(), 1.0, 1e-12);
    if (e->inside[static_cast<size_t>(i)]) {
      EXPECT_GE(e->barycentric.row(i).minCoeff(), -1e-9);
    }
  }
}

TEST(TetLocator, OutsidePointsGetTheTrulyNearestTetWhateverTheCellSize) {
  // A jittered block with a quarter of its cubes missing: cavities, tunnels and overhangs.
  std::mt19937 holes(11);
  std::vector<bool> kept(5 * 5 * 5);
  for (size_t c = 0; c < kept.size(); ++c) kept[c] = holes() % 4 != 0;
  const TetMesh mesh =
      cube_block(5, 10.0, 1.5, [&](int i, int j, int k) { return kept[static_cast<size_t>(i + 5 * (j + 5 * k))]; });
  std::mt19937 rng(5);
  std::uniform_real_distribution<double> near(-12.0, 62.0);
  std::uniform_real_distribution<double> far(-400.0, 450.0);
  std::vector<Eigen::Vector3d> points;
  for (int trial = 0; trial < 400; ++trial) points.emplace_back(near(rng), near(rng), near(rng));
  for (int trial = 0; trial < 60; ++trial) points.emplace_back(far(rng), far(rng), far(rng));
  std::vector<double> expected;
  for (const Eigen::Vector3d& p : points) expected.push_back(brute_force_distance(mesh, p));

  for (const double cell_mm : {0.0, 2.5, 10.0, 45.0}) {
    Result<TetLocator> locator = TetLocator::build(mesh, cell_mm);
    ASSERT_TRUE(locator.ok()) << locator.status().to_string();
    int outside = 0;
    for (size_t n = 0; n < points.size(); ++n) {
      const Eigen::Vector3d& p = points[n];
      const TetLocator::Location l = locator->locate(p);
      ASSERT_GE(l.tet, 0);
      EXPECT_NEAR(l.distance_mm, expected[n], 1e-9) << "cell " << cell_mm << " mm, point " << p.transpose();
      EXPECT_NEAR(tet_distance(mesh, l.tet, p), expected[n], 1e-9)
          << "cell " << cell_mm << " mm, point " << p.transpose();
      EXPECT_EQ(l.inside, expected[n] == 0.0) << p.transpose();
      // Extrapolated barycentrics still reproduce the point.
      EXPECT_LT((from_barycentric(mesh, l.tet, l.barycentric) - p).norm(), 1e-9);
      outside += l.inside ? 0 : 1;
    }
    EXPECT_GT(outside, 100);  // the check above is not only about inside points
  }
}

TEST(TetLocator, PointsOnSharedFacesEdgesAndVerticesAreInside) {
  const TetMesh mesh = cube_block(3, 10.0);
  Result<TetLocator> locator = TetLocator::build(mesh);
  ASSERT_TRUE(locator.ok());
  for (int v = 0; v < mesh.vertex_count(); ++v) {
    const TetLocator::Location l = locator->locate(mesh.vertices.row(v).transpose());
    EXPECT_TRUE(l.inside) << "vertex " << v;
  }
  const TetLocator::Location face = locator->locate(Eigen::Vector3d(10.0, 4.0, 3.0));
  EXPECT_TRUE(face.inside);
  EXPECT_LT((from_barycentric(mesh, face.tet, face.barycentric) - Eigen::Vector3d(10.0, 4.0, 3.0)).norm(), 1e-12);
}

TEST(TetLocator, EmbeddedPointsMoveRigidlyWithARigidlyMovedMesh) {
  const TetMesh mesh = cube_block(4, 10.0, 1.0);
  std::mt19937 rng(6);
  std::uniform_real_distribution<double> around(-8.0, 48.0);
  Eigen::MatrixXd points(500, 3);
  for (int i = 0; i < points.rows(); ++i) points.row(i) << around(rng), around(rng), around(rng);
  Result<Embedding> e = embed_points(mesh, points, {});
  ASSERT_TRUE(e.ok());
  const Eigen::Matrix3d r = Eigen::AngleAxisd(0.8, Eigen::Vector3d(1, 1, 0).normalized()).toRotationMatrix();
  const Eigen::RowVector3d shift(12.0, -30.0, 7.5);
  const Eigen::MatrixXd posed = (mesh.vertices * r.transpose()).rowwise() + shift;
  const Eigen::MatrixXd moved = deform_points(*e, mesh, posed);
  const Eigen::MatrixXd expected = (points * r.transpose()).rowwise() + shift;
  EXPECT_LT((moved - expected).cwiseAbs().maxCoeff(), 1e-9);
}

TEST(TetLocator, FlatTetsAreSkippedAndTheRestStillLocatePoints) {
  TetMesh mesh = cube_block(2, 10.0);
  const Eigen::Index n = mesh.tet_count();
  mesh.tets.conservativeResize(n + 1, 4);
  mesh.tets.row(n) << 0, 1, 2, 3;  // four vertices on the plane z = 0
  Result<TetLocator> locator = TetLocator::build(mesh);
  ASSERT_TRUE(locator.ok());
  EXPECT_EQ(locator->degenerate_tet_count(), 1);
  const TetLocator::Location l = locator->locate(Eigen::Vector3d(5.0, 0.5, 0.0));
  EXPECT_TRUE(l.inside);
  EXPECT_LT(l.tet, n);
}

TEST(TetLocator, UnusableMeshesAndPointsAreRefused) {
  TetMesh empty;
  EXPECT_EQ(TetLocator::build(empty).status().code(), StatusCode::kInvalidArgument);

  TetMesh bad_index = cube_block(1, 10.0);
  bad_index.tets(0, 2) = 99;
  EXPECT_EQ(TetLocator::build(bad_index).status().code(), StatusCode::kInvalidArgument);

  TetMesh not_finite = cube_block(1, 10.0);
  not_finite.vertices(3, 1) = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(TetLocator::build(not_finite).status().code(), StatusCode::kInvalidArgument);

  TetMesh flat = cube_block(1, 10.0);
  flat.vertices.col(2).setZero();
  EXPECT_EQ(TetLocator::build(flat).status().code(), StatusCode::kInvalidArgument);

  const TetMesh good = cube_block(1, 10.0);
  EXPECT_EQ(TetLocator::build(good, -1.0).status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(TetLocator::build(good, 1e-6).status().code(), StatusCode::kResourceExhausted);

  EXPECT_EQ(embed_points(good, Eigen::MatrixXd::Zero(4, 2), {}).status().code(), StatusCode::kInvalidArgument);
  Eigen::MatrixXd nan_point = Eigen::MatrixXd::Constant(3, 3, 5.0);
  nan_point(1, 0) = std::numeric_limits<double>::infinity();
  const Status status = embed_points(good, nan_point, {}).status();
  EXPECT_EQ(status.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(status.message().find("point 1"), std::string::npos) << status.message();
}

TEST(TetLocator, NoPointsGiveAnEmptyEmbedding) {
  Result<Embedding> e = embed_points(cube_block(1, 10.0), Eigen::MatrixXd(0, 3), {});
  ASSERT_TRUE(e.ok());
  EXPECT_EQ(e->tet.size(), 0);
  EXPECT_EQ(deform_points(*e, cube_block(1, 10.0), cube_block(1, 10.0).vertices).rows(), 0);
}

TEST(TetLocator, EmbeddingStopsWhenCancelled) {
  const TetMesh mesh = cube_block(4, 10.0);
  ProgressHooks hooks;
  hooks.cancel_requested = [] { return true; };
  const Eigen::MatrixXd points = Eigen::MatrixXd::Constant(50000, 3, 20.0);
  EXPECT_EQ(embed_points(mesh, points, hooks).status().code(), StatusCode::kCancelled);
}

TEST(TetLocator, EmbeddingReportsProgressToTheEnd) {
  const TetMesh mesh = cube_block(4, 10.0);
  double last = -1.0;
  ProgressHooks hooks;
  hooks.on_progress = [&](std::string_view, double fraction) { last = fraction; };
  const Eigen::MatrixXd points = Eigen::MatrixXd::Constant(20000, 3, 20.0);
  ASSERT_TRUE(embed_points(mesh, points, hooks).ok());
  EXPECT_EQ(last, 1.0);
}

TEST(TetLocator, DeformingWithAMismatchedEmbeddingGivesNaNRowsNotACrash) {
  const TetMesh mesh = cube_block(1, 10.0);
  Embedding e;
  e.tet = Eigen::VectorXi::Constant(2, 0);
  e.tet(1) = 1000;
  e.barycentric = Eigen::MatrixXd::Constant(2, 4, 0.25);
  const Eigen::MatrixXd moved = deform_points(e, mesh, mesh.vertices);
  EXPECT_TRUE(moved.row(0).allFinite());
  EXPECT_TRUE(moved.row(1).array().isNaN().all());
  EXPECT_TRUE(deform_points(e, mesh, Eigen::MatrixXd::Zero(2, 3)).array().isNaN().all());
}

// Not a timing assertion: prints the throughput the design targets (1M points/s on 2 cores inside the mesh).
TEST(TetLocatorThroughput, EmbedsAMillionPointsInAHundredThousandTets) {
  const TetMesh mesh = cube_block(27, 10.0, 1.0);  // 98,415 tets
  ASSERT_GT(mesh.tet_count(), 95000);
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> inside(1.01, 268.99);
  Eigen::MatrixXd points(1'000'000, 3);
  for (Eigen::Index i = 0; i < points.rows(); ++i) points.row(i) << inside(rng), inside(rng), inside(rng);
  // Skin-like points: within 3 mm outside the faces of the block.
  std::uniform_real_distribution<double> face(0.0, 270.0), offset(1.01, 4.0);
  Eigen::MatrixXd skin(200'000, 3);
  for (Eigen::Index i = 0; i < skin.rows(); ++i) {
    const int axis = static_cast<int>(i % 3);
    skin.row(i) << face(rng), face(rng), face(rng);
    skin(i, axis) = (i / 3) % 2 == 0 ? -offset(rng) : 270.0 + offset(rng);
  }

  using Clock = std::chrono::steady_clock;
  const auto t0 = Clock::now();
  Result<TetLocator> locator = TetLocator::build(mesh);
  const auto t1 = Clock::now();
  Result<Embedding> e = embed_points(mesh, points, {});
  const auto t2 = Clock::now();
  Result<Embedding> s = embed_points(mesh, skin, {});
  const auto t3 = Clock::now();
  ASSERT_TRUE(locator.ok() && e.ok() && s.ok());
  EXPECT_EQ(e->outside_count, 0);
  EXPECT_EQ(s->outside_count, skin.rows());
  EXPECT_LT((deform_points(*e, mesh, mesh.vertices) - points).cwiseAbs().maxCoeff(), 1e-9);
  const double build_s = std::chrono::duration<double>(t1 - t0).count();
  const double inside_s = std::chrono::duration<double>(t2 - t1).count();
  const double skin_s = std::chrono::duration<double>(t3 - t2).count();
  std::cout << "[ throughput ] locator build for " << mesh.tet_count() << " tets: " << build_s * 1e3 << " ms\n"
            << "[ throughput ] embed " << points.rows() << " random inside points (build included): " << inside_s
            << " s = " << static_cast<double>(points.rows()) / inside_s / 1e6 << " M points/s\n"
            << "[ throughput ] embed " << skin.rows() << " points 1-4 mm outside the mesh: " << skin_s
            << " s = " << static_cast<double>(skin.rows()) / skin_s / 1e6 << " M points/s\n";
}

}  // namespace
}  // namespace posewarp::mapping
