#include "posewarp/api/rig.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <array>
#include <chrono>
#include <cmath>
#include <map>
#include <string>
#include <vector>

#include <nlohmann/json.hpp>

#include "posewarp/api/rig_file.h"
#include "posewarp/common/sha256.h"
#include "posewarp/rig/skeleton.h"
#include "posewarp/skinning/skinning.h"
#include "rig_test_support.h"

namespace posewarp::api {
namespace {

using posewarp::testing::bar_inputs;
using posewarp::testing::shared_bar_rig;
using posewarp::testing::small_bar_params;

TEST(BuildRig, BarBuildsWithNoManualInput) {
  const Rig& rig = shared_bar_rig();
  EXPECT_EQ(rig.skeleton.segments.size(), 3u);
  EXPECT_EQ(rig.skeleton.joints.size(), 2u);
  EXPECT_GT(rig.mesh.tet_count(), 1000);
  EXPECT_EQ(rig.weights.vertex_count(), rig.mesh.vertex_count());
  EXPECT_EQ(rig.centres.centre.rows(), rig.mesh.vertex_count());
  std::vector<std::string> stages;
  for (const auto& [stage, seconds] : rig.provenance.stage_seconds) stages.push_back(stage);
  EXPECT_EQ(stages, (std::vector<std::string>{"skeleton", "body", "contacts", "mesh", "weights", "cor", "gaps",
                                              "surfaces", "ranges", "tables"}));
}

TEST(BuildRig, WeightsArePartitionsOfUnityAndBonesAreExact) {
  const Rig& rig = shared_bar_rig();
  const auto stats = nlohmann::json::parse(rig.provenance.stats_json);
  EXPECT_LT(stats["weights"]["max_partition_error"].get<double>(), 1e-9);
  for (int64_t v = 0; v < rig.weights.vertex_count(); ++v) {
    double sum = 0.0;
    for (int i = 0; i < rig.weights.influences; ++i) sum += rig.weights.weight(v, i);
    ASSERT_NEAR(sum, 1.0, 1e-6) << "vertex " << v;
  }
  // Every vertex of a bone tet is fully owned by a bone (its own, or a neighbour's on a shared face).
  for (int64_t t = 0; t < rig.mesh.tet_count(); ++t) {
    if (rig.mesh.tet_class(t) < kFirstBoneClass) continue;
    for (int c = 0; c < 4; ++c) ASSERT_FLOAT_EQ(rig.weights.weight(rig.mesh.tets(t, c), 0), 1.0f);
  }
}

TEST(BuildRig, SameInputsAndParametersGiveTheSameRig) {
  Result<Rig> again = build_rig(bar_inputs(), small_bar_params(), {});
  ASSERT_TRUE(again.ok()) << again.status().to_string();
  EXPECT_EQ(again->id(), shared_bar_rig().id());
  EXPECT_EQ(content_hash(*again), content_hash(shared_bar_rig()));
  BuildParams other = small_bar_params();
  other.mesh.seed = 99;
  Result<Rig> reseeded = build_rig(bar_inputs(), other, {});
  ASSERT_TRUE(reseeded.ok());
  EXPECT_NE(reseeded->id(), shared_bar_rig().id());
}

TEST(BuildRig, ABodyMaskThatLeavesBonesOutIsRefused) {
  BuildInputs inputs = bar_inputs();
  LabelVolume body(inputs.labels.geometry(), 0);
  for (int64_t v = 0; v < body.voxel_count(); ++v) body.data()[v] = inputs.labels.data()[v] == 1 ? 1 : 0;
  inputs.body = body;
  Result<Rig> rig = build_rig(inputs, small_bar_params(), {});
  EXPECT_EQ(rig.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(rig.status().message().find("must contain the bones"), std::string::npos);
}

TEST(BuildRig, AnEmptyVolumeIsAClearError) {
  BuildInputs inputs = bar_inputs();
  std::fill(inputs.labels.voxels().begin(), inputs.labels.voxels().end(), 0);
  Result<Rig> rig = build_rig(inputs, small_bar_params(), {});
  EXPECT_EQ(rig.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(rig.status().message().find("no bone labels"), std::string::npos);
}

// A CT given as the labels and the labels given as the CT are refused before any meshing, naming both inputs; the
// same volumes the right way round build (BarBuildsWithNoManualInput).
TEST(BuildRig, LabelsAndCtSwappedAreRefusedNamingBothBeforeMeshing) {
  const BuildInputs right = bar_inputs();
  BuildInputs swapped = right;
  swapped.labels_source = "ct.nii.gz";
  swapped.ct_source = "labels.nii.gz";
  LabelVolume ct_as_labels(right.labels.geometry(), 0);
  for (int64_t v = 0; v < ct_as_labels.voxel_count(); ++v) {
    ct_as_labels.data()[v] = static_cast<Label>(std::lround(right.ct->data()[v]));
  }
  IntensityVolume labels_as_ct(right.labels.geometry(), 0.0f);
  for (int64_t v = 0; v < labels_as_ct.voxel_count(); ++v) {
    labels_as_ct.data()[v] = static_cast<float>(right.labels.data()[v]);
  }
  swapped.labels = ct_as_labels;
  swapped.ct = labels_as_ct;
  // Any stage that started would report progress (and polls for cancellation): none may.
  std::vector<std::string> stages;
  ProgressHooks hooks;
  hooks.on_progress = [&stages](std::string_view stage, double) { stages.emplace_back(stage); };
  hooks.cancel_requested = [&stages] {
    stages.emplace_back("polled");
    return false;
  };
  Result<Rig> rig = build_rig(swapped, small_bar_params(), hooks);
  EXPECT_EQ(rig.status().code(), StatusCode::kInvalidArgument) << rig.status().to_string();
  EXPECT_NE(rig.status().message().find("the CT 'labels.nii.gz'"), std::string::npos) << rig.status().to_string();
  EXPECT_NE(rig.status().message().find("the labels 'ct.nii.gz'"), std::string::npos) << rig.status().to_string();
  EXPECT_NE(rig.status().message().find("swapped"), std::string::npos) << rig.status().to_string();

  // The labels alone given as the CT too (no swap of the labels): the CT is still refused.
  BuildInputs twice = right;
  twice.ct = labels_as_ct;
  twice.ct_source = "labels.nii.gz";
  Result<Rig> doubled = build_rig(twice, small_bar_params(), hooks);
  EXPECT_EQ(doubled.status().code(), StatusCode::kInvalidArgument) << doubled.status().to_string();
  EXPECT_NE(doubled.status().message().find("looks like a label volume given as the CT"), std::string::npos)
      << doubled.status().to_string();
  EXPECT_TRUE(stages.empty()) << "a stage ran: " << stages.front();
}

// A cancel in the middle of meshing (CGAL's stop flag), of the weights (between solves) or of the centres of
// rotation ends the build within a second.
TEST(BuildRig, CancellationStopsTheBuildWithinASecond) {
  for (const char* when : {"mesh", "weights", "cor"}) {
    SCOPED_TRACE(when);
    ProgressHooks hooks;
    CancelFlag flag;
    std::chrono::steady_clock::time_point cancelled_at;
    hooks.cancel_requested = flag.as_hook();
    hooks.on_progress = [&](std::string_view stage, double fraction) {
      if (stage == when && fraction > 0.0 && !flag.cancelled()) {
        cancelled_at = std::chrono::steady_clock::now();
        flag.cancel();
      }
    };
    const Status status = build_rig(bar_inputs(), small_bar_params(), hooks).status();
    EXPECT_EQ(status.code(), StatusCode::kCancelled) << status.to_string();
    EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - cancelled_at).count(), 1.0);
  }
  ProgressHooks expired;
  expired.deadline = std::chrono::steady_clock::now();
  EXPECT_EQ(build_rig(bar_inputs(), small_bar_params(), expired).status().code(), StatusCode::kDeadlineExceeded);
}

// The rig id is a SHA-256 of everything that shapes the rig: the same inputs give the same id, a changed rig spec
// or body mask another.
// --joint-size: the build refines the mesh around its hinge and ball joints' centres (finer tets within the radius,
// the rest as before); the parameters' JSON names it only when set, so rigs built without it keep their ids.
TEST(BuildRig, JointCellSizeRefinesTheMeshAroundTheSkeletonsJoints) {
  const Rig& plain = shared_bar_rig();
  EXPECT_EQ(plain.params_json.find("joint_cell_size_mm"), std::string::npos);
  BuildParams params = small_bar_params();
  params.mesh.joint_cell_size_mm = 2.0;
  params.mesh.joint_radius_mm = 12.0;
  Result<Rig> refined = build_rig(bar_inputs(), params, {});
  ASSERT_TRUE(refined.ok()) << refined.status().to_string();
  EXPECT_NE(refined->params_json.find("joint_cell_size_mm"), std::string::npos);
  EXPECT_NE(refined->id(), plain.id());
  auto near_joints = [](const Rig& rig) {
    int64_t near = 0;
    for (int64_t t = 0; t < rig.mesh.tet_count(); ++t) {
      Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
      for (int k = 0; k < 4; ++k) centroid += 0.25 * rig.mesh.vertices.row(rig.mesh.tets(t, k)).transpose();
      for (const rig::Joint& joint : rig.skeleton.joints) near += (centroid - joint.centre_mm).norm() < 12.0;
    }
    return near;
  };
  EXPECT_GT(near_joints(*refined), 2 * near_joints(plain));
  params.mesh.joint_cell_size_mm = 0.1;
  EXPECT_EQ(build_rig(bar_inputs(), params, {}).status().code(), StatusCode::kInvalidArgument);
}

// The gap between two bones is split by default (no soft tet of the rig keeps an edge between two bones' vertices);
// --keep-bone-gaps leaves the mesher's tets there, and gives another id.
TEST(BuildRig, SplitsTheEdgesBetweenTwoBonesUnlessAskedToKeepThem) {
  auto bridging = [](const Rig& rig) {
    std::vector<int> bone(static_cast<size_t>(rig.mesh.vertex_count()), -1);
    for (int64_t t = 0; t < rig.mesh.tet_count(); ++t) {
      if (rig.mesh.tet_class(t) < kFirstBoneClass) continue;
      for (int c = 0; c < 4; ++c) bone[static_cast<size_t>(rig.mesh.tets(t, c))] = rig.mesh.tet_class(t);
    }
    int64_t edges = 0;
    for (int64_t t = 0; t < rig.mesh.tet_count(); ++t) {
      if (rig.mesh.tet_class(t) != kSoftTissueClass) continue;
      for (int a = 0; a < 4; ++a)
        for (int b = a + 1; b < 4; ++b) {
          const int ba = bone[static_cast<size_t>(rig.mesh.tets(t, a))],
                    bb = bone[static_cast<size_t>(rig.mesh.tets(t, b))];
          edges += ba >= 0 && bb >= 0 && ba != bb;
        }
    }
    return edges;
  };
  const Rig& split = shared_bar_rig();
  EXPECT_EQ(bridging(split), 0);
  EXPECT_GT(nlohmann::json::parse(split.provenance.stats_json)["mesh"]["bone_gap_edges_split"].get<int64_t>(), 0);
  BuildParams params = small_bar_params();
  params.mesh.split_bone_gaps = false;
  params.mesh.slide_joint_gaps = false;
  Result<Rig> kept = build_rig(bar_inputs(), params, {});
  ASSERT_TRUE(kept.ok()) << kept.status().to_string();
  EXPECT_GT(bridging(*kept), 0);
  EXPECT_NE(kept->id(), split.id());
  EXPECT_EQ(nlohmann::json::parse(kept->provenance.stats_json)["mesh"]["joint_gap_vertices_cut"].get<int64_t>(), 0);
}

// Each joint's gap is cut along its middle once the weights are made (fem::cut_joint_gaps): the copies take their
// vertex's weights and centre, so every skinning method moves them with it, and nothing spans the gap after it even
// where its edges were not split. --weld-joint-gaps leaves it whole and gives another id.
TEST(BuildRig, CutsTheJointGapsUnlessAskedToWeldThem) {
  const Rig& cut = shared_bar_rig();
  const int64_t copies =
      nlohmann::json::parse(cut.provenance.stats_json)["mesh"]["joint_gap_vertices_cut"].get<int64_t>();
  EXPECT_GT(copies, 0);
  const int64_t n = cut.mesh.vertex_count();
  EXPECT_EQ(cut.weights.vertex_count(), n);
  EXPECT_EQ(cut.centres.centre.rows(), n);
  const std::vector<Eigen::MatrixXd> skinned = [&] {
    skinning::SegmentTransforms t;
    for (int s = 0; s < cut.weights.segment_count; ++s) {
      t.rotation.push_back(Eigen::AngleAxisd(0.3 * s, Eigen::Vector3d::UnitX()).toRotationMatrix());
      t.translation.push_back(Eigen::Vector3d(0.0, 2.0 * s, 0.0));
    }
    std::vector<Eigen::MatrixXd> out;
    for (const skinning::Method m : {skinning::Method::kLbs, skinning::Method::kDqs, skinning::Method::kCor}) {
      out.push_back(skinning::skin(m, cut.mesh.vertices, cut.weights, cut.centres, t).value());
    }
    return out;
  }();
  // Every copy sits where a vertex of the mesh before the cut sits, and goes where it goes.
  std::map<std::array<double, 3>, int64_t> first;
  int64_t shared = 0;
  for (int64_t v = 0; v < n; ++v) {
    const std::array<double, 3> key{cut.mesh.vertices(v, 0), cut.mesh.vertices(v, 1), cut.mesh.vertices(v, 2)};
    const auto [it, inserted] = first.emplace(key, v);
    if (inserted) continue;
    ++shared;
    for (const Eigen::MatrixXd& x : skinned) ASSERT_EQ(x.row(v), x.row(it->second)) << v;
  }
  EXPECT_EQ(shared, copies);
  const Rig& welded = posewarp::testing::shared_welded_bar_rig();
  EXPECT_EQ(nlohmann::json::parse(welded.provenance.stats_json)["mesh"]["joint_gap_vertices_cut"].get<int64_t>(), 0);
  EXPECT_EQ(welded.mesh.vertex_count() + copies, n);  // the bar is meshed sequentially: the same mesh, uncut
  EXPECT_NE(welded.id(), cut.id());
}

TEST(BuildRig, TheIdIsDerivedFromEveryInput) {
  const Rig& rig = shared_bar_rig();
  EXPECT_TRUE(is_hex_id(rig.id()));
  EXPECT_TRUE(is_hex_id(rig.labels_hash));
  EXPECT_GT(rig.footprint_bytes(), rig.labels.voxel_count() * static_cast<int64_t>(sizeof(Label)));
  BuildParams params = small_bar_params();
  BuildInputs inputs = bar_inputs();
  Result<Rig> again = build_rig(inputs, params, {});
  ASSERT_TRUE(again.ok()) << again.status().to_string();
  EXPECT_EQ(again->id(), rig.id());
  inputs.spec.root = "bar_bone_2";
  Result<Rig> rerooted = build_rig(inputs, params, {});
  ASSERT_TRUE(rerooted.ok()) << rerooted.status().to_string();
  EXPECT_NE(rerooted->id(), rig.id());
}

}  // namespace
}  // namespace posewarp::api
