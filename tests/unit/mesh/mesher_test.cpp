#include "posewarp/mesh/mesher.h"

#include <gtest/gtest.h>

#include <Eigen/Dense>

#include <atomic>
#include <chrono>
#include <iostream>

#include "posewarp/labels/body.h"
#include "posewarp/phantom/phantom.h"

namespace posewarp::mesh {
namespace {

struct BarClasses {
  LabelVolume classes;
  std::vector<std::string> segments;
};

BarClasses bar_classes() {
  phantom::BarParams params;
  params.length_mm = 160.0;
  params.bone_count = 3;
  Result<phantom::Phantom> bar = phantom::make_bar(params);
  EXPECT_TRUE(bar.ok());
  Result<LabelVolume> body = labels::body_mask(bar->label_map, bar->labels, nullptr);
  EXPECT_TRUE(body.ok());
  return {labels::segment_classes(bar->label_map, bar->labels, *body), bar->label_map.bone_segments()};
}

MeshParams small_sizes() {
  MeshParams params;
  params.facet_size_mm = 4.0;
  params.facet_distance_mm = 1.0;
  params.bone_cell_size_mm = 4.0;
  params.soft_cell_size_mm = 8.0;
  return params;
}

TEST(CgalMesher, AParallelMesherPastItsWatchdogFallsBackToTheSequentialOneWithAWarning) {
  const BarClasses bar = bar_classes();
  MeshParams params = small_sizes();
  params.parallel = true;
  params.parallel_watchdog_s = 1e-3;  // the first look of the watchdog (50 ms) already finds it late
  MeshHealth health;
  Result<TetMesh> mesh = make_cgal_mesher()->mesh(bar.classes, 3, params, {}, &health);
  ASSERT_TRUE(mesh.ok()) << mesh.status().to_string();
  EXPECT_TRUE(health.sequential_fallback);
  ASSERT_EQ(health.warnings.size(), 1u);
  EXPECT_NE(health.warnings[0].find("sequentially"), std::string::npos);
  ASSERT_TRUE(check_mesh_health(*mesh, bar.classes, bar.segments, &health).ok());
  EXPECT_EQ(health.body_components, 1);
  // Exactly the sequential mesh: the fallback is the reproducible mesher with the same seed.
  MeshParams sequential = small_sizes();
  sequential.parallel = false;
  Result<TetMesh> reference = make_cgal_mesher()->mesh(bar.classes, 3, sequential, {}, nullptr);
  ASSERT_TRUE(reference.ok());
  EXPECT_EQ(mesh->tets, reference->tets);
}

TEST(CgalMesher, ACancelledMeshingStopsPromptlyWithCancelled) {
  const BarClasses bar = bar_classes();
  for (const bool parallel : {true, false}) {
    SCOPED_TRACE(parallel ? "parallel" : "sequential");
    MeshParams params = small_sizes();
    params.parallel = parallel;
    params.facet_size_mm = 2.0;  // slow enough to be caught refining
    params.bone_cell_size_mm = 2.0;
    const auto start = std::chrono::steady_clock::now();
    std::atomic<bool> asked{false};
    std::chrono::steady_clock::time_point asked_at;
    ProgressHooks hooks;
    hooks.cancel_requested = [&] {
      if (!asked && std::chrono::steady_clock::now() - start > std::chrono::milliseconds(300)) {
        asked_at = std::chrono::steady_clock::now();
        asked = true;
      }
      return asked.load();
    };
    Result<TetMesh> mesh = make_cgal_mesher()->mesh(bar.classes, 3, params, hooks, nullptr);
    ASSERT_TRUE(asked.load()) << "meshing finished before the cancel request; make it slower";
    EXPECT_EQ(mesh.status().code(), StatusCode::kCancelled) << mesh.status().to_string();
    // Not a timing benchmark: a bound far above the 50 ms polling, far below "never".
    EXPECT_LT(std::chrono::duration<double>(std::chrono::steady_clock::now() - asked_at).count(), 5.0);
  }
}

TEST(CgalMesher, AMeshThatWouldGrowPastItsVertexCapStopsWithResourceExhausted) {
  const BarClasses bar = bar_classes();
  for (const bool parallel : {true, false}) {
    SCOPED_TRACE(parallel ? "parallel" : "sequential");
    MeshParams params = small_sizes();
    params.parallel = parallel;
    params.max_vertices = 2500;  // over the estimate (about 1900), under what the bar really needs at these sizes
    Result<TetMesh> mesh = make_cgal_mesher()->mesh(bar.classes, 3, params, {}, nullptr);
    EXPECT_EQ(mesh.status().code(), StatusCode::kResourceExhausted) << mesh.status().to_string();
    EXPECT_NE(mesh.status().message().find("2500 vertices"), std::string::npos) << mesh.status().to_string();
  }
  // Sizes whose estimate alone is over the cap are refused before refinement starts.
  MeshParams fine = small_sizes();
  fine.max_vertices = 1000;
  MeshHealth health;
  const Status refused = make_cgal_mesher()->mesh(bar.classes, 3, fine, {}, &health).status();
  EXPECT_EQ(refused.code(), StatusCode::kResourceExhausted) << refused.to_string();
  EXPECT_NE(refused.message().find("would make at least"), std::string::npos) << refused.to_string();
  EXPECT_GT(health.estimated_vertices, 1000);
  MeshParams tiny;
  tiny.bone_cell_size_mm = 0.05;
  EXPECT_EQ(validate(tiny).code(), StatusCode::kInvalidArgument);
}

TEST(CgalMesher, MeshesEveryBoneOfTheBarWithPositiveTets) {
  const BarClasses bar = bar_classes();
  MeshHealth health;
  Result<TetMesh> mesh = make_cgal_mesher()->mesh(bar.classes, 3, small_sizes(), {}, &health);
  ASSERT_TRUE(mesh.ok()) << mesh.status().to_string();
  EXPECT_GT(mesh->tet_count(), 1000);
  ASSERT_TRUE(check_mesh_health(*mesh, bar.classes, bar.segments, &health).ok());
  for (int k = 0; k < 3; ++k) EXPECT_GT(health.tets_per_class[static_cast<size_t>(kFirstBoneClass + k)], 10) << k;
  EXPECT_EQ(health.body_components, 1);
  EXPECT_EQ(health.degenerate_tets, 0);
  EXPECT_LT(health.body_volume_error, 0.05);
  EXPECT_LT(health.max_bone_volume_error, 0.25);
  for (int64_t t = 0; t < mesh->tet_count(); ++t) {
    const Eigen::Vector3d a = mesh->vertices.row(mesh->tets(t, 0));
    const Eigen::Vector3d e1 = mesh->vertices.row(mesh->tets(t, 1)).transpose() - a;
    const Eigen::Vector3d e2 = mesh->vertices.row(mesh->tets(t, 2)).transpose() - a;
    const Eigen::Vector3d e3 = mesh->vertices.row(mesh->tets(t, 3)).transpose() - a;
    const double det = e1.dot(e2.cross(e3));
    ASSERT_GT(det, 0.0) << "tet " << t;
  }
}

TEST(CgalMesher, SequentialModeReproducesTheMeshExactly) {
  const BarClasses bar = bar_classes();
  MeshParams params = small_sizes();
  params.parallel = false;
  params.seed = 7;
  Result<TetMesh> first = make_cgal_mesher()->mesh(bar.classes, 3, params, {}, nullptr);
  Result<TetMesh> second = make_cgal_mesher()->mesh(bar.classes, 3, params, {}, nullptr);
  ASSERT_TRUE(first.ok() && second.ok());
  ASSERT_EQ(first->vertex_count(), second->vertex_count());
  ASSERT_EQ(first->tet_count(), second->tet_count());
  EXPECT_EQ(first->vertices, second->vertices);
  EXPECT_EQ(first->tets, second->tets);
  EXPECT_EQ(first->tet_class, second->tet_class);
}

TEST(CgalMesher, MeshLivesInPhysicalSpaceOfAnObliqueGrid) {
  phantom::BarParams params;
  params.length_mm = 120.0;
  params.bone_count = 2;
  const double a = 0.4;
  params.direction = {std::cos(a), 0, std::sin(a), 0, 1, 0, -std::sin(a), 0, std::cos(a)};
  Result<phantom::Phantom> bar = phantom::make_bar(params);
  ASSERT_TRUE(bar.ok());
  Result<LabelVolume> body = labels::body_mask(bar->label_map, bar->labels, nullptr);
  const LabelVolume classes = labels::segment_classes(bar->label_map, bar->labels, *body);
  Result<TetMesh> mesh = make_cgal_mesher()->mesh(classes, 2, small_sizes(), {}, nullptr);
  ASSERT_TRUE(mesh.ok());
  // The bar's axis is physical z whatever the grid: every vertex lies within the cylinder's radius of it.
  for (int64_t v = 0; v < mesh->vertex_count(); ++v) {
    const double r = std::hypot(mesh->vertices(v, 0), mesh->vertices(v, 1));
    ASSERT_LT(r, params.radius_mm + 2.5) << "vertex " << v;
    ASSERT_GT(mesh->vertices(v, 2), -2.5);
    ASSERT_LT(mesh->vertices(v, 2), params.length_mm + 2.5);
  }
}

TEST(Downsample, BonesTakePrecedenceSoThinBonesSurvive) {
  ImageGeometry g;
  g.size = {4, 4, 4};
  LabelVolume classes(g, 1);
  classes.at(0, 0, 0) = 2;  // one bone voxel in a 2x2x2 block: under a quarter, soft tissue wins
  for (int i = 2; i < 4; ++i) classes.at(i, 0, 0) = 3, classes.at(i, 1, 0) = 3;  // half a block of bone 3
  LabelVolume down = downsample_classes(classes, {2, 2, 2});
  EXPECT_EQ(down.size(), (Index3{2, 2, 2}));
  EXPECT_EQ(down.at(0, 0, 0), 1);
  EXPECT_EQ(down.at(1, 0, 0), 3);
  EXPECT_DOUBLE_EQ(down.geometry().spacing[0], 2.0);
  EXPECT_DOUBLE_EQ(down.geometry().origin[0], 0.5);
  EXPECT_EQ(downsample_factor_for(g, 8), (Index3{2, 2, 2}));
  EXPECT_EQ(downsample_factor_for(g, 64), (Index3{1, 1, 1}));
}

TEST(MeshHealthCheck, ALostBoneIsAnErrorNamingIt) {
  ImageGeometry g;
  g.size = {4, 4, 4};
  LabelVolume classes(g, 1);
  classes.at(1, 1, 1) = 3;  // segment 1 has voxels
  TetMesh mesh;
  mesh.segment_count = 2;
  mesh.vertices.resize(4, 3);
  mesh.vertices << 0, 0, 0, 1, 0, 0, 0, 1, 0, 0, 0, 1;
  mesh.tets.resize(1, 4);
  mesh.tets << 0, 1, 2, 3;
  mesh.tet_class.resize(1);
  mesh.tet_class << 2;
  MeshHealth health;
  const Status status = check_mesh_health(mesh, classes, {"femur", "tibia"}, &health);
  EXPECT_EQ(status.code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(status.message().find("tibia"), std::string::npos);
  EXPECT_EQ(health.lost_segments, (std::vector<std::string>{"tibia"}));
}

// Around a joint centre the tets are as small as joint_cell_size_mm asks; away from it the mesh is as before.
TEST(CgalMesher, JointCellSizeRefinesAroundTheJointCentresOnly) {
  phantom::BarParams bar_params;
  bar_params.length_mm = 160.0;
  bar_params.bone_count = 3;
  Result<phantom::Phantom> bar = phantom::make_bar(bar_params);
  ASSERT_TRUE(bar.ok());
  ASSERT_FALSE(bar->joints.empty());
  const BarClasses classes = bar_classes();
  const Vec3 c = bar->joints.front().centre_mm;
  const Eigen::Vector3d centre(c[0], c[1], c[2]);
  MeshParams params = small_sizes();
  params.parallel = false;
  Result<TetMesh> plain = make_cgal_mesher()->mesh(classes.classes, 3, params, {}, nullptr);
  params.joint_cell_size_mm = 2.0;
  params.joint_radius_mm = 12.0;
  params.joint_centres_lps = {{c[0], c[1], c[2]}};
  Result<TetMesh> refined = make_cgal_mesher()->mesh(classes.classes, 3, params, {}, nullptr);
  ASSERT_TRUE(plain.ok() && refined.ok()) << refined.status().to_string();
  // Tets whose centroid lies within 12 mm of the joint, and beyond 45 mm of it.
  auto count = [&](const TetMesh& mesh) {
    std::pair<int64_t, int64_t> near_far{0, 0};
    for (int64_t t = 0; t < mesh.tet_count(); ++t) {
      Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
      for (int k = 0; k < 4; ++k) centroid += 0.25 * mesh.vertices.row(mesh.tets(t, k)).transpose();
      const double d = (centroid - centre).norm();
      near_far.first += d < 12.0;
      near_far.second += d > 45.0;
    }
    return near_far;
  };
  const auto [plain_near, plain_far] = count(*plain);
  const auto [refined_near, refined_far] = count(*refined);
  std::cout << "tets within 12 mm of the joint: " << plain_near << " -> " << refined_near << "; beyond 45 mm: "
            << plain_far << " -> " << refined_far << "\n";
  EXPECT_GT(refined_near, 3 * plain_near);
  EXPECT_NEAR(static_cast<double>(refined_far), static_cast<double>(plain_far), 0.25 * static_cast<double>(plain_far));
}

TEST(MeshParamsCheck, RejectsSizesThatCannotWork) {
  MeshParams params;
  params.facet_angle_deg = 40.0;
  EXPECT_EQ(validate(params).code(), StatusCode::kInvalidArgument);
  params = MeshParams{};
  params.bone_cell_size_mm = 0.0;
  EXPECT_EQ(validate(params).code(), StatusCode::kInvalidArgument);
  params = MeshParams{};
  params.cell_radius_edge_ratio = 1.0;
  EXPECT_EQ(validate(params).code(), StatusCode::kInvalidArgument);
  params = MeshParams{};
  params.joint_cell_size_mm = 0.1;
  EXPECT_EQ(validate(params).code(), StatusCode::kInvalidArgument);
  params.joint_cell_size_mm = 4.0;
  EXPECT_TRUE(validate(params).ok());
  params.joint_radius_mm = -1.0;
  EXPECT_EQ(validate(params).code(), StatusCode::kInvalidArgument);
}

// A column of Kuhn-subdivided cubes: bone segment 0 below, bone segment 1 above, one layer of soft cells between them,
// so that every soft tet of the gap has its corners on the two bones. Split, no soft tet keeps an edge between them,
// and the mesh keeps its volume, its bone tets and positive orientation.
TEST(SplitBoneGaps, LeavesNoSoftTetWithAnEdgeBetweenTwoBones) {
  constexpr int kN = 3, kLayers = 5;  // 3 x 3 cells per layer; layers 0-1 bone 0, 2 soft, 3-4 bone 1
  auto id = [](int i, int j, int k) { return (k * (kN + 1) + j) * (kN + 1) + i; };
  TetMesh mesh;
  mesh.segment_count = 2;
  mesh.vertices.resize((kN + 1) * (kN + 1) * (kLayers + 1), 3);
  for (int k = 0; k <= kLayers; ++k)
    for (int j = 0; j <= kN; ++j)
      for (int i = 0; i <= kN; ++i) mesh.vertices.row(id(i, j, k)) << 4.0 * i, 4.0 * j, 4.0 * k;
  const int paths[6][3] = {{0, 1, 2}, {0, 2, 1}, {1, 0, 2}, {1, 2, 0}, {2, 0, 1}, {2, 1, 0}};
  std::vector<Eigen::Vector4i> tets;
  std::vector<int> classes;
  for (int k = 0; k < kLayers; ++k)
    for (int j = 0; j < kN; ++j)
      for (int i = 0; i < kN; ++i)
        for (const auto& path : paths) {
          int c[3] = {i, j, k};
          Eigen::Vector4i tet;
          tet(0) = id(c[0], c[1], c[2]);
          for (int s = 0; s < 3; ++s) ++c[path[s]], tet(s + 1) = id(c[0], c[1], c[2]);
          Eigen::Matrix3d e;
          for (int s = 0; s < 3; ++s)
            e.col(s) = (mesh.vertices.row(tet(s + 1)) - mesh.vertices.row(tet(0))).transpose();
          if (e.determinant() < 0) std::swap(tet(2), tet(3));
          tets.push_back(tet);
          classes.push_back(k < 2 ? kFirstBoneClass : k > 2 ? kFirstBoneClass + 1 : kSoftTissueClass);
        }
  mesh.tets.resize(static_cast<Eigen::Index>(tets.size()), 4);
  mesh.tet_class.resize(static_cast<Eigen::Index>(tets.size()));
  for (size_t t = 0; t < tets.size(); ++t) {
    mesh.tets.row(static_cast<Eigen::Index>(t)) = tets[t].transpose();
    mesh.tet_class(static_cast<Eigen::Index>(t)) = classes[t];
  }
  struct Figures {
    int64_t bridging_edges = 0, bone_tets = 0, soft_tets = 0;
    double volume = 0.0, smallest = 1e300;
  };
  auto figures = [](const TetMesh& m) {
    std::vector<int> bone(static_cast<size_t>(m.vertex_count()), -1);
    Figures f;
    for (int64_t t = 0; t < m.tet_count(); ++t) {
      if (m.tet_class(t) >= kFirstBoneClass) {
        ++f.bone_tets;
        for (int c = 0; c < 4; ++c) bone[static_cast<size_t>(m.tets(t, c))] = m.tet_class(t) - kFirstBoneClass;
      }
    }
    for (int64_t t = 0; t < m.tet_count(); ++t) {
      Eigen::Matrix3d e;
      for (int s = 0; s < 3; ++s)
        e.col(s) = (m.vertices.row(m.tets(t, s + 1)) - m.vertices.row(m.tets(t, 0))).transpose();
      f.volume += e.determinant() / 6.0;
      f.smallest = std::min(f.smallest, e.determinant() / 6.0);
      if (m.tet_class(t) != kSoftTissueClass) continue;
      ++f.soft_tets;
      for (int a = 0; a < 4; ++a)
        for (int b = a + 1; b < 4; ++b) {
          const int ba = bone[static_cast<size_t>(m.tets(t, a))], bb = bone[static_cast<size_t>(m.tets(t, b))];
          f.bridging_edges += ba >= 0 && bb >= 0 && ba != bb;
        }
    }
    return f;
  };
  const Figures before = figures(mesh);
  const int64_t rest_vertices = mesh.vertex_count();
  const int64_t split = split_bone_gaps(mesh);
  const Figures after = figures(mesh);
  EXPECT_GT(before.bridging_edges, 0);
  EXPECT_EQ(after.bridging_edges, 0);
  EXPECT_EQ(mesh.vertex_count(), rest_vertices + split);  // one new vertex per edge split
  EXPECT_EQ(split, 16 + 24 + 9);  // the gap's 16 vertical edges, its 24 vertical faces' and 9 cells' diagonals
  EXPECT_EQ(after.bone_tets, before.bone_tets);
  EXPECT_GT(after.soft_tets, before.soft_tets);
  EXPECT_NEAR(after.volume, before.volume, 1e-9 * before.volume);
  EXPECT_GT(after.smallest, 0.0);
  EXPECT_EQ(split_bone_gaps(mesh), 0);  // nothing left to split
}

}  // namespace
}  // namespace posewarp::mesh
