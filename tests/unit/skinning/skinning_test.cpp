#include "posewarp/skinning/skinning.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <cstdlib>

#include "posewarp/skinning/tet_maps.h"

namespace posewarp::skinning {
namespace {

// Vertices on a ring of radius 10 around the z axis at heights -10..10; bone 0 below z = 0, bone 1 above, blended
// linearly over |z| < 5.
struct Ring {
  Eigen::MatrixXd rest;
  SkinWeights weights;
  RotationCentres centres;
};

Ring ring() {
  Ring r;
  const int n = 21 * 16;
  r.rest.resize(n, 3);
  r.weights.influences = 2;
  r.weights.segment_count = 2;
  r.weights.segment.resize(n, 2);
  r.weights.weight.resize(n, 2);
  r.centres.centre.resize(n, 3);
  r.centres.rigid.assign(n, 0);
  int v = 0;
  for (int h = -10; h <= 10; ++h) {
    for (int a = 0; a < 16; ++a, ++v) {
      const double angle = 2.0 * M_PI * a / 16.0;
      r.rest.row(v) << 10.0 * std::cos(angle), 10.0 * std::sin(angle), h;
      const double w1 = std::clamp((h + 5.0) / 10.0, 0.0, 1.0);
      const bool upper = w1 >= 0.5;
      r.weights.segment(v, 0) = upper ? 1 : 0;
      r.weights.segment(v, 1) = upper ? 0 : 1;
      r.weights.weight(v, 0) = static_cast<float>(upper ? w1 : 1.0 - w1);
      r.weights.weight(v, 1) = static_cast<float>(upper ? 1.0 - w1 : w1);
      r.centres.centre.row(v) << 0.0, 0.0, h * (1.0 - std::min(1.0, std::abs(h) / 5.0 < 1.0 ? 1.0 : 0.0));
      r.centres.rigid[static_cast<size_t>(v)] = std::abs(h) >= 5 ? 1 : 0;
      if (!r.centres.rigid[static_cast<size_t>(v)]) r.centres.centre.row(v) << 0.0, 0.0, 0.0;
    }
  }
  return r;
}

SegmentTransforms twist(double degrees) {
  SegmentTransforms t;
  t.rotation = {Eigen::Matrix3d::Identity(),
                Eigen::AngleAxisd(degrees * M_PI / 180.0, Eigen::Vector3d::UnitZ()).toRotationMatrix()};
  t.translation = {Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()};
  return t;
}

SegmentTransforms bend(double degrees) {
  // Bone 1 rotates about the x axis through the joint at the origin.
  SegmentTransforms t;
  t.rotation = {Eigen::Matrix3d::Identity(),
                Eigen::AngleAxisd(degrees * M_PI / 180.0, Eigen::Vector3d::UnitX()).toRotationMatrix()};
  t.translation = {Eigen::Vector3d::Zero(), Eigen::Vector3d::Zero()};
  return t;
}

TEST(Skinning, IdentityTransformsLeaveEveryVertexInPlace) {
  const Ring r = ring();
  for (const Method m : {Method::kLbs, Method::kDqs, Method::kCor}) {
    Result<Eigen::MatrixXd> posed = skin(m, r.rest, r.weights, r.centres, twist(0.0));
    ASSERT_TRUE(posed.ok());
    EXPECT_LT((*posed - r.rest).cwiseAbs().maxCoeff(), 1e-12) << method_name(m);
  }
}

TEST(Skinning, AllMethodsMoveFullyOwnedVerticesRigidly) {
  const Ring r = ring();
  const SegmentTransforms t = bend(60.0);
  for (const Method m : {Method::kLbs, Method::kDqs, Method::kCor}) {
    Result<Eigen::MatrixXd> posed = skin(m, r.rest, r.weights, r.centres, t);
    ASSERT_TRUE(posed.ok());
    for (int v = 0; v < r.rest.rows(); ++v) {
      if (r.weights.weight(v, 0) < 1.0f) continue;
      const int s = r.weights.segment(v, 0);
      const Eigen::Vector3d expected = t.rotation[static_cast<size_t>(s)] * r.rest.row(v).transpose();
      ASSERT_LT((posed->row(v).transpose() - expected).norm(), 1e-9) << method_name(m) << " vertex " << v;
    }
  }
}

TEST(Skinning, LbsCollapsesATwistedJointWhileDqsAndCorKeepTheRadius) {
  // The candy-wrapper artefact: at 180 degrees of twist LBS pulls the half-blended ring onto the axis.
  const Ring r = ring();
  const SegmentTransforms t = twist(180.0);
  Eigen::MatrixXd posed_lbs = lbs(r.rest, r.weights, t);
  Eigen::MatrixXd posed_dqs = dqs(r.rest, r.weights, t);
  Eigen::MatrixXd posed_cor = cor(r.rest, r.weights, r.centres, t);
  const int middle = 10 * 16;  // h = 0: weights 0.5 / 0.5
  EXPECT_LT(posed_lbs.row(middle).head<2>().norm(), 1e-6);
  EXPECT_NEAR(posed_dqs.row(middle).head<2>().norm(), 10.0, 1e-6);
  EXPECT_NEAR(posed_cor.row(middle).head<2>().norm(), 10.0, 1e-6);
}

// The skinning loops use Kavan's closed forms (no square root, no rotation matrix); here the textbook forms.
TEST(Skinning, DqsAndCorMatchTheirTextbookFormulas) {
  const int n = 200, segments = 6;
  std::srand(3);
  auto unit = [] { return static_cast<double>(std::rand()) / RAND_MAX; };
  Eigen::MatrixXd rest(n, 3);
  SkinWeights weights;
  weights.influences = 3;
  weights.segment_count = segments;
  weights.segment.resize(n, 3);
  weights.weight.resize(n, 3);
  RotationCentres centres;
  centres.centre.resize(n, 3);
  centres.rigid.assign(n, 0);
  for (int v = 0; v < n; ++v) {
    rest.row(v) << 200 * unit() - 100, 200 * unit() - 100, 200 * unit() - 100;
    centres.centre.row(v) << 50 * unit(), 50 * unit(), 50 * unit();
    double w[3] = {unit() + 1.0, unit(), unit() * 0.5};
    const double sum = w[0] + w[1] + w[2];
    for (int i = 0; i < 3; ++i) {
      weights.segment(v, i) = (v + 2 * i) % segments;
      weights.weight(v, i) = static_cast<float>(w[i] / sum);
    }
  }
  SegmentTransforms t;
  for (int s = 0; s < segments; ++s) {
    // Rotations up to 170 degrees, some on the far hemisphere of others.
    t.rotation.push_back(Eigen::AngleAxisd(0.5 * s + 0.2, Eigen::Vector3d(1.0, s, 2.0 - s).normalized()).toRotationMatrix());
    t.translation.push_back(Eigen::Vector3d(10.0 * s, -5.0 * s, 3.0));
  }
  const Eigen::MatrixXd dq = dqs(rest, weights, t);
  const Eigen::MatrixXd cr = cor(rest, weights, centres, t);
  for (int v = 0; v < n; ++v) {
    Eigen::Quaterniond first(t.rotation[static_cast<size_t>(weights.segment(v, 0))]);
    Eigen::Vector4d real = Eigen::Vector4d::Zero(), dual = Eigen::Vector4d::Zero();
    Eigen::Vector3d lbs_centre = Eigen::Vector3d::Zero();
    double total = 0.0;
    for (int i = 0; i < 3; ++i) {
      const int s = weights.segment(v, i);
      const double w = weights.weight(v, i);
      Eigen::Quaterniond q(t.rotation[static_cast<size_t>(s)]);
      const Eigen::Quaterniond tq(0.0, t.translation[static_cast<size_t>(s)].x(), t.translation[static_cast<size_t>(s)].y(),
                                  t.translation[static_cast<size_t>(s)].z());
      const Eigen::Quaterniond d = tq * q;  // twice the dual part
      const double sign = q.coeffs().dot(first.coeffs()) < 0.0 ? -1.0 : 1.0;
      real += sign * w * q.coeffs();
      dual += sign * w * 0.5 * d.coeffs();
      lbs_centre += w * (t.rotation[static_cast<size_t>(s)] * centres.centre.row(v).transpose() + t.translation[static_cast<size_t>(s)]);
      total += w;
    }
    const double norm = real.norm();
    const Eigen::Quaterniond q0(real / norm), qe(dual / norm);
    const Eigen::Vector3d translation = 2.0 * (qe * q0.conjugate()).vec();
    const Eigen::Vector3d p = rest.row(v).transpose();
    const Eigen::Vector3d expected_dqs = q0.toRotationMatrix() * p + translation;
    const Eigen::Vector3d c = centres.centre.row(v).transpose();
    const Eigen::Vector3d expected_cor = q0.toRotationMatrix() * (p - c) + lbs_centre / total;
    EXPECT_LT((dq.row(v).transpose() - expected_dqs).norm(), 1e-9) << v;
    EXPECT_LT((cr.row(v).transpose() - expected_cor).norm(), 1e-9) << v;
  }
}

TEST(Skinning, MismatchedInputsAreRefused) {
  const Ring r = ring();
  SegmentTransforms one = twist(0.0);
  one.rotation.pop_back();
  one.translation.pop_back();
  EXPECT_EQ(skin(Method::kLbs, r.rest, r.weights, r.centres, one).status().code(), StatusCode::kInvalidArgument);
  RotationCentres none;
  EXPECT_EQ(skin(Method::kCor, r.rest, r.weights, none, twist(0.0)).status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(method_from_name("splines").status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(*method_from_name("dqs"), Method::kDqs);
}

TEST(TetMaps, DeterminantIsOneForRigidMotionAndScalesWithVolume) {
  TetMesh mesh;
  mesh.vertices.resize(4, 3);
  mesh.vertices << 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1;
  mesh.tets.resize(1, 4);
  mesh.tets << 0, 1, 2, 3;
  mesh.tet_class.resize(1);
  mesh.tet_class << 1;
  const RestTetFrames frames = rest_tet_frames(mesh);
  EXPECT_NEAR(frames.rest_volume(0), 1.0 / 6.0, 1e-12);
  const Eigen::Matrix3d r = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  Eigen::MatrixXd moved = (mesh.vertices * r.transpose()).rowwise() + Eigen::RowVector3d(5, -2, 1);
  EXPECT_NEAR(tet_determinants(mesh, frames, moved)(0), 1.0, 1e-12);
  EXPECT_NEAR(tet_determinants(mesh, frames, 2.0 * mesh.vertices)(0), 8.0, 1e-12);
  Eigen::MatrixXd flipped = mesh.vertices;
  flipped.col(2) *= -1.0;
  EXPECT_LT(tet_determinants(mesh, frames, flipped)(0), 0.0);
}

}  // namespace
}  // namespace posewarp::skinning
