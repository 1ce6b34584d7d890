// Posing the anatomical body phantom (arms against the trunk, thighs touching, condyles, a shallow glenoid, an
// oblique anisotropic grid): what a radiologist would check, measured independently of the report.
#include <gtest/gtest.h>

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <map>

#include "posewarp/api/joint_range.h"
#include "posewarp/api/pose_engine.h"
#include "posewarp/api/rig.h"
#include "posewarp/api/rig_info.h"
#include "posewarp/labels/body.h"
#include "posewarp/phantom/phantom.h"
#include "posewarp/pose/pose.h"
#include "posewarp/rig/skin_contacts.h"

namespace posewarp::api {
namespace {

struct BodyRig {
  phantom::Phantom phantom;
  std::optional<PoseEngine> engine;
};

// One rig of the body phantom at 4 x 4 x 8 mm for every test here (about 6 s to build).
const BodyRig& body_rig() {
  static const BodyRig rig = [] {
    BodyRig r;
    phantom::BodyParams params;
    params.spacing_mm = {4.0, 4.0, 8.0};
    r.phantom = phantom::make_body(params).value();
    BuildInputs inputs;
    inputs.labels = r.phantom.labels;
    inputs.ct = r.phantom.ct;
    inputs.label_map = r.phantom.label_map;
    BuildParams build;
    build.mesh.parallel = false;  // the same mesh every run
    Result<Rig> built = build_rig(inputs, build, {});
    if (!built.ok()) throw std::runtime_error(built.status().to_string());
    Result<PoseEngine> engine = PoseEngine::create(std::move(built).value());
    if (!engine.ok()) throw std::runtime_error(engine.status().to_string());
    r.engine.emplace(std::move(engine).value());
    return r;
  }();
  return rig;
}

Pose single(const std::string& joint, double flexion, double abduction = 0.0) {
  Pose p;
  p.name = joint;
  p.joints.push_back(pose::anatomical_rotation(joint, flexion, abduction));
  return p;
}

Result<PoseResult> run(const Pose& p, api::Method method, bool fields = true) {
  PoseRequest request;
  request.pose = p;
  request.method = method;
  request.grid = api::GridPolicy::kGrow;
  request.want_ct = false;
  request.want_surfaces = false;
  request.want_fields = fields;
  return body_rig().engine->pose(request);
}

Eigen::Vector3d physical(const ImageGeometry& g, int64_t i, int64_t j, int64_t k) {
  const Vec3 p = g.index_to_physical({double(i), double(j), double(k)});
  return {p[0], p[1], p[2]};
}

// The segment of a label value (-1 for soft tissue).
std::map<Label, int> segment_of_labels(const rig::Skeleton& skeleton) {
  std::map<Label, int> segment;
  for (size_t k = 0; k < skeleton.segments.size(); ++k) {
    for (const Label v : skeleton.segments[k].labels) segment[v] = static_cast<int>(k);
  }
  return segment;
}

const std::vector<std::pair<std::string, Pose>>& test_poses() {
  static const std::vector<std::pair<std::string, Pose>> poses{
      {"knee flexion 90", single("knee_left", 90)},
      {"elbow flexion 90", single("elbow_right", 90)},
      {"shoulder abduction 90", single("shoulder_left", 0, 90)},
      {"hip flexion 90", single("hip_right", 90)}};
  return poses;
}

// Every output voxel holding a bone's label samples, through the exported inverse field, a source point within half
// a voxel (per axis) of where that bone's own rigid inverse puts it: bones do not bend, for every method.
TEST(BodyPosing, EveryBoneVoxelFollowsItsBoneRigidlyForEveryMethod) {
  const Rig& rig = body_rig().engine->rig();
  const std::map<Label, int> segment_of = segment_of_labels(rig.skeleton);
  const ImageGeometry& source = rig.labels.geometry();
  for (const auto& [name, p] : test_poses()) {
    for (const api::Method method : {api::Method::kCor, api::Method::kDqs, api::Method::kLbs}) {
      SCOPED_TRACE(name + ", " + std::string(api::method_name(method)));
      Result<PoseResult> result = run(p, method);
      ASSERT_TRUE(result.ok()) << result.status().to_string();
      const ImageGeometry& out = result->output_grid;
      double worst = 0.0;
      int64_t bone_voxels = 0;
      for (int64_t k = 0; k < out.size[2]; ++k) {
        for (int64_t j = 0; j < out.size[1]; ++j) {
          for (int64_t i = 0; i < out.size[0]; ++i) {
            const int64_t v = out.offset(i, j, k);
            const auto it = segment_of.find(result->labels->data()[v]);
            if (it == segment_of.end()) continue;
            ++bone_voxels;
            const Eigen::Vector3d x = physical(out, i, j, k);
            const Eigen::Vector3d sampled =
                x + Eigen::Vector3d(result->inverse_field[static_cast<size_t>(3 * v)],
                                    result->inverse_field[static_cast<size_t>(3 * v + 1)],
                                    result->inverse_field[static_cast<size_t>(3 * v + 2)]);
            const size_t s = static_cast<size_t>(it->second);
            const Eigen::Vector3d rigid =
                result->segment_rotation[s].transpose() * (x - result->segment_translation[s]);
            const Vec3 a = source.physical_to_index({sampled.x(), sampled.y(), sampled.z()});
            const Vec3 b = source.physical_to_index({rigid.x(), rigid.y(), rigid.z()});
            for (int axis = 0; axis < 3; ++axis) worst = std::max(worst, std::abs(a[axis] - b[axis]));
          }
        }
      }
      EXPECT_GT(bone_voxels, 10000);
      EXPECT_LE(worst, 0.5 + 1e-6) << "voxels";
      // The report says the same.
      EXPECT_LE(result->report.bone_voxel_deviation_mm, 0.5 * std::max({source.spacing[0], source.spacing[1], source.spacing[2]}));
    }
  }
}

// Issue 21's poses and the knee bent further: the joints' fitted centres and axes keep every bone out of its
// neighbours (under 1 ml overlapping; the bones move alike whatever the method). At the elbow it takes the humerus's
// coronoid fossa, which holds the rim of the forearm's notch at 90 degrees (scripts/body_check's 2.5 x 2.5 x 5 mm rig
// overlapped 1.2 ml there without it; this coarser grid did not). Bent to 120 degrees the rim reaches the humerus's
// posterior column: 1.0 ml here, none at 2.5 mm.
TEST(BodyPosing, BentJointsKeepTheirBonesApart) {
  std::vector<std::pair<std::string, Pose>> poses = test_poses();
  poses.emplace_back("knee flexion 120", single("knee_left", 120));
  for (const auto& [name, p] : poses) {
    Result<PoseResult> cor = run(p, api::Method::kCor, false);
    ASSERT_TRUE(cor.ok()) << cor.status().to_string();
    double overlap_ml = 0.0;
    for (const BoneOverlap& o : cor->report.bone_overlaps) overlap_ml += o.volume_ml;
    EXPECT_LT(overlap_ml, 1.0) << name;
  }
}

// Hinges flexed 90 degrees about their fitted axes: CoR keeps the soft tissue around the joint within 10% where LBS
// loses more.
TEST(BodyPosing, HingesFlexAndCorKeepsLocalVolume) {
  for (const auto& [joint, name] : std::vector<std::pair<std::string, std::string>>{{"knee_left", "knee"},
                                                                                    {"elbow_right", "elbow"}}) {
    SCOPED_TRACE(name);
    Result<PoseResult> cor = run(single(joint, 90), api::Method::kCor, false);
    Result<PoseResult> lbs = run(single(joint, 90), api::Method::kLbs, false);
    ASSERT_TRUE(cor.ok() && lbs.ok());
    const JointRegionChange* cor_100 = nullptr;
    const JointRegionChange* lbs_100 = nullptr;
    for (const auto& c : cor->report.joint_regions) if (c.radius_mm == 100.0) cor_100 = &c;
    for (const auto& c : lbs->report.joint_regions) if (c.radius_mm == 100.0) lbs_100 = &c;
    ASSERT_NE(cor_100, nullptr);
    ASSERT_NE(lbs_100, nullptr);
    EXPECT_EQ(cor_100->joint, joint);
    EXPECT_LT(std::abs(cor_100->volume_change), 0.10);
    EXPECT_LT(std::abs(cor_100->volume_change), std::abs(lbs_100->volume_change));
  }
}

// The soft tissue's steady state (fem) where the body phantom shows skinning's failures: knee and elbow at 90, the
// forearm against the upper arm at elbow 120: bones as CoR puts them, the tissue within 50 mm within 5% of its
// volume, less than half CoR's folded tissue around the joint (the untangling turns back what the steady state folds
// but for tets held by bone at every corner, and contact between the tissue of thigh and calf is not modelled). The arm
// lifted 30 degrees from the trunk it rests against: fem keeps the tissue's volume and leaves nothing folded.
TEST(BodyPosing, FemFoldsLessTissueThanCorAtBentJoints) {
  struct Case {
    std::string name;
    Pose pose;
    std::string joint;
  };
  for (const Case& c : std::vector<Case>{{"knee 90", single("knee_left", 90), "knee_left"},
                                         {"elbow 90", single("elbow_right", 90), "elbow_right"},
                                         {"elbow 120", single("elbow_right", 120), "elbow_right"},
                                         {"shoulder abduction 30", single("shoulder_left", 0, 30), "shoulder_left"}}) {
    SCOPED_TRACE(c.name);
    Result<PoseResult> cor = run(c.pose, api::Method::kCor, false);
    Result<PoseResult> fem = run(c.pose, api::Method::kFem, false);
    ASSERT_TRUE(cor.ok() && fem.ok()) << fem.status().to_string();
    EXPECT_EQ(fem->report.method, "fem");
    EXPECT_EQ(fem->report.bone_voxel_deviation_mm, cor->report.bone_voxel_deviation_mm);
    for (const double radius : {50.0, 100.0}) {
      const JointRegionChange *cr = nullptr, *fr = nullptr;
      for (const auto& r : cor->report.joint_regions) if (r.radius_mm == radius) cr = &r;
      for (const auto& r : fem->report.joint_regions) if (r.radius_mm == radius) fr = &r;
      ASSERT_NE(cr, nullptr);
      ASSERT_NE(fr, nullptr);
      EXPECT_EQ(fr->joint, c.joint);
      std::cout << c.name << " within " << radius << " mm: volume cor " << cr->volume_change << ", fem "
                << fr->volume_change << "; folded cor " << cr->folded_fraction << ", fem " << fr->folded_fraction
                << "; skin vertices inside the tissue facing them cor " << cr->skin_inside_tissue << " + "
                << cr->skin_inside_bone << ", fem " << fr->skin_inside_tissue << " + " << fr->skin_inside_bone << " of "
                << fr->skin_vertices << "\n";
      EXPECT_EQ(fr->skin_vertices, cr->skin_vertices);  // the same rest skin, whatever the method
      if (c.name == "shoulder abduction 30") {
        EXPECT_LT(std::abs(fr->volume_change), 0.02);
        EXPECT_LT(fr->folded_fraction, 0.01);
      } else {
        EXPECT_LT(fr->folded_fraction, 0.5 * cr->folded_fraction) << radius;  // 0.19-0.41 with the untangling
        // The 1% (CoR 9-15% within 50 mm): measured 0.16-0.24% within 50 mm, with the joints' gaps cut.
        EXPECT_LT(fr->folded_fraction, 0.01) << radius;
        if (radius == 100.0) {
          EXPECT_LT(std::abs(fr->volume_change), 0.10);
        } else {  // the issue's +-5% (CoR -7 to -14%); measured -0.8 to -2.5% (-0.6 to -1.9% with the gaps whole)
          EXPECT_LT(std::abs(fr->volume_change), 0.05);
        }
      }
    }
    EXPECT_LE(fem->report.mesh.inverted_tets, cor->report.mesh.inverted_tets);
    // Bones keep exactly CoR's voxels (rigid whatever the method; a rotated bone resampled on this 4 x 4 x 8 mm grid
    // differs from rest by up to 2%), and the soft labels keep their volume within 1% of rest, but where the bent
    // forearm passes into the abdomen (no contact between body parts yet): the liver there loses about 2%.
    const labels::LabelMap& map = body_rig().engine->rig().label_map;
    for (const auto& [label, counts] : fem->report.labels.voxels) {
      if (label == 0 || counts.first < 1000) continue;  // background grows with the grid
      const double change = static_cast<double>(counts.second) / static_cast<double>(counts.first) - 1.0;
      if (map.role_of(label) == labels::LabelRole::kBone) {
        EXPECT_EQ(counts.second, cor->report.labels.voxels.at(label).second) << "bone label " << label;
      } else if (c.joint != "elbow_right" || map.find(label)->name != "liver") {
        EXPECT_LT(std::abs(change), 0.01) << "label " << label;
      }
    }
    if (c.name == "knee 90") {
      // Without contact the back of the thigh passes into the calf (issue 21, item 2, still open): the report says
      // so rather than hiding it.
      const JointRegionChange& cr = cor->report.joint_regions.back();
      ASSERT_EQ(cr.radius_mm, 100.0);
      EXPECT_GT(cr.skin_inside_tissue, 0);
      EXPECT_TRUE(std::any_of(cor->report.warnings.begin(), cor->report.warnings.end(), [](const std::string& w) {
        return w.find("a crease without contact") != std::string::npos;
      })) << "no crease warning";
    }
  }
}

// rig info says why each joint is where it is: the fit and its radius for balls (wrists on the carpal head too) and
// hinges, the declared kind for plane joints.
TEST(BodyPosing, RigInfoSaysWhyEachJointIsWhereItIs) {
  const SkeletonInfo info = describe_skeleton(body_rig().engine->rig());
  std::map<std::string, std::string> why;
  for (const JointInfo& joint : info.joints) why[joint.name] = joint.placed_because;
  for (const char* ball : {"hip_left", "shoulder_right", "wrist_left", "wrist_right"}) {
    EXPECT_EQ(why[ball].rfind("a sphere of radius", 0), 0u) << ball << ": " << why[ball];
  }
  for (const char* hinge : {"knee_left", "elbow_right", "ankle_left"}) {
    EXPECT_EQ(why[hinge].rfind("a cylinder of radius", 0), 0u) << hinge << ": " << why[hinge];
  }
  EXPECT_EQ(why["L4_L5"].rfind("declared a plane joint", 0), 0u) << why["L4_L5"];
}

// Each joint's range on this study: flexion for hinges, flexion and abduction for balls and planes; the knee bends
// past 90 degrees, the arm resting against the trunk cannot be adducted, and posing a joint well past where its
// range stops drives its bones into another bone, as the report's overlap shows.
TEST(BodyPosing, JointRangesSayWhereBonesMeet) {
  const Rig& rig = body_rig().engine->rig();
  Result<std::vector<JointRange>> ranges = joint_ranges(rig);
  ASSERT_TRUE(ranges.ok()) << ranges.status().to_string();
  ASSERT_EQ(ranges->size(), rig.skeleton.joints.size());
  std::map<std::string, std::map<std::string, MotionRange>> by_joint;
  for (size_t j = 0; j < ranges->size(); ++j) {
    const JointRange& r = (*ranges)[j];
    EXPECT_EQ(r.joint, rig.skeleton.joints[j].name);
    EXPECT_EQ(r.motions.size(), rig.skeleton.joints[j].kind == labels::JointKind::kHinge ? 1u : 2u) << r.joint;
    // The build measured the same ranges and keeps them with the joint (rig info and GetRig read them there).
    ASSERT_EQ(rig.skeleton.joints[j].ranges.size(), r.motions.size()) << r.joint;
    for (size_t m = 0; m < r.motions.size(); ++m) {
      EXPECT_EQ(rig.skeleton.joints[j].ranges[m].motion, r.motions[m].motion);
      EXPECT_EQ(rig.skeleton.joints[j].ranges[m].positive_deg, r.motions[m].positive_deg) << r.joint;
      EXPECT_EQ(rig.skeleton.joints[j].ranges[m].negative_stopped, r.motions[m].negative_stopped) << r.joint;
    }
    for (const MotionRange& m : r.motions) {
      by_joint[r.joint][m.motion] = m;
      std::cout << r.joint << " " << m.motion << " " << -m.negative_deg << " .. " << m.positive_deg << "\n";
    }
  }
  const MotionRange& knee = by_joint["knee_left"]["flexion"];
  EXPECT_GE(knee.positive_deg, 90.0);
  EXPECT_TRUE(by_joint["shoulder_left"]["abduction"].negative_stopped);
  EXPECT_LE(by_joint["shoulder_left"]["abduction"].negative_deg, 10.0);
  // Past the knee's stop, the posed bones overlap.
  ASSERT_TRUE(knee.positive_stopped);
  const double past_deg = std::min(knee.positive_deg + 25.0, 150.0);
  Result<PoseResult> past = run(single("knee_left", past_deg), api::Method::kCor, false);
  ASSERT_TRUE(past.ok());
  double overlap_ml = 0.0;
  for (const BoneOverlap& o : past->report.bone_overlaps) overlap_ml += o.volume_ml;
  EXPECT_GT(overlap_ml, 0.5);
  // ... and the report says the pose is past the knee's range, with the pose's angle, whether the pose gave angles
  // or a quaternion; a pose within the range says nothing.
  ASSERT_EQ(past->report.past_range.size(), 1u);
  EXPECT_EQ(past->report.past_range[0].joint, "knee_left");
  EXPECT_EQ(past->report.past_range[0].motion, "flexion");
  EXPECT_DOUBLE_EQ(past->report.past_range[0].angle_deg, past_deg);
  EXPECT_EQ(past->report.past_range[0].positive_deg, knee.positive_deg);
  bool warned = false;
  for (const std::string& w : past->report.warnings) {
    warned |= w.find("'knee_left' flexion") != std::string::npos && w.find("past its range") != std::string::npos;
  }
  EXPECT_TRUE(warned);
  Pose quaternion;
  pose::JointRotation turn;
  turn.joint = "knee_left";
  turn.rotation = Eigen::Quaterniond(Eigen::AngleAxisd(past_deg * M_PI / 180.0, Eigen::Vector3d::UnitX()));
  quaternion.joints.push_back(turn);
  Result<PoseResult> same = run(quaternion, api::Method::kCor, false);
  ASSERT_TRUE(same.ok());
  ASSERT_EQ(same->report.past_range.size(), 1u);
  EXPECT_NEAR(same->report.past_range[0].angle_deg, past_deg, 1e-6);
  Result<PoseResult> within = run(single("knee_left", knee.positive_deg - 5.0), api::Method::kCor, false);
  ASSERT_TRUE(within.ok());
  EXPECT_TRUE(within->report.past_range.empty());
  RangeParams bad;
  bad.step_deg = 0.0;
  EXPECT_EQ(joint_ranges(rig, bad).status().code(), StatusCode::kInvalidArgument);
}

// The report's soft-tissue figure around a moved joint agrees with one computed from the exported forward field
// (finite-difference Jacobians of the voxels' motion).
TEST(BodyPosing, ReportedLocalVolumeChangeAgreesWithTheForwardField) {
  const Rig& rig = body_rig().engine->rig();
  const ImageGeometry& g = rig.labels.geometry();
  const std::map<Label, int> segment_of = segment_of_labels(rig.skeleton);
  Result<PoseResult> result = run(single("knee_left", 60), api::Method::kCor);
  ASSERT_TRUE(result.ok());
  const rig::Joint& knee = rig.skeleton.joints[static_cast<size_t>(rig.skeleton.joint_index("knee_left"))];
  const std::vector<float>& u = result->forward_field;
  Eigen::Matrix3d step;  // index -> mm
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) step(r, c) = g.direction[static_cast<size_t>(3 * r + c)] * g.spacing[static_cast<size_t>(c)];
  const Eigen::Matrix3d to_index = step.inverse();
  double rest = 0.0, posed = 0.0;
  for (int64_t k = 1; k + 1 < g.size[2]; ++k) {
    for (int64_t j = 1; j + 1 < g.size[1]; ++j) {
      for (int64_t i = 1; i + 1 < g.size[0]; ++i) {
        const int64_t v = g.offset(i, j, k);
        const Label l = rig.labels.data()[v];
        if (l == 0 || segment_of.count(l)) continue;
        if ((physical(g, i, j, k) - knee.centre_mm).norm() > 100.0) continue;
        // du/dindex by central differences, only where all six neighbours are soft tissue too.
        Eigen::Matrix3d du;
        bool interior = true;
        const int64_t offsets[3] = {1, g.size[0], g.size[0] * g.size[1]};
        for (int a = 0; a < 3 && interior; ++a) {
          const int64_t lo = v - offsets[a], hi = v + offsets[a];
          const Label ll = rig.labels.data()[lo], lh = rig.labels.data()[hi];
          interior = ll != 0 && lh != 0 && !segment_of.count(ll) && !segment_of.count(lh);
          for (int c = 0; c < 3; ++c) du(c, a) = 0.5 * (u[static_cast<size_t>(3 * hi + c)] - u[static_cast<size_t>(3 * lo + c)]);
        }
        if (!interior) continue;
        const double det = (Eigen::Matrix3d::Identity() + du * to_index).determinant();
        rest += 1.0;
        posed += det;
      }
    }
  }
  ASSERT_GT(rest, 1000.0);
  const double from_field = posed / rest - 1.0;
  const JointRegionChange* reported = nullptr;
  for (const auto& c : result->report.joint_regions) if (c.radius_mm == 100.0) reported = &c;
  ASSERT_NE(reported, nullptr);
  EXPECT_NEAR(reported->volume_change, from_field, 0.05) << "report " << reported->volume_change << ", field " << from_field;
}

// Raising the arm or flexing the hip leaves the soft tissue of other body parts where it was: the arm lies against
// the trunk and the thighs touch at rest, but no tissue is dragged across those contacts. Measured on the posed
// volume through the exported inverse field: every output voxel that shows soft tissue whose nearest bone does not
// move, from further than 120 mm from the moved joint, shows it where it was.
TEST(BodyPosing, NoTissueIsDraggedAcrossASkinContact) {
  const Rig& rig = body_rig().engine->rig();
  const ImageGeometry& g = rig.labels.geometry();
  const phantom::Phantom& p = body_rig().phantom;
  Result<LabelVolume> body = labels::body_mask(p.label_map, p.labels, &p.ct);
  ASSERT_TRUE(body.ok());
  Result<rig::BodyRegions> regions = rig::body_regions(rig.skeleton, rig.labels, *body);
  ASSERT_TRUE(regions.ok());
  const std::map<Label, int> segment_of = segment_of_labels(rig.skeleton);
  const std::vector<uint8_t> separated = rig::separated_segments(rig.skeleton);
  const size_t n = rig.skeleton.segments.size();
  for (const auto& [joint, posed] : std::vector<std::pair<std::string, Pose>>{
           {"shoulder_left", single("shoulder_left", 0, 90)}, {"hip_right", single("hip_right", 90)}}) {
    SCOPED_TRACE(joint);
    Result<PoseResult> result = run(posed, api::Method::kCor);
    ASSERT_TRUE(result.ok());
    const rig::Joint& moved = rig.skeleton.joints[static_cast<size_t>(rig.skeleton.joint_index(joint))];
    const ImageGeometry& out = result->output_grid;
    double worst = 0.0, attached_worst = 0.0;
    int64_t dragged = 0, considered = 0;
    std::map<std::string, int> by_region;
    for (int64_t k = 0; k < out.size[2]; ++k) {
      for (int64_t j = 0; j < out.size[1]; ++j) {
        for (int64_t i = 0; i < out.size[0]; ++i) {
          const int64_t v = out.offset(i, j, k);
          const Label l = result->labels->data()[v];
          if (l == 0 || segment_of.count(l)) continue;
          const Eigen::Vector3d x = physical(out, i, j, k);
          const Eigen::Vector3d d(result->inverse_field[static_cast<size_t>(3 * v)],
                                  result->inverse_field[static_cast<size_t>(3 * v + 1)],
                                  result->inverse_field[static_cast<size_t>(3 * v + 2)]);
          const Eigen::Vector3d from = x + d;
          if ((from - moved.centre_mm).norm() < 120.0) continue;
          const Vec3 index = g.physical_to_index({from.x(), from.y(), from.z()});
          const int64_t si = std::llround(index[0]), sj = std::llround(index[1]), sk = std::llround(index[2]);
          if (!rig.labels.contains(si, sj, sk)) continue;
          const int region = regions->segment[static_cast<size_t>(g.offset(si, sj, sk))];
          if (region < 0) continue;
          const size_t s = static_cast<size_t>(region);
          if (!result->segment_rotation[s].isIdentity(1e-12) || !result->segment_translation[s].isZero(1e-9)) continue;
          if (!separated[s * n + static_cast<size_t>(moved.child)]) {
            // The bone the limb hangs from (the pelvis for a hip): its tissue blends with the limb's near the joint.
            attached_worst = std::max(attached_worst, d.norm());
            continue;
          }
          ++considered;
          worst = std::max(worst, d.norm());
          dragged += d.norm() > 10.0 ? 1 : 0;
          if (d.norm() > 10.0) ++by_region[rig.skeleton.segments[s].name + (d.norm() > 100 ? " far" : " near")];
        }
      }
    }
    std::printf("%s: tissue of other body parts from beyond 120 mm: %lld of %lld voxels shown more than 10 mm away "
                "(largest %.1f mm); the parent's tissue up to %.1f mm\n",
                joint.c_str(), static_cast<long long>(dragged), static_cast<long long>(considered), worst, attached_worst);
    for (const auto& [name, count] : by_region) std::printf("  %s %d\n", name.c_str(), count);
    // A few voxels of folded tets near the moved limb sample from afar; no web or flap of tissue.
    EXPECT_GT(considered, 100000);
    EXPECT_LT(static_cast<double>(dragged), 1e-3 * static_cast<double>(considered));
  }
}

// The liver's flank lies nearer the right elbow than the ribs, beyond the trunk's skin the arm rests against: it is
// the trunk's region, not the arm's, so bending the elbow leaves it where it was and keeps its volume. Before limb
// regions stopped at the depth of their bone, 7% of the liver was the arm's region on this grid, and fem lost 2.8%
// of it (CoR 0.4%, fem 2.2% on scripts/body_check's 2.5 mm grid). A few voxels on the 8 mm slices still are.
TEST(BodyPosing, BendingTheElbowLeavesTheLiverWhereItIs) {
  const Rig& rig = body_rig().engine->rig();
  const phantom::Phantom& p = body_rig().phantom;
  constexpr Label kLiver = 3;
  ASSERT_NE(p.label_map.find(kLiver), nullptr);
  ASSERT_EQ(p.label_map.find(kLiver)->name, "liver");
  Result<LabelVolume> body = labels::body_mask(p.label_map, p.labels, &p.ct);
  ASSERT_TRUE(body.ok());
  Result<rig::BodyRegions> regions = rig::body_regions(rig.skeleton, rig.labels, *body);
  ASSERT_TRUE(regions.ok());
  const std::vector<uint8_t> limb = rig::limb_segments(rig.skeleton);
  int64_t liver = 0, in_limb = 0;
  for (int64_t v = 0; v < rig.labels.voxel_count(); ++v) {
    if (rig.labels.data()[v] != kLiver) continue;
    ++liver;
    const int region = regions->segment[static_cast<size_t>(v)];
    in_limb += region >= 0 && limb[static_cast<size_t>(region)];
  }
  EXPECT_GT(liver, 1000);
  EXPECT_LT(static_cast<double>(in_limb), 0.01 * static_cast<double>(liver));
  for (const api::Method method : {api::Method::kCor, api::Method::kFem}) {
    SCOPED_TRACE(std::string(api::method_name(method)));
    Result<PoseResult> result = run(single("elbow_right", 90), method);
    ASSERT_TRUE(result.ok()) << result.status().to_string();
    int64_t posed = 0, moved = 0;
    for (int64_t v = 0; v < result->output_grid.voxel_count(); ++v) {
      if (result->labels->data()[v] != kLiver) continue;
      ++posed;
      moved += Eigen::Vector3d(result->inverse_field[static_cast<size_t>(3 * v)],
                               result->inverse_field[static_cast<size_t>(3 * v + 1)],
                               result->inverse_field[static_cast<size_t>(3 * v + 2)])
                   .norm() > 1.0;
    }
    EXPECT_NEAR(static_cast<double>(posed) / static_cast<double>(liver), 1.0, 0.01);
    EXPECT_LT(static_cast<double>(moved), 0.01 * static_cast<double>(posed)) << "voxels shown more than 1 mm away";
  }
}

}  // namespace
}  // namespace posewarp::api
