// The report's parallel reductions against the plain loops they replace: the same counts and figures, and the same
// figures whatever the thread count.
#include "posewarp/report/quality_report.h"

#include <gtest/gtest.h>

#include <random>

#include "posewarp/common/parallel.h"

namespace posewarp::report {
namespace {

// Random tets over a 300 mm cube (not a valid mesh; the report reads only corners, classes and volumes), spread
// over several of the report's blocks.
struct RandomMesh {
  TetMesh mesh;
  Eigen::VectorXd det, rest_volume;
  explicit RandomMesh(int64_t tets) {
    std::mt19937 random(7);
    std::uniform_real_distribution<double> coordinate(0.0, 300.0), unit(0.0, 1.0);
    const int64_t vertices = tets / 2;
    mesh.vertices.resize(vertices, 3);
    for (int64_t v = 0; v < vertices; ++v)
      for (int a = 0; a < 3; ++a) mesh.vertices(v, a) = coordinate(random);
    mesh.tets.resize(tets, 4);
    mesh.tet_class.resize(tets);
    mesh.segment_count = 3;
    det.resize(tets);
    rest_volume.resize(tets);
    std::uniform_int_distribution<int> corner(0, static_cast<int>(vertices - 1)), klass(1, 4);
    for (int64_t t = 0; t < tets; ++t) {
      for (int c = 0; c < 4; ++c) mesh.tets(t, c) = corner(random);
      mesh.tet_class(t) = klass(random);  // 1 soft, 2..4 bones
      det(t) = 3.0 * unit(random) - 0.5;  // folded, squashed, kept and stretched ones
      rest_volume(t) = 1.0 + 10.0 * unit(random);
    }
  }
};

TEST(JointRegionChanges, OnePassOverTheTetsGivesWhatAPassPerJointAndRadiusGaveAtAnyThreadCount) {
  const RandomMesh r(100000);
  const std::vector<std::pair<std::string, Eigen::Vector3d>> joints{{"knee", {100.0, 150.0, 80.0}},
                                                                    {"elbow", {220.0, 60.0, 200.0}}};
  const std::vector<double> radii{50.0, 100.0};
  set_thread_count(2);
  const std::vector<JointRegionChange> two = joint_region_changes(r.mesh, r.det, r.rest_volume, joints, radii);
  set_thread_count(1);
  const std::vector<JointRegionChange> one = joint_region_changes(r.mesh, r.det, r.rest_volume, joints, radii);
  set_thread_count(0);
  ASSERT_EQ(two.size(), 4u);
  ASSERT_EQ(one.size(), 4u);
  for (size_t j = 0; j < joints.size(); ++j) {
    for (size_t k = 0; k < radii.size(); ++k) {
      double rest = 0.0, posed = 0.0, folded = 0.0, stretched = 0.0;
      for (int64_t t = 0; t < r.mesh.tet_count(); ++t) {
        if (r.mesh.tet_class(t) != kSoftTissueClass) continue;
        Eigen::Vector3d c = Eigen::Vector3d::Zero();
        for (int q = 0; q < 4; ++q) c += r.mesh.vertices.row(r.mesh.tets(t, q)).transpose();
        if ((0.25 * c - joints[j].second).norm() > radii[k]) continue;
        rest += r.rest_volume(t);
        posed += r.rest_volume(t) * r.det(t);
        if (r.det(t) <= 0.0)
          folded += r.rest_volume(t);
        else if (r.det(t) > 2.0 || r.det(t) < 0.5)
          stretched += r.rest_volume(t);
      }
      const JointRegionChange& got = two[j * radii.size() + k];
      EXPECT_EQ(got.joint, joints[j].first);
      EXPECT_EQ(got.radius_mm, radii[k]);
      ASSERT_GT(rest, 0.0);
      EXPECT_NEAR(got.rest_volume_ml, rest / 1000.0, 1e-9);
      EXPECT_NEAR(got.volume_change, posed / rest - 1.0, 1e-12);
      EXPECT_NEAR(got.folded_fraction, folded / rest, 1e-12);
      EXPECT_NEAR(got.stretched_fraction, stretched / rest, 1e-12);
      EXPECT_GT(got.folded_fraction, 0.0);
      // Bit for bit the same on one thread: the blocks do not depend on the threads.
      const JointRegionChange& single = one[j * radii.size() + k];
      EXPECT_EQ(single.rest_volume_ml, got.rest_volume_ml);
      EXPECT_EQ(single.volume_change, got.volume_change);
      EXPECT_EQ(single.folded_fraction, got.folded_fraction);
    }
  }
}

TEST(BoneRigidity, EachSegmentsWorstCornerOverEveryBlock) {
  RandomMesh r(70000);
  const std::vector<Eigen::Matrix3d> rotation(3, Eigen::Matrix3d::Identity());
  const std::vector<Eigen::Vector3d> translation(3, Eigen::Vector3d::Zero());
  Eigen::MatrixXd posed = r.mesh.vertices;
  // One corner of the last bone tet moved 4 mm, one of the first bone tet of segment 0 moved 2 mm.
  int64_t last = -1, first = -1;
  for (int64_t t = 0; t < r.mesh.tet_count(); ++t) {
    if (r.mesh.tet_class(t) == kFirstBoneClass + 2) last = t;
    if (first < 0 && r.mesh.tet_class(t) == kFirstBoneClass) first = t;
  }
  posed(r.mesh.tets(last, 3), 0) += 4.0;
  posed(r.mesh.tets(first, 1), 2) -= 2.0;
  const std::vector<SegmentRigidity> rigidity = bone_rigidity(r.mesh, posed, rotation, translation, {"a", "b", "c"});
  ASSERT_EQ(rigidity.size(), 3u);
  EXPECT_EQ(rigidity[2].segment, "c");
  EXPECT_NEAR(rigidity[2].max_error_mm, 4.0, 1e-12);
  EXPECT_NEAR(rigidity[0].max_error_mm, 2.0, 1e-12);
}

TEST(LabelCounts, TheSameWithTheExpectedRangeAndWhenAValueLiesOutsideIt) {
  ImageGeometry g;
  g.size = {64, 64, 300};  // 1.2M voxels: several blocks
  LabelVolume labels(g, 0);
  std::mt19937 random(3);
  std::uniform_int_distribution<int> value(0, 40);
  for (int64_t v = 0; v < labels.voxel_count(); ++v) labels.data()[v] = value(random) < 30 ? 0 : value(random) + 100;
  std::map<Label, int64_t> truth;
  for (int64_t v = 0; v < labels.voxel_count(); ++v) ++truth[labels.data()[v]];
  EXPECT_EQ(label_counts(labels), truth);
  EXPECT_EQ(label_counts(labels, std::pair<Label, Label>{0, 140}), truth);
  labels.data()[777777] = 9000;  // a value past the range the caller expected: still counted
  labels.data()[5] = -3;
  truth.clear();
  for (int64_t v = 0; v < labels.voxel_count(); ++v) ++truth[labels.data()[v]];
  EXPECT_EQ(label_counts(labels, std::pair<Label, Label>{0, 140}), truth);
  EXPECT_EQ(truth.at(9000), 1);
  EXPECT_EQ(truth.at(-3), 1);
}

}  // namespace
}  // namespace posewarp::report
