#include "posewarp/phantom/phantom.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <map>
#include <memory>
#include <set>
#include <string>
#include <utility>
#include <vector>

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

// ---- body -------------------------------------------------------------------------------------------------------

double dot3(const Vec3& a, const Vec3& b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}
Vec3 along(const Vec3& p, const Vec3& direction, double mm) {
  return {p[0] + direction[0] * mm, p[1] + direction[1] * mm, p[2] + direction[2] * mm};
}
double voxel_diagonal(const ImageGeometry& g) {
  return std::sqrt(g.spacing[0] * g.spacing[0] + g.spacing[1] * g.spacing[1] + g.spacing[2] * g.spacing[2]);
}

// The centre (physical point) of the voxel of `segment` nearest to `p` within `radius` mm, if any.
bool nearest_voxel_of(const Phantom& phantom, const std::string& segment, const Vec3& p, double radius, Vec3& found) {
  const ImageGeometry& g = phantom.labels.geometry();
  const std::vector<Label> values = phantom.label_map.labels_of_segment(segment);
  const Vec3 centre = g.physical_to_index(p);
  double best = radius;
  bool any = false;
  Index3 reach{};
  for (int a = 0; a < 3; ++a) reach[a] = static_cast<int64_t>(std::ceil(radius / g.spacing[a])) + 1;
  for (int64_t k = std::llround(centre[2]) - reach[2]; k <= std::llround(centre[2]) + reach[2]; ++k)
    for (int64_t j = std::llround(centre[1]) - reach[1]; j <= std::llround(centre[1]) + reach[1]; ++j)
      for (int64_t i = std::llround(centre[0]) - reach[0]; i <= std::llround(centre[0]) + reach[0]; ++i) {
        if (!phantom.labels.contains(i, j, k)) continue;
        if (std::find(values.begin(), values.end(), phantom.labels.at(i, j, k)) == values.end()) continue;
        const Vec3 q = g.index_to_physical({double(i), double(j), double(k)});
        const double d =
            std::sqrt((q[0] - p[0]) * (q[0] - p[0]) + (q[1] - p[1]) * (q[1] - p[1]) + (q[2] - p[2]) * (q[2] - p[2]));
        if (d <= best) best = d, found = q, any = true;
      }
  return any;
}

const JointTruth* find_joint(const Phantom& phantom, const std::string& name) {
  for (const JointTruth& joint : phantom.joints) {
    if (joint.name == name) return &joint;
  }
  return nullptr;
}

// The body at the coarse spacing tests use (about 4M voxels), built once.
class Body : public ::testing::Test {
 protected:
  static BodyParams coarse() {
    BodyParams params;
    params.spacing_mm = {4.0, 4.0, 8.0};
    return params;
  }
  static void SetUpTestSuite() {
    Result<Phantom> made = make_body(coarse());
    ASSERT_TRUE(made.ok()) << made.status().to_string();
    body_ = std::make_unique<Phantom>(std::move(*made));
  }
  static void TearDownTestSuite() { body_.reset(); }
  static const Phantom& body() { return *body_; }
  static inline std::unique_ptr<Phantom> body_;
};

TEST_F(Body, DefaultGridIsObliqueAnisotropicAndHolds15To20MillionVoxels) {
  const BodyParams params;
  EXPECT_LT(params.spacing_mm[0], params.spacing_mm[2]);
  EXPECT_EQ(params.spacing_mm[0], params.spacing_mm[1]);
  const std::array<double, 9>& d = params.direction;
  // A proper rotation by about 8 degrees whose axis is not a coordinate axis.
  const double det =
      d[0] * (d[4] * d[8] - d[5] * d[7]) - d[1] * (d[3] * d[8] - d[5] * d[6]) + d[2] * (d[3] * d[7] - d[4] * d[6]);
  EXPECT_NEAR(det, 1.0, 1e-12);
  const double angle = std::acos((d[0] + d[4] + d[8] - 1.0) / 2.0) * 180.0 / std::acos(-1.0);
  EXPECT_NEAR(angle, 8.0, 0.5);
  for (int axis = 0; axis < 3; ++axis) EXPECT_LT(std::abs(d[4 * axis]), 0.999) << "index axis " << axis << " tilted";
  Result<ImageGeometry> grid = body_grid(params);
  ASSERT_TRUE(grid.ok()) << grid.status().to_string();
  EXPECT_GE(grid->voxel_count(), 15'000'000);
  EXPECT_LE(grid->voxel_count(), 20'000'000);
  EXPECT_TRUE(body().labels.geometry().same_grid(*body_grid(coarse())));
}

TEST_F(Body, LabelMapDeclaresEverySegmentAndATreeOfJointsFromThePelvis) {
  const Phantom& p = body();
  EXPECT_EQ(p.label_map.root_segment(), "pelvis");
  const std::vector<std::string> segments = p.label_map.bone_segments();
  EXPECT_EQ(segments.size(), 27u);
  ASSERT_EQ(p.joints.size(), segments.size() - 1);
  ASSERT_EQ(p.label_map.joint_names().size(), p.joints.size());
  std::map<std::string, int> parents_of;
  std::set<std::string> reached{"pelvis"};
  for (size_t n = 0; n < p.joints.size(); ++n) {
    const JointTruth& joint = p.joints[n];
    const labels::JointName& named = p.label_map.joint_names()[n];
    EXPECT_EQ(named.name, joint.name);
    EXPECT_EQ(named.segment_a, joint.parent_segment) << "the parent comes first";
    EXPECT_EQ(named.segment_b, joint.child_segment);
    EXPECT_TRUE(reached.count(joint.parent_segment)) << joint.name << ": parent declared after its child";
    reached.insert(joint.child_segment);
    ++parents_of[joint.child_segment];
  }
  EXPECT_EQ(reached.size(), segments.size());
  for (const auto& [child, count] : parents_of) EXPECT_EQ(count, 1) << child;
  const labels::LabelCensus census = labels::census(p.label_map, p.labels);
  EXPECT_TRUE(census.unknown.empty());
  EXPECT_TRUE(census.absent.empty());
  EXPECT_TRUE(census.absent_bone_segments.empty());
  for (const char* tissue : {"soft_tissue", "fat", "liver", "brain"}) {
    bool named = false;
    for (const labels::LabelEntry& entry : p.label_map.entries()) named |= entry.name == tissue;
    EXPECT_TRUE(named) << tissue;
  }
}

TEST_F(Body, PlaneJointCentresLieInSoftTissueBetweenParentAndChild) {
  const Phantom& p = body();
  const double gap = p.joint_gap_mm;
  const double diag = voxel_diagonal(p.labels.geometry());
  int planes = 0;
  for (const JointTruth& joint : p.joints) {
    if (joint.kind != "plane") continue;
    SCOPED_TRACE(joint.name);
    ++planes;
    EXPECT_EQ(label_at(p.labels, joint.centre_mm), 1) << "soft tissue at the centre";
    EXPECT_EQ(joint.axis, (Vec3{0, 0, 0}));
    Vec3 parent{}, child{};
    ASSERT_TRUE(nearest_voxel_of(p, joint.parent_segment, joint.centre_mm, gap / 2 + diag, parent));
    ASSERT_TRUE(nearest_voxel_of(p, joint.child_segment, joint.centre_mm, gap / 2 + diag, child));
    // Parent and child lie on opposite sides of the centre.
    const Vec3 to_parent{parent[0] - joint.centre_mm[0], parent[1] - joint.centre_mm[1],
                         parent[2] - joint.centre_mm[2]};
    const Vec3 to_child{child[0] - joint.centre_mm[0], child[1] - joint.centre_mm[1], child[2] - joint.centre_mm[2]};
    EXPECT_LT(dot3(to_parent, to_child), 0.0);
  }
  EXPECT_EQ(planes, 14);
}

TEST_F(Body, BallJointCentresAreTheCentresOfTheHeads) {
  const Phantom& p = body();
  const double diag = voxel_diagonal(p.labels.geometry());
  const std::map<std::string, double> head_radius{{"hip_left", 24.0},      {"hip_right", 24.0},
                                                  {"shoulder_left", 22.0}, {"shoulder_right", 22.0},
                                                  {"wrist_left", 11.0},    {"wrist_right", 11.0}};
  int balls = 0;
  for (const JointTruth& joint : p.joints) {
    if (joint.kind != "ball") continue;
    SCOPED_TRACE(joint.name);
    ++balls;
    ASSERT_TRUE(head_radius.count(joint.name));
    const double r = head_radius.at(joint.name);
    EXPECT_EQ(segment_at(p, joint.centre_mm), joint.child_segment);
    for (int axis = 0; axis < 3; ++axis) {
      for (double sign : {-1.0, 1.0}) {
        Vec3 direction{0, 0, 0};
        direction[axis] = sign;
        EXPECT_EQ(segment_at(p, along(joint.centre_mm, direction, 0.8 * r)), joint.child_segment)
            << "axis " << axis << " sign " << sign;
      }
    }
    Vec3 socket{};
    EXPECT_TRUE(nearest_voxel_of(p, joint.parent_segment, joint.centre_mm, r + p.joint_gap_mm + diag, socket));
  }
  EXPECT_EQ(balls, 6);
}

TEST_F(Body, HingeAxesRunAlongTheirBoneCylinders) {
  const Phantom& p = body();
  const double diag = voxel_diagonal(p.labels.geometry());
  // How far along the axis the hinge cylinder still holds bone (0.8 of its half-length or more), and its radius.
  const std::map<std::string, std::pair<double, double>> reach{
      {"knee", {30.0, 22.0}}, {"elbow", {17.0, 13.0}}, {"ankle", {14.0, 18.0}}};
  int hinges = 0;
  for (const JointTruth& joint : p.joints) {
    if (joint.kind != "hinge") continue;
    SCOPED_TRACE(joint.name);
    ++hinges;
    EXPECT_EQ(joint.axis, (Vec3{1, 0, 0})) << "unit, to the patient's left";
    const std::string kind = joint.name.substr(0, joint.name.find('_'));
    ASSERT_TRUE(reach.count(kind));
    const auto [along_mm, radius] = reach.at(kind);
    const std::string bone = segment_at(p, joint.centre_mm);
    EXPECT_TRUE(bone == joint.parent_segment || bone == joint.child_segment) << bone;
    if (kind == "knee") {
      EXPECT_EQ(bone, joint.parent_segment) << "the condyles are the femur's";
    }
    EXPECT_EQ(segment_at(p, along(joint.centre_mm, joint.axis, along_mm)), bone);
    EXPECT_EQ(segment_at(p, along(joint.centre_mm, joint.axis, -along_mm)), bone);
    const std::string other = bone == joint.parent_segment ? joint.child_segment : joint.parent_segment;
    Vec3 partner{};
    EXPECT_TRUE(nearest_voxel_of(p, other, joint.centre_mm, radius + p.joint_gap_mm + diag, partner));
    // Not touching: the partner's nearest voxel is beyond the cylinder.
    const double d = std::hypot(partner[1] - joint.centre_mm[1], partner[2] - joint.centre_mm[2]);
    EXPECT_GE(d, radius + p.joint_gap_mm - diag);
  }
  EXPECT_EQ(hinges, 6);
}

// Walks the x line (y = 0) at height z from x0 to x1 and returns the labels met, in order.
std::vector<Label> labels_along_x(const Phantom& p, double z, double x0, double x1) {
  std::vector<Label> met;
  const double step = 0.5;
  for (double x = x0; (x1 - x) * (x1 - x0) >= 0.0; x += (x1 > x0 ? step : -step)) {
    met.push_back(label_at(p.labels, {x, 0.0, z}));
  }
  return met;
}

// True when, going along `met`, there is no background between the last voxel of `from` and the first voxel of
// `to` that follows it, and both are met.
bool no_air_between(const Phantom& p, const std::vector<Label>& met, const std::string& from, const std::string& to) {
  auto segment_of = [&](Label v) {
    const labels::LabelEntry* e = p.label_map.find(v);
    return e && e->role == labels::LabelRole::kBone ? e->segment : std::string();
  };
  size_t first_to = met.size();
  for (size_t n = 0; n < met.size(); ++n) {
    if (segment_of(met[n]) == to) {
      first_to = n;
      break;
    }
  }
  if (first_to == met.size()) return false;
  size_t last_from = met.size();
  for (size_t n = 0; n < first_to; ++n) {
    if (segment_of(met[n]) == from) last_from = n;
  }
  if (last_from == met.size()) return false;
  for (size_t n = last_from; n < first_to; ++n) {
    if (met[n] == 0) return false;
  }
  return true;
}

TEST_F(Body, UpperArmsRestAgainstTheTrunk) {
  const Phantom& p = body();
  for (const char* side : {"left", "right"}) {
    SCOPED_TRACE(side);
    const JointTruth* shoulder = find_joint(p, std::string("shoulder_") + side);
    const JointTruth* elbow = find_joint(p, std::string("elbow_") + side);
    ASSERT_TRUE(shoulder && elbow);
    const double z = 0.5 * (shoulder->centre_mm[2] + elbow->centre_mm[2]);
    const double outside = shoulder->centre_mm[0] > 0 ? 300.0 : -300.0;
    EXPECT_TRUE(no_air_between(p, labels_along_x(p, z, 0.0, outside), "thorax", std::string("humerus_") + side));
  }
  std::set<std::pair<std::string, std::string>> contacts(p.skin_contacts.begin(), p.skin_contacts.end());
  EXPECT_TRUE(contacts.count({"arm_left", "trunk"}) && contacts.count({"arm_right", "trunk"}));
}

TEST_F(Body, ThighsTouchAtTheMidline) {
  const Phantom& p = body();
  const JointTruth* knee = find_joint(p, "knee_left");
  const JointTruth* hip = find_joint(p, "hip_left");
  ASSERT_TRUE(knee && hip);
  for (double z = knee->centre_mm[2]; z <= hip->centre_mm[2]; z += 2.0) {
    EXPECT_NE(label_at(p.labels, {0.0, 0.0, z}), 0) << "air between the thighs at z = " << z;
  }
  std::set<std::pair<std::string, std::string>> contacts(p.skin_contacts.begin(), p.skin_contacts.end());
  EXPECT_TRUE(contacts.count({"thigh_left", "thigh_right"}));
}

TEST_F(Body, HandsRestOnTheLateralThighs) {
  const Phantom& p = body();
  for (const char* side : {"left", "right"}) {
    SCOPED_TRACE(side);
    const JointTruth* wrist = find_joint(p, std::string("wrist_") + side);
    ASSERT_TRUE(wrist);
    const double z = wrist->centre_mm[2] - 80.0;
    const double outside = wrist->centre_mm[0] > 0 ? 300.0 : -300.0;
    EXPECT_TRUE(no_air_between(p, labels_along_x(p, z, 0.0, outside), std::string("femur_") + side,
                               std::string("hand_") + side));
  }
}

TEST_F(Body, ScapulaeLieOnTheRibs) {
  const Phantom& p = body();
  const ImageGeometry& g = p.labels.geometry();
  Label ribs = 0;
  std::map<Label, std::string> scapulae;
  for (const labels::LabelEntry& entry : p.label_map.entries()) {
    if (entry.name == "ribs") ribs = entry.value;
    if (entry.segment.rfind("scapula_", 0) == 0) scapulae[entry.value] = entry.segment;
  }
  ASSERT_NE(ribs, 0);
  ASSERT_EQ(scapulae.size(), 2u);
  std::map<std::string, int> touching;
  for (int64_t k = 1; k + 1 < g.size[2]; ++k)
    for (int64_t j = 1; j + 1 < g.size[1]; ++j)
      for (int64_t i = 1; i + 1 < g.size[0]; ++i) {
        auto it = scapulae.find(p.labels.at(i, j, k));
        if (it == scapulae.end()) continue;
        bool next_to_rib = false;
        for (int dk = -1; dk <= 1; ++dk)
          for (int dj = -1; dj <= 1; ++dj)
            for (int di = -1; di <= 1; ++di) next_to_rib |= p.labels.at(i + di, j + dj, k + dk) == ribs;
        touching[it->second] += next_to_rib;
      }
  EXPECT_GE(touching["scapula_left"], 20);
  EXPECT_GE(touching["scapula_right"], 20);
}

// The smallest distance between voxel centres of every pair of bone segments that come within `radius` mm.
std::map<std::pair<std::string, std::string>, double> closest_segment_pairs(const Phantom& p, double radius) {
  const ImageGeometry& g = p.labels.geometry();
  std::map<Label, int> segment_index;
  const std::vector<std::string> segments = p.label_map.bone_segments();
  for (size_t s = 0; s < segments.size(); ++s) {
    for (Label v : p.label_map.labels_of_segment(segments[s])) segment_index[v] = static_cast<int>(s);
  }
  std::vector<int> seg(static_cast<size_t>(p.labels.voxel_count()), -1);
  for (int64_t v = 0; v < p.labels.voxel_count(); ++v) {
    auto it = segment_index.find(p.labels.data()[v]);
    if (it != segment_index.end()) seg[static_cast<size_t>(v)] = it->second;
  }
  std::vector<std::array<int64_t, 3>> offsets;
  std::vector<double> lengths;
  Index3 reach{};
  for (int a = 0; a < 3; ++a) reach[a] = static_cast<int64_t>(std::floor(radius / g.spacing[a]));
  for (int64_t dk = -reach[2]; dk <= reach[2]; ++dk)
    for (int64_t dj = -reach[1]; dj <= reach[1]; ++dj)
      for (int64_t di = -reach[0]; di <= reach[0]; ++di) {
        const double d =
            std::sqrt(std::pow(di * g.spacing[0], 2) + std::pow(dj * g.spacing[1], 2) + std::pow(dk * g.spacing[2], 2));
        if (d > 0.0 && d <= radius) offsets.push_back({di, dj, dk}), lengths.push_back(d);
      }
  std::vector<std::vector<double>> best(segments.size(), std::vector<double>(segments.size(), 1e9));
  for (int64_t k = 0; k < g.size[2]; ++k)
    for (int64_t j = 0; j < g.size[1]; ++j)
      for (int64_t i = 0; i < g.size[0]; ++i) {
        const int a = seg[static_cast<size_t>(g.offset(i, j, k))];
        if (a < 0) continue;
        for (size_t o = 0; o < offsets.size(); ++o) {
          const int64_t ii = i + offsets[o][0], jj = j + offsets[o][1], kk = k + offsets[o][2];
          if (!p.labels.contains(ii, jj, kk)) continue;
          const int b = seg[static_cast<size_t>(g.offset(ii, jj, kk))];
          if (b <= a) continue;
          best[a][b] = std::min(best[a][b], lengths[o]);
        }
      }
  std::map<std::pair<std::string, std::string>, double> pairs;
  for (size_t a = 0; a < segments.size(); ++a)
    for (size_t b = a + 1; b < segments.size(); ++b) {
      if (best[a][b] < 1e9)
        pairs[{std::min(segments[a], segments[b]), std::max(segments[a], segments[b])}] = best[a][b];
    }
  return pairs;
}

TEST_F(Body, OnlyJointPartnersComeWithinTheGapAndScapulaeTouchTheRibs) {
  const Phantom& p = body();
  const double gap = p.joint_gap_mm;
  const double diag = voxel_diagonal(p.labels.geometry());
  const auto pairs = closest_segment_pairs(p, gap + diag);
  std::set<std::pair<std::string, std::string>> joints;
  for (const JointTruth& joint : p.joints) {
    joints.insert(
        {std::min(joint.parent_segment, joint.child_segment), std::max(joint.parent_segment, joint.child_segment)});
  }
  const double max_spacing = *std::max_element(p.labels.geometry().spacing.begin(), p.labels.geometry().spacing.end());
  for (const auto& [pair, distance] : pairs) {
    SCOPED_TRACE(pair.first + " - " + pair.second + ": " + std::to_string(distance) + " mm");
    if (pair.first == "scapula_left" || pair.first == "scapula_right") {
      if (pair.second == "thorax") {
        EXPECT_LE(distance, max_spacing + 1e-9) << "a scapula touches the ribs";
        continue;
      }
    }
    EXPECT_GE(distance, gap - 1e-6) << "bones closer than the joint gap";
    if (!joints.count(pair)) ADD_FAILURE() << "segments within the gap + a voxel that share no joint";
  }
  for (const auto& pair : joints) {
    EXPECT_TRUE(pairs.count(pair)) << pair.first << " - " << pair.second << " are further apart than gap + a voxel";
  }
}

TEST(BodyPhantom, IsDeterministicAndTheSeedOnlyChangesTheNoise) {
  BodyParams params;
  params.spacing_mm = {6.0, 6.0, 10.0};
  Result<Phantom> a = make_body(params);
  Result<Phantom> b = make_body(params);
  ASSERT_TRUE(a.ok() && b.ok()) << a.status().to_string();
  EXPECT_EQ(a->labels.voxels(), b->labels.voxels());
  EXPECT_EQ(a->ct.voxels(), b->ct.voxels());
  params.seed = 2;
  Result<Phantom> c = make_body(params);
  ASSERT_TRUE(c.ok());
  EXPECT_EQ(c->labels.voxels(), a->labels.voxels());
  EXPECT_NE(c->ct.voxels(), a->ct.voxels());
}

// A heavier body on the same skeleton (the skin 15 mm further out, 25 mm of fat): its grid grows to hold it, every
// joint stays where it was, the bones keep their volume (to the resampling of thin bones on the moved grid), and
// the soft tissue grows.
TEST(BodyPhantom, AHeavierBodyKeepsItsSkeletonUnderMoreSoftTissue) {
  BodyParams params;
  params.spacing_mm = {6.0, 6.0, 10.0};
  BodyParams heavier = params;
  heavier.skin_offset_mm = 15.0;
  heavier.fat_mm = 25.0;
  Result<Phantom> a = make_body(params);
  Result<Phantom> b = make_body(heavier);
  ASSERT_TRUE(a.ok() && b.ok()) << b.status().to_string();
  EXPECT_GT(b->labels.geometry().voxel_count(), a->labels.geometry().voxel_count());
  ASSERT_EQ(a->joints.size(), b->joints.size());
  for (size_t j = 0; j < a->joints.size(); ++j) {
    for (int axis = 0; axis < 3; ++axis) EXPECT_EQ(a->joints[j].centre_mm[axis], b->joints[j].centre_mm[axis]);
  }
  const auto volumes = [](const Phantom& p) {
    std::map<Label, double> ml;
    const Vec3& s = p.labels.geometry().spacing;
    for (const Label l : p.labels.voxels()) ml[l] += s[0] * s[1] * s[2] / 1000.0;
    return ml;
  };
  const std::map<Label, double> before = volumes(*a), after = volumes(*b);
  double soft_before = 0, soft_after = 0, bone_before = 0, bone_after = 0;
  for (const LabelEntry& e : a->label_map.entries()) {
    if (e.value == 0) continue;
    const double was = before.count(e.value) ? before.at(e.value) : 0.0;
    const double is = after.count(e.value) ? after.at(e.value) : 0.0;
    (e.role == LabelRole::kBone ? bone_before : soft_before) += was;
    (e.role == LabelRole::kBone ? bone_after : soft_after) += is;
  }
  EXPECT_NEAR(bone_after, bone_before, 0.03 * bone_before);
  EXPECT_GT(soft_after, 1.25 * soft_before);
  heavier.skin_offset_mm = 150.0;
  EXPECT_EQ(make_body(heavier).status().code(), StatusCode::kInvalidArgument);
}

TEST(BodyPhantom, SpacingForAVoxelBudgetKeepsTheAnisotropy) {
  BodyParams params;
  for (const int64_t target : {int64_t{4'000'000}, int64_t{18'000'000}}) {
    const Vec3 spacing = body_spacing_for_voxels(params, target);
    EXPECT_NEAR(spacing[2] / spacing[0], params.spacing_mm[2] / params.spacing_mm[0], 1e-9);
    EXPECT_NEAR(spacing[1] / spacing[0], params.spacing_mm[1] / params.spacing_mm[0], 1e-9);
    BodyParams scaled = params;
    scaled.spacing_mm = spacing;
    Result<ImageGeometry> grid = body_grid(scaled);
    ASSERT_TRUE(grid.ok());
    EXPECT_NEAR(static_cast<double>(grid->voxel_count()), static_cast<double>(target), 0.05 * target);
  }
}

TEST(BodyPhantom, BadParametersAreRefusedWithTheirName) {
  BodyParams params;
  params.spacing_mm = {2.0, 0.0, 4.0};
  Status status = make_body(params).status();
  EXPECT_EQ(status.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(status.message().find("spacing"), std::string::npos);
  params = BodyParams{};
  params.spacing_mm = {0.05, 0.05, 0.1};
  EXPECT_EQ(make_body(params).status().code(), StatusCode::kResourceExhausted);
  params = BodyParams{};
  params.spacing_mm = {4.0, 4.0, 12.0};
  EXPECT_EQ(make_body(params).status().code(), StatusCode::kInvalidArgument);
  params = BodyParams{};
  params.joint_gap_mm = 40.0;
  status = make_body(params).status();
  EXPECT_EQ(status.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(status.message().find("gap"), std::string::npos);
  params = BodyParams{};
  params.height_mm = 100.0;
  EXPECT_EQ(make_body(params).status().code(), StatusCode::kInvalidArgument);
  params = BodyParams{};
  params.direction = {1, 0, 0, 0, 1, 0, 0, 0, 0};
  EXPECT_EQ(make_body(params).status().code(), StatusCode::kInvalidArgument);
}

TEST_F(Body, JointsJsonWritesHingeAxesAndSkinContacts) {
  const std::string json = joints_to_json(body());
  EXPECT_NE(json.find("\"knee_left\""), std::string::npos);
  EXPECT_NE(json.find("\"hinge\""), std::string::npos);
  EXPECT_NE(json.find("\"axis\""), std::string::npos);
  EXPECT_NE(json.find("\"skin_contacts\""), std::string::npos);
  EXPECT_NE(json.find("\"thigh_right\""), std::string::npos);
}

TEST(Phantoms, RotationDirectionIsARotationAboutItsAxis) {
  const std::array<double, 9> r = rotation_direction({0.0, 0.0, 2.0}, 90.0);
  const std::array<double, 9> expected{0, -1, 0, 1, 0, 0, 0, 0, 1};
  for (int n = 0; n < 9; ++n) EXPECT_NEAR(r[n], expected[n], 1e-12);
}

}  // namespace
}  // namespace posewarp::phantom
