// The soft tissue's steady state on a hand-made limb: two bone blocks joined by 32 mm of soft tissue, bent 60
// degrees at the soft part's middle. LBS warm-starts it (as CoR would), the solve keeps bones where they are and
// gives the soft tissue its volume back without inverted tets.
#include "posewarp/fem/soft_tissue.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <cmath>

namespace posewarp::fem {
namespace {

constexpr int kNx = 6, kNy = 6, kNz = 20;  // cells of 4 mm: 24 x 24 x 80 mm
constexpr double kCell = 4.0;
constexpr double kSoftFrom = 24.0, kSoftTo = 56.0;  // z range of the soft joint

struct Limb {
  TetMesh mesh;
  SkinWeights weights;
};

// Six tets per cube cell (Kuhn's subdivision, conforming across cells); cells below kSoftFrom are bone segment 0,
// above kSoftTo bone segment 1, between them soft tissue. Weights blend linearly with height across the soft part.
Limb limb() {
  Limb limb;
  auto id = [](int i, int j, int k) { return (k * (kNy + 1) + j) * (kNx + 1) + i; };
  limb.mesh.vertices.resize((kNx + 1) * (kNy + 1) * (kNz + 1), 3);
  for (int k = 0; k <= kNz; ++k)
    for (int j = 0; j <= kNy; ++j)
      for (int i = 0; i <= kNx; ++i) limb.mesh.vertices.row(id(i, j, k)) << i * kCell, j * kCell, k * kCell;
  const int paths[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2}, {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};
  std::vector<Eigen::Vector4i> tets;
  std::vector<int> classes;
  for (int k = 0; k < kNz; ++k)
    for (int j = 0; j < kNy; ++j)
      for (int i = 0; i < kNx; ++i) {
        const double z = (k + 0.5) * kCell;
        const int cls = z < kSoftFrom ? kFirstBoneClass : z > kSoftTo ? kFirstBoneClass + 1 : kSoftTissueClass;
        for (const auto& path : paths) {
          int c[3] = {i, j, k};
          Eigen::Vector4i tet;
          tet(0) = id(c[0], c[1], c[2]);
          for (int s = 0; s < 3; ++s) {
            ++c[path[s]];
            tet(s + 1) = id(c[0], c[1], c[2]);
          }
          Eigen::Matrix3d e;
          for (int s = 0; s < 3; ++s) e.col(s) = (limb.mesh.vertices.row(tet(s + 1)) - limb.mesh.vertices.row(tet(0))).transpose();
          if (e.determinant() < 0) std::swap(tet(2), tet(3));
          tets.push_back(tet);
          classes.push_back(cls);
        }
      }
  limb.mesh.tets.resize(static_cast<Eigen::Index>(tets.size()), 4);
  limb.mesh.tet_class.resize(static_cast<Eigen::Index>(tets.size()));
  for (size_t t = 0; t < tets.size(); ++t) {
    limb.mesh.tets.row(static_cast<Eigen::Index>(t)) = tets[t].transpose();
    limb.mesh.tet_class(static_cast<Eigen::Index>(t)) = classes[t];
  }
  limb.mesh.segment_count = 2;
  const auto n = limb.mesh.vertices.rows();
  limb.weights.influences = 2;
  limb.weights.segment_count = 2;
  limb.weights.segment.resize(n, 2);
  limb.weights.weight.resize(n, 2);
  for (Eigen::Index v = 0; v < n; ++v) {
    const double w1 = std::clamp((limb.mesh.vertices(v, 2) - kSoftFrom) / (kSoftTo - kSoftFrom), 0.0, 1.0);
    const bool upper = w1 > 0.5;
    limb.weights.segment.row(v) << (upper ? 1 : 0), (upper ? 0 : 1);
    limb.weights.weight.row(v) << static_cast<float>(upper ? w1 : 1.0 - w1), static_cast<float>(upper ? 1.0 - w1 : w1);
  }
  return limb;
}

// Segment 1 turned `degrees` about the x axis through the middle of the soft part.
skinning::SegmentTransforms bend(double degrees) {
  skinning::SegmentTransforms t;
  const Eigen::Vector3d centre(kNx * kCell / 2, kNy * kCell / 2, (kSoftFrom + kSoftTo) / 2);
  const Eigen::Matrix3d r = Eigen::AngleAxisd(degrees * M_PI / 180.0, Eigen::Vector3d::UnitX()).toRotationMatrix();
  t.rotation = {Eigen::Matrix3d::Identity(), r};
  t.translation = {Eigen::Vector3d::Zero(), centre - r * centre};
  return t;
}

struct SoftFigures {
  double volume_change = 0.0;  // signed posed volume over rest volume, minus 1
  int64_t inverted = 0;
};

SoftFigures soft_figures(const Limb& limb, const skinning::RestTetFrames& frames, const Eigen::MatrixXd& posed) {
  const Eigen::VectorXd det = skinning::tet_determinants(limb.mesh, frames, posed);
  double rest = 0.0, now = 0.0;
  SoftFigures f;
  for (Eigen::Index t = 0; t < det.size(); ++t) {
    if (limb.mesh.tet_class(t) != kSoftTissueClass) continue;
    rest += frames.rest_volume(t);
    now += frames.rest_volume(t) * det(t);
    f.inverted += det(t) <= 0.0;
  }
  f.volume_change = now / rest - 1.0;
  return f;
}

class SoftTissue : public ::testing::Test {
 protected:
  Limb limb_ = limb();
  skinning::RestTetFrames frames_ = skinning::rest_tet_frames(limb_.mesh);
  Topology topology_ = topology(limb_.mesh);
};

TEST_F(SoftTissue, GivesTheBentJointItsVolumeBackAndKeepsBonesWhereTheyAre) {
  const skinning::SegmentTransforms transforms = bend(60.0);
  const Eigen::MatrixXd warm = skinning::lbs(limb_.mesh.vertices, limb_.weights, transforms);
  FemStats stats;
  Result<Eigen::MatrixXd> posed =
      solve({limb_.mesh, frames_, topology_, limb_.weights, transforms, warm}, FemParams{}, {}, &stats);
  ASSERT_TRUE(posed.ok()) << posed.status().to_string();
  const SoftFigures lbs = soft_figures(limb_, frames_, warm), fem = soft_figures(limb_, frames_, *posed);
  std::cout << "60 degrees: soft volume lbs " << lbs.volume_change << " (" << lbs.inverted << " inverted), fem "
            << fem.volume_change << " (" << fem.inverted << " inverted); " << stats.free_vertices << " free, "
            << stats.iterations << " iterations, last step " << stats.last_step_mm << " mm\n";
  EXPECT_LT(lbs.volume_change, -0.04);  // LBS pinches the inside of the bend
  EXPECT_LT(std::abs(fem.volume_change), 0.01);
  EXPECT_EQ(fem.inverted, 0);
  EXPECT_GT(stats.free_vertices, 0);
  // Every vertex of a bone tet keeps its skinned (rigid) place, exactly.
  for (Eigen::Index v = 0; v < warm.rows(); ++v) {
    if (topology_.bone[static_cast<size_t>(v)]) {
      ASSERT_EQ(posed->row(v), warm.row(v)) << v;
    }
  }
}

TEST_F(SoftTissue, LeavesARigidMotionAsItIs) {
  skinning::SegmentTransforms transforms = bend(0.0);
  const Eigen::Matrix3d r = Eigen::AngleAxisd(0.7, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix();
  transforms.rotation = {r, r};
  transforms.translation = {Eigen::Vector3d(5, -3, 2), Eigen::Vector3d(5, -3, 2)};
  const Eigen::MatrixXd warm = skinning::lbs(limb_.mesh.vertices, limb_.weights, transforms);
  FemStats stats;
  Result<Eigen::MatrixXd> posed =
      solve({limb_.mesh, frames_, topology_, limb_.weights, transforms, warm}, FemParams{}, {}, &stats);
  ASSERT_TRUE(posed.ok());
  EXPECT_EQ(stats.free_vertices, 0);
  EXPECT_EQ(*posed, warm);
}

TEST_F(SoftTissue, RefusesBadParametersAndMismatchedInputsAndStopsWhenCancelled) {
  const skinning::SegmentTransforms transforms = bend(45.0);
  const Eigen::MatrixXd warm = skinning::lbs(limb_.mesh.vertices, limb_.weights, transforms);
  const SolveInputs inputs{limb_.mesh, frames_, topology_, limb_.weights, transforms, warm};
  FemParams params;
  params.volume_weight = -1.0;
  Result<Eigen::MatrixXd> bad = solve(inputs, params, {});
  EXPECT_EQ(bad.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(bad.status().message().find("volume_weight"), std::string::npos);
  params = FemParams{};
  params.tolerance_mm = std::nan("");
  EXPECT_EQ(solve(inputs, params, {}).status().code(), StatusCode::kInvalidArgument);
  const Eigen::MatrixXd short_warm = warm.topRows(10);
  EXPECT_EQ(solve({limb_.mesh, frames_, topology_, limb_.weights, transforms, short_warm}, FemParams{}, {}).status().code(),
            StatusCode::kInvalidArgument);
  ProgressHooks hooks;
  hooks.cancel_requested = [] { return true; };
  EXPECT_EQ(solve(inputs, FemParams{}, hooks).status().code(), StatusCode::kCancelled);
}

}  // namespace
}  // namespace posewarp::fem
