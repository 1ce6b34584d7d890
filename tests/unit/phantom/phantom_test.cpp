#include "posewarp/phantom/phantom.h"

#include <gtest/gtest.h>

#include <cmath>
#include <map>
#include <set>

namespace posewarp::phantom {
namespace {

// Label at the voxel nearest a physical point (0 outside the grid).
Label label_at(const LabelVolume& labels, const Vec3& p) {
  const Vec3 index = labels.geometry().physical_to_index(p);
  const int64_t i = std::llround(index[0]), j = std::llround(index[1]), k = std::llround(index[2]);
  return labels.contains(i, j, k) ? labels.at(i, j, k) : 0;
}

std::string segment_at(const Phantom& p, const Vec3& point) {
  const labels::LabelEntry* entry = p.label_map.find(label_at(p.labels, point));
  return entry && entry->role == labels::LabelRole::kBone ? entry->segment : std::string();
}

TEST(Bar, IsAChainOfBonesInASoftCylinderWithJointsInTheGaps) {
  Result<Phantom> bar = make_bar(BarParams{});
  ASSERT_TRUE(bar.ok()) << bar.status().to_string();
  EXPECT_EQ(bar->label_map.bone_segments().size(), 4u);
  ASSERT_EQ(bar->joints.size(), 3u);
  const double gap = bar->joint_gap_mm;
  EXPECT_DOUBLE_EQ(gap, 4.0);  // two voxels of 2 mm
  for (const JointTruth& joint : bar->joints) {
    // The centre lies in soft tissue; the parent bone is just below it on the axis, the child just above.
    EXPECT_EQ(label_at(bar->labels, joint.centre_mm), 1) << joint.name;
    Vec3 below = joint.centre_mm, above = joint.centre_mm;
    below[2] -= gap / 2 + 2.0;
    above[2] += gap / 2 + 2.0;
    EXPECT_EQ(segment_at(*bar, below), joint.parent_segment) << joint.name;
    EXPECT_EQ(segment_at(*bar, above), joint.child_segment) << joint.name;
    // Soft tissue surrounds the joint.
    EXPECT_EQ(label_at(bar->labels, {20.0, 0.0, joint.centre_mm[2]}), 1);
    EXPECT_EQ(label_at(bar->labels, {40.0, 0.0, joint.centre_mm[2]}), 0);
  }
}

TEST(Bar, CtFollowsTheLabels) {
  Result<Phantom> bar = make_bar(BarParams{});
  ASSERT_TRUE(bar.ok());
  ASSERT_TRUE(bar->ct.geometry().same_grid(bar->labels.geometry()));
  for (int64_t v = 0; v < bar->labels.voxel_count(); v += 97) {
    const Label l = bar->labels.data()[v];
    const float hu = bar->ct.data()[v];
    const float expected = l == 0 ? -1000.0f : l == 1 ? 40.0f : 700.0f;
    ASSERT_NEAR(hu, expected, 5.0) << "voxel " << v;
  }
}

TEST(Mannequin, EveryJointSitsBetweenItsTwoSegments) {
  MannequinParams params;
  params.spacing_mm = 4.0;
  Result<Phantom> m = make_mannequin(params);
  ASSERT_TRUE(m.ok()) << m.status().to_string();
  EXPECT_EQ(m->label_map.bone_segments().size(), 16u);
  EXPECT_EQ(m->joints.size(), 15u);
  const double gap = m->joint_gap_mm;
  for (const JointTruth& joint : m->joints) {
    SCOPED_TRACE(joint.name);
    if (joint.kind == "ball") {
      EXPECT_EQ(segment_at(*m, joint.centre_mm), joint.child_segment) << "the centre is the ball's";
      // The ball (child) fills the centre's neighbourhood; the socket (parent) caps it from above.
      Vec3 inside = joint.centre_mm;
      inside[2] += 8.0;
      EXPECT_EQ(segment_at(*m, inside), joint.child_segment);
      Vec3 cap = joint.centre_mm;
      cap[2] += 24.0 + gap + 6.0;
      EXPECT_EQ(segment_at(*m, cap), joint.parent_segment);
    } else {
      EXPECT_EQ(segment_at(*m, joint.centre_mm), "") << "the centre lies in the joint space";
      // Flat bone ends face each other along z across the gap; the child is the one further from the root.
      Vec3 below = joint.centre_mm, above = joint.centre_mm;
      below[2] -= gap / 2 + params.spacing_mm;
      above[2] += gap / 2 + params.spacing_mm;
      const std::set<std::string> found{segment_at(*m, below), segment_at(*m, above)};
      EXPECT_EQ(found, (std::set<std::string>{joint.parent_segment, joint.child_segment}));
    }
  }
}

TEST(Mannequin, BallJointCentreIsTheCentreOfTheChildHead) {
  MannequinParams params;
  params.spacing_mm = 2.0;
  Result<Phantom> m = make_mannequin(params);
  ASSERT_TRUE(m.ok());
  for (const JointTruth& joint : m->joints) {
    if (joint.kind != "ball") continue;
    // Centroid of the child's voxels above the centre (the head's upper half) lies on the vertical through it.
    double sum[3] = {0, 0, 0};
    int64_t n = 0;
    const ImageGeometry& g = m->labels.geometry();
    const std::vector<Label> child = m->label_map.labels_of_segment(joint.child_segment);
    for (int64_t k = 0; k < g.size[2]; ++k)
      for (int64_t j = 0; j < g.size[1]; ++j)
        for (int64_t i = 0; i < g.size[0]; ++i) {
          const Label l = m->labels.at(i, j, k);
          if (std::find(child.begin(), child.end(), l) == child.end()) continue;
          const Vec3 p = g.index_to_physical({double(i), double(j), double(k)});
          if (p[2] < joint.centre_mm[2]) continue;
          for (int a = 0; a < 3; ++a) sum[a] += p[a];
          ++n;
        }
    ASSERT_GT(n, 0);
    EXPECT_NEAR(sum[0] / n, joint.centre_mm[0], 2.0) << joint.name;
    EXPECT_NEAR(sum[1] / n, joint.centre_mm[1], 2.0) << joint.name;
  }
}

TEST(Mannequin, IsDeterministic) {
  MannequinParams params;
  params.spacing_mm = 6.0;
  Result<Phantom> a = make_mannequin(params);
  Result<Phantom> b = make_mannequin(params);
  ASSERT_TRUE(a.ok() && b.ok());
  EXPECT_EQ(a->labels.voxels(), b->labels.voxels());
  EXPECT_EQ(a->ct.voxels(), b->ct.voxels());
  params.seed = 2;
  Result<Phantom> c = make_mannequin(params);
  EXPECT_EQ(c->labels.voxels(), a->labels.voxels());
  EXPECT_NE(c->ct.voxels(), a->ct.voxels());
}

TEST(Mannequin, SpacingForAVoxelBudgetLandsNearIt) {
  MannequinParams params;
  for (const int64_t target : {int64_t{1'000'000}, int64_t{5'000'000}}) {
    params.spacing_mm = mannequin_spacing_for_voxels(params, target);
    Result<Phantom> m = make_mannequin(params);
    ASSERT_TRUE(m.ok());
    EXPECT_NEAR(static_cast<double>(m->labels.voxel_count()), static_cast<double>(target), 0.1 * target);
  }
}

TEST(Mannequin, ObliqueGridKeepsJointsInPhysicalSpace) {
  MannequinParams params;
  params.spacing_mm = 5.0;
  const double a = 0.3;
  params.direction = {std::cos(a), -std::sin(a), 0, std::sin(a), std::cos(a), 0, 0, 0, 1};
  Result<Phantom> m = make_mannequin(params);
  ASSERT_TRUE(m.ok());
  for (const JointTruth& joint : m->joints) {
    if (joint.kind != "plane") continue;
    Vec3 below = joint.centre_mm;
    below[2] -= m->joint_gap_mm / 2 + 6.0;
    EXPECT_NE(segment_at(*m, below), "") << joint.name;
  }
}

TEST(Phantoms, BadParametersAreRefused) {
  BarParams bar;
  bar.bone_radius_mm = 40.0;
  EXPECT_EQ(make_bar(bar).status().code(), StatusCode::kInvalidArgument);
  bar = BarParams{};
  bar.spacing_mm = 0.0;
  EXPECT_EQ(make_bar(bar).status().code(), StatusCode::kInvalidArgument);
  bar = BarParams{};
  bar.bone_count = 1;
  EXPECT_EQ(make_bar(bar).status().code(), StatusCode::kInvalidArgument);
  MannequinParams mannequin;
  mannequin.spacing_mm = 0.05;  // ~10^11 voxels
  EXPECT_EQ(make_mannequin(mannequin).status().code(), StatusCode::kResourceExhausted);
  mannequin = MannequinParams{};
  mannequin.spacing_mm = 30.0;
  EXPECT_EQ(make_mannequin(mannequin).status().code(), StatusCode::kInvalidArgument);
  mannequin = MannequinParams{};
  mannequin.direction = {1, 0, 0, 0, 1, 0, 0, 0, 0};
  EXPECT_EQ(make_mannequin(mannequin).status().code(), StatusCode::kInvalidArgument);
}

TEST(Phantoms, JointsJsonListsEveryJoint) {
  Result<Phantom> bar = make_bar(BarParams{});
  ASSERT_TRUE(bar.ok());
  const std::string json = joints_to_json(*bar);
  EXPECT_NE(json.find("\"joint_1_2\""), std::string::npos);
  EXPECT_NE(json.find("\"joint_3_4\""), std::string::npos);
  EXPECT_NE(json.find("centre_mm"), std::string::npos);
}

}  // namespace
}  // namespace posewarp::phantom
