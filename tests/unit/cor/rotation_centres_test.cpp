#include "posewarp/cor/rotation_centres.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <functional>
#include <numeric>
#include <vector>

#include "posewarp/common/parallel.h"

namespace posewarp::cor {
namespace {

// Dense weights over all segments at a point (mm); they need not be normalized.
using WeightField = std::function<std::vector<double>(const Eigen::Vector3d&)>;

// A bar of nx x ny x nz cubes of side h (mm), centred on the z axis, z from z_min, shifted by `offset`; each cube is
// split into six tets around its main diagonal (Kuhn), every tet turned positive.
TetMesh make_bar(int nx, int ny, int nz, double h, double z_min, int segment_count,
                 const Eigen::Vector3d& offset = Eigen::Vector3d::Zero()) {
  TetMesh mesh;
  mesh.segment_count = segment_count;
  auto index = [&](int i, int j, int k) { return (k * (ny + 1) + j) * (nx + 1) + i; };
  mesh.vertices.resize(static_cast<Eigen::Index>(nx + 1) * (ny + 1) * (nz + 1), 3);
  for (int k = 0; k <= nz; ++k) {
    for (int j = 0; j <= ny; ++j) {
      for (int i = 0; i <= nx; ++i) {
        mesh.vertices.row(index(i, j, k)) =
            (Eigen::Vector3d((i - 0.5 * nx) * h, (j - 0.5 * ny) * h, z_min + k * h) + offset).transpose();
      }
    }
  }
  const std::array<std::array<int, 3>, 6> orders = {{{0, 1, 2}, {0, 2, 1}, {1, 0, 2}, {1, 2, 0}, {2, 0, 1}, {2, 1, 0}}};
  mesh.tets.resize(static_cast<Eigen::Index>(6) * nx * ny * nz, 4);
  Eigen::Index t = 0;
  for (int k = 0; k < nz; ++k) {
    for (int j = 0; j < ny; ++j) {
      for (int i = 0; i < nx; ++i) {
        for (const auto& order : orders) {
          std::array<int, 3> step = {0, 0, 0};
          std::array<int, 4> tet{};
          tet[0] = index(i, j, k);
          for (int s = 0; s < 3; ++s) {
            step[static_cast<size_t>(order[static_cast<size_t>(s)])] = 1;
            tet[static_cast<size_t>(s + 1)] = index(i + step[0], j + step[1], k + step[2]);
          }
          const Eigen::Vector3d p0 = mesh.vertices.row(tet[0]).transpose();
          const Eigen::Vector3d e1 = mesh.vertices.row(tet[1]).transpose() - p0;
          const Eigen::Vector3d e2 = mesh.vertices.row(tet[2]).transpose() - p0;
          const Eigen::Vector3d e3 = mesh.vertices.row(tet[3]).transpose() - p0;
          const double det = e1.dot(e2.cross(e3));
          if (det < 0) std::swap(tet[1], tet[2]);
          mesh.tets.row(t++) << tet[0], tet[1], tet[2], tet[3];
        }
      }
    }
  }
  mesh.tet_class = Eigen::VectorXi::Constant(mesh.tets.rows(), kSoftTissueClass);
  return mesh;
}

// Keeps the `influences` largest weights of the field at each vertex (below 1e-6 counts as zero), renormalized,
// largest first, -1 in unused slots.
SkinWeights sample_weights(const TetMesh& mesh, int influences, const WeightField& field) {
  SkinWeights weights;
  weights.influences = influences;
  weights.segment_count = mesh.segment_count;
  weights.segment.setConstant(mesh.vertex_count(), influences, -1);
  weights.weight.setZero(mesh.vertex_count(), influences);
  for (Eigen::Index v = 0; v < mesh.vertex_count(); ++v) {
    const std::vector<double> dense = field(mesh.vertices.row(v).transpose());
    std::vector<int> order(dense.size());
    std::iota(order.begin(), order.end(), 0);
    std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return dense[size_t(a)] > dense[size_t(b)]; });
    double sum = 0.0;
    int kept = 0;
    for (; kept < influences && kept < static_cast<int>(order.size()) && dense[size_t(order[size_t(kept)])] > 1e-6;
         ++kept) {
      sum += dense[size_t(order[size_t(kept)])];
    }
    for (int c = 0; c < kept; ++c) {
      weights.segment(v, c) = order[size_t(c)];
      weights.weight(v, c) = static_cast<float>(dense[size_t(order[size_t(c)])] / sum);
    }
  }
  return weights;
}

double logistic(double z, double width) {
  return 1.0 / (1.0 + std::exp(-z / width));
}

// Two bones meeting at the plane z = joint_z, blended over a few mm.
WeightField two_bone_field(double joint_z, double width) {
  return [=](const Eigen::Vector3d& p) {
    const double upper = logistic(p.z() - joint_z, width);
    return std::vector<double>{1.0 - upper, upper};
  };
}

// Three bones along z with tilted joints whose wide blends overlap, so the middle holds three nonzero weights.
WeightField three_bone_field(double z_centre) {
  return [=](const Eigen::Vector3d& p) {
    const double z = p.z() - z_centre;
    const double lower = logistic(z + 10.0 + 0.3 * p.x(), 5.0);
    const double upper = logistic(z - 10.0 - 0.2 * p.y(), 4.0);
    return std::vector<double>{1.0 - lower, lower * (1.0 - upper), lower * upper};
  };
}

// `bones` bones stacked along z with joints every `spacing` mm, tilted and with widths that vary across the bar.
WeightField stacked_field(int bones, double z_min, double spacing) {
  return [=](const Eigen::Vector3d& p) {
    std::vector<double> dense(static_cast<size_t>(bones), 0.0);
    double below = 1.0;  // product of the "above joint" blends so far
    for (int b = 0; b < bones; ++b) {
      const double joint = z_min + (b + 1) * spacing + 0.25 * p.x() - 0.15 * p.y();
      const double width = 4.0 + 0.05 * (p.x() + 20.0);
      const double up = b + 1 < bones ? logistic(p.z() - joint, width) : 1.0;
      dense[static_cast<size_t>(b)] = below * (1.0 - up) + (b + 1 == bones ? below : 0.0);
      below *= up;
    }
    return dense;
  };
}

// `bones` bones scattered on a helix through the bar, each weighted by a Gaussian of the distance to it: weights
// that vary in all three directions with up to four overlapping bones, closer to a body's Laplace weights.
WeightField scattered_field(int bones, double z_min, double z_max, double radius) {
  return [=](const Eigen::Vector3d& p) {
    std::vector<double> dense(static_cast<size_t>(bones));
    for (int b = 0; b < bones; ++b) {
      const double angle = 2.4 * b;
      const Eigen::Vector3d bone(0.5 * radius * std::cos(angle), 0.5 * radius * std::sin(angle),
                                 z_min + (b + 0.5) * (z_max - z_min) / bones);
      dense[static_cast<size_t>(b)] = std::exp(-(p - bone).squaredNorm() / (2.0 * radius * radius));
    }
    return dense;
  };
}

double bounding_box_diagonal(const TetMesh& mesh) {
  return (mesh.vertices.colwise().maxCoeff() - mesh.vertices.colwise().minCoeff()).norm();
}

double largest_weight(const SkinWeights& weights, Eigen::Index v) {
  return weights.weight.row(v).maxCoeff();
}

struct Case {
  const char* name;
  TetMesh mesh;
  SkinWeights weights;
};

std::vector<Case> small_cases() {
  std::vector<Case> cases;
  {
    TetMesh mesh = make_bar(6, 6, 30, 2.0, -30.0, 2);
    SkinWeights weights = sample_weights(mesh, 2, two_bone_field(0.0, 2.0));
    cases.push_back({"two bones", std::move(mesh), std::move(weights)});
  }
  {
    // Far from the physical origin, as CT coordinates are.
    TetMesh mesh = make_bar(5, 6, 28, 2.5, -35.0, 3, Eigen::Vector3d(120.0, -240.0, 1350.0));
    SkinWeights weights = sample_weights(mesh, 3, three_bone_field(1350.0));
    cases.push_back({"three bones", std::move(mesh), std::move(weights)});
  }
  {
    TetMesh mesh = make_bar(6, 5, 32, 2.0, -32.0, 4);
    SkinWeights weights = sample_weights(mesh, 3, stacked_field(4, -32.0, 13.0));
    cases.push_back({"four bones, three influences", std::move(mesh), std::move(weights)});
  }
  return cases;
}

TEST(RotationCentres, MatchBruteForceOnSmallMeshes) {
  for (const Case& c : small_cases()) {
    SCOPED_TRACE(c.name);
    CorStats stats;
    Result<RotationCentres> fast = rotation_centres(c.mesh, c.weights, CorParams{}, ProgressHooks{}, &stats);
    Result<RotationCentres> slow = rotation_centres_brute_force(c.mesh, c.weights, CorParams{});
    ASSERT_TRUE(fast.ok()) << fast.status().to_string();
    ASSERT_TRUE(slow.ok()) << slow.status().to_string();
    ASSERT_EQ(fast->centre.rows(), c.mesh.vertex_count());
    EXPECT_EQ(fast->rigid, slow->rigid);
    EXPECT_GT(stats.centred_vertices, c.mesh.vertex_count() / 5);
    const Eigen::VectorXd distance = (fast->centre - slow->centre).rowwise().norm();
    const double diagonal = bounding_box_diagonal(c.mesh);
    EXPECT_LT(distance.maxCoeff(), 0.01 * diagonal);
    std::printf(
        "[ cor      ] %s: %lld vertices, %lld centred, %lld clusters, max |fast - brute| %.4f mm "
        "(%.4f%% of the diagonal), mean %.4f mm\n",
        c.name, static_cast<long long>(c.mesh.vertex_count()), static_cast<long long>(stats.centred_vertices),
        static_cast<long long>(stats.clusters), distance.maxCoeff(), 100.0 * distance.maxCoeff() / diagonal,
        distance.mean());
  }
}

TEST(RotationCentres, FinerQuantizationComesCloserToBruteForce) {
  const Case c = std::move(small_cases()[1]);
  Result<RotationCentres> slow = rotation_centres_brute_force(c.mesh, c.weights, CorParams{});
  ASSERT_TRUE(slow.ok());
  CorParams coarse;
  coarse.quantization = 8;
  CorParams fine;
  fine.quantization = 512;
  Result<RotationCentres> coarse_centres = rotation_centres(c.mesh, c.weights, coarse, ProgressHooks{}, nullptr);
  Result<RotationCentres> fine_centres = rotation_centres(c.mesh, c.weights, fine, ProgressHooks{}, nullptr);
  ASSERT_TRUE(coarse_centres.ok());
  ASSERT_TRUE(fine_centres.ok());
  const double coarse_error = (coarse_centres->centre - slow->centre).rowwise().norm().maxCoeff();
  const double fine_error = (fine_centres->centre - slow->centre).rowwise().norm().maxCoeff();
  EXPECT_LT(fine_error, coarse_error);
  EXPECT_LT(fine_error, 1e-3 * bounding_box_diagonal(c.mesh));
}

TEST(RotationCentres, FlagRigidVerticesAndKeepThemInPlace) {
  int64_t rigid_in_all_cases = 0;
  for (const Case& c : small_cases()) {
    SCOPED_TRACE(c.name);
    CorStats stats;
    Result<RotationCentres> centres = rotation_centres(c.mesh, c.weights, CorParams{}, ProgressHooks{}, &stats);
    ASSERT_TRUE(centres.ok());
    ASSERT_EQ(centres->rigid.size(), static_cast<size_t>(c.mesh.vertex_count()));
    int64_t rigid = 0;
    for (Eigen::Index v = 0; v < c.mesh.vertex_count(); ++v) {
      const int nonzero = static_cast<int>((c.weights.weight.row(v).array() > 0.0f).count());
      const bool dominated = static_cast<double>(largest_weight(c.weights, v)) >= 0.999 || nonzero < 2;
      EXPECT_EQ(centres->rigid[size_t(v)] != 0, dominated) << "vertex " << v;
      if (centres->rigid[size_t(v)] != 0) {
        ++rigid;
        EXPECT_EQ(centres->centre.row(v), c.mesh.vertices.row(v)) << "vertex " << v;
      }
    }
    rigid_in_all_cases += rigid;
    EXPECT_EQ(stats.rigid_vertices, rigid);
    EXPECT_EQ(stats.unsupported_vertices, 0);
    EXPECT_EQ(stats.rigid_vertices + stats.centred_vertices + stats.unsupported_vertices, c.mesh.vertex_count());
  }
  EXPECT_GT(rigid_in_all_cases, 500);
}

TEST(RotationCentres, KeepBlendedVertexInPlaceWhenNoTetSharesItsBones) {
  TetMesh mesh = make_bar(3, 3, 10, 2.0, -10.0, 3);
  SkinWeights weights = sample_weights(mesh, 2, two_bone_field(0.0, 2.0));
  // One more vertex, in no tet, blended between bones 0 and 2, a pair no tet holds.
  const Eigen::Index lonely = mesh.vertex_count();
  mesh.vertices.conservativeResize(lonely + 1, 3);
  mesh.vertices.row(lonely) << 50.0, 0.0, 0.0;
  weights.segment.conservativeResize(lonely + 1, 2);
  weights.weight.conservativeResize(lonely + 1, 2);
  weights.segment.row(lonely) << 2, 0;
  weights.weight.row(lonely) << 0.6f, 0.4f;
  for (const bool brute : {false, true}) {
    CorStats stats;
    Result<RotationCentres> centres = brute ? rotation_centres_brute_force(mesh, weights, CorParams{})
                                            : rotation_centres(mesh, weights, CorParams{}, ProgressHooks{}, &stats);
    ASSERT_TRUE(centres.ok()) << centres.status().to_string();
    EXPECT_EQ(centres->rigid[size_t(lonely)], 1);
    EXPECT_EQ(centres->centre.row(lonely), mesh.vertices.row(lonely));
    if (!brute) {
      EXPECT_EQ(stats.unsupported_vertices, 1);
    }
  }
}

TEST(RotationCentres, PutBlendedCentresNearTheJointPlaneOnTheAxisOfASymmetricBar) {
  // Bar of 12 x 12 mm across, z in [-30, 30], bones meeting at z = 0 with a blend symmetric in z.
  const double h = 2.0;
  const TetMesh mesh = make_bar(6, 6, 30, h, -30.0, 2);
  const SkinWeights weights = sample_weights(mesh, 2, two_bone_field(0.0, 3.0));
  Result<RotationCentres> centres = rotation_centres(mesh, weights, CorParams{}, ProgressHooks{}, nullptr);
  ASSERT_TRUE(centres.ok());
  int blended = 0;
  double worst_lateral = 0.0, worst_joint_slice = 0.0;
  for (Eigen::Index v = 0; v < mesh.vertex_count(); ++v) {
    if (centres->rigid[size_t(v)] != 0) continue;
    ++blended;
    const Eigen::Vector3d p = mesh.vertices.row(v).transpose();
    const Eigen::Vector3d c = centres->centre.row(v).transpose();
    // On the axis: the weights are the same across each slice and the cross-section is symmetric.
    worst_lateral = std::max(worst_lateral, std::hypot(c.x(), c.y()));
    // Drawn towards the joint plane, never past the vertex's own slice.
    EXPECT_LE(std::abs(c.z()), std::abs(p.z()) + 0.25 * h) << "vertex at z = " << p.z();
    EXPECT_LE(std::abs(c.z()), 15.0) << "vertex at z = " << p.z();
    if (std::abs(p.z()) < 1e-9) worst_joint_slice = std::max(worst_joint_slice, std::abs(c.z()));
  }
  EXPECT_GT(blended, 200);
  EXPECT_LT(worst_lateral, 0.25 * h);
  EXPECT_LT(worst_joint_slice, 0.25 * h);
  // The centre depends on the weights alone, so a whole slice shares one centre.
  for (Eigen::Index v = 0; v < mesh.vertex_count(); ++v) {
    if (centres->rigid[size_t(v)] != 0) continue;
    const Eigen::Index first_of_slice = v - v % (7 * 7);
    EXPECT_EQ(centres->centre.row(v), centres->centre.row(first_of_slice)) << "vertex " << v;
  }
  std::printf(
      "[ cor      ] symmetric bar: %d blended vertices, worst distance from the axis %.4f mm, "
      "joint-slice centre |z| %.4f mm\n",
      blended, worst_lateral, worst_joint_slice);
}

TEST(RotationCentres, GiveIdenticalResultsOnEveryRunAndThreadCount) {
  const Case c = std::move(small_cases()[2]);
  set_thread_count(1);
  Result<RotationCentres> one_thread = rotation_centres(c.mesh, c.weights, CorParams{}, ProgressHooks{}, nullptr);
  set_thread_count(0);
  Result<RotationCentres> first = rotation_centres(c.mesh, c.weights, CorParams{}, ProgressHooks{}, nullptr);
  Result<RotationCentres> second = rotation_centres(c.mesh, c.weights, CorParams{}, ProgressHooks{}, nullptr);
  ASSERT_TRUE(one_thread.ok() && first.ok() && second.ok());
  EXPECT_TRUE(first->centre == second->centre);
  EXPECT_EQ(first->rigid, second->rigid);
  EXPECT_TRUE(first->centre == one_thread->centre);
  EXPECT_EQ(first->rigid, one_thread->rigid);
}

TEST(RotationCentres, RejectParametersOutsideTheirRanges) {
  const std::vector<std::pair<CorParams, const char*>> bad = {
      {{0.0, 0.999, 64}, "sigma"},          {{-0.1, 0.999, 64}, "sigma"},        {{1.5, 0.999, 64}, "sigma"},
      {{std::nan(""), 0.999, 64}, "sigma"}, {{0.1, 0.5, 64}, "rigid_threshold"}, {{0.1, 1.01, 64}, "rigid_threshold"},
      {{0.1, 0.999, 3}, "quantization"},    {{0.1, 0.999, 5000}, "quantization"}};
  const Case c = std::move(small_cases()[0]);
  for (const auto& [params, field] : bad) {
    const Status status = validate(params);
    EXPECT_EQ(status.code(), StatusCode::kInvalidArgument) << field;
    EXPECT_NE(status.message().find(field), std::string::npos) << status.message();
    EXPECT_EQ(rotation_centres(c.mesh, c.weights, params, ProgressHooks{}, nullptr).status().code(),
              StatusCode::kInvalidArgument);
    EXPECT_EQ(rotation_centres_brute_force(c.mesh, c.weights, params).status().code(), StatusCode::kInvalidArgument);
  }
  EXPECT_TRUE(validate(CorParams{}).ok());
}

TEST(RotationCentres, RejectWeightsThatDoNotBelongToTheMesh) {
  const TetMesh mesh = make_bar(3, 3, 6, 2.0, -6.0, 2);
  const SkinWeights good = sample_weights(mesh, 2, two_bone_field(0.0, 2.0));
  std::vector<std::pair<const char*, std::function<void(TetMesh&, SkinWeights&)>>> breakages = {
      {"one weight row short",
       [](TetMesh&, SkinWeights& w) {
         w.segment.conservativeResize(w.segment.rows() - 1, w.influences);
         w.weight.conservativeResize(w.weight.rows() - 1, w.influences);
       }},
      {"segment index past the segment count", [](TetMesh&, SkinWeights& w) { w.segment(10, 0) = 2; }},
      {"segment index below -1", [](TetMesh&, SkinWeights& w) { w.segment(10, 0) = -2; }},
      {"segment counts differ", [](TetMesh& m, SkinWeights&) { m.segment_count = 3; }},
      {"negative weight", [](TetMesh&, SkinWeights& w) { w.weight(4, 1) = -0.5f; }},
      {"weight on slot -1",
       [](TetMesh&, SkinWeights& w) {
         w.segment(4, 1) = -1;
         w.weight(4, 1) = 0.5f;
       }},
      {"segment repeated in a row",
       [](TetMesh&, SkinWeights& w) {
         w.segment(20, 1) = w.segment(20, 0);
         w.weight(20, 1) = 0.1f;
       }},
      {"columns disagree with influences", [](TetMesh&, SkinWeights& w) { w.influences = 3; }},
      {"tet past the last vertex", [](TetMesh& m, SkinWeights&) { m.tets(5, 2) = static_cast<int>(m.vertex_count()); }},
      {"NaN vertex", [](TetMesh& m, SkinWeights&) { m.vertices(3, 1) = std::nan(""); }},
  };
  for (const auto& [what, breakage] : breakages) {
    TetMesh mesh_copy = mesh;
    SkinWeights weights = good;
    breakage(mesh_copy, weights);
    Result<RotationCentres> fast = rotation_centres(mesh_copy, weights, CorParams{}, ProgressHooks{}, nullptr);
    Result<RotationCentres> slow = rotation_centres_brute_force(mesh_copy, weights, CorParams{});
    EXPECT_EQ(fast.status().code(), StatusCode::kInvalidArgument) << what;
    EXPECT_EQ(slow.status().code(), StatusCode::kInvalidArgument) << what;
    EXPECT_FALSE(fast.status().message().empty()) << what;
  }
}

TEST(RotationCentres, ReturnNothingForAnEmptyMesh) {
  TetMesh mesh;
  mesh.segment_count = 2;
  SkinWeights weights;
  weights.segment_count = 2;
  weights.influences = 2;
  Result<RotationCentres> centres = rotation_centres(mesh, weights, CorParams{}, ProgressHooks{}, nullptr);
  ASSERT_TRUE(centres.ok()) << centres.status().to_string();
  EXPECT_EQ(centres->centre.rows(), 0);
  EXPECT_TRUE(centres->rigid.empty());
}

TEST(RotationCentres, StopWithCancelledWhenAsked) {
  const Case c = std::move(small_cases()[0]);
  CancelFlag flag;
  flag.cancel();
  ProgressHooks hooks;
  hooks.cancel_requested = flag.as_hook();
  Result<RotationCentres> centres = rotation_centres(c.mesh, c.weights, CorParams{}, hooks, nullptr);
  EXPECT_EQ(centres.status().code(), StatusCode::kCancelled);
}

TEST(RotationCentres, StopWithCancelledWhenAskedHalfwayThroughTheVertices) {
  const Case c = std::move(small_cases()[2]);
  int polls = 0;
  double last_fraction = 0.0;
  ProgressHooks hooks;
  hooks.on_progress = [&](std::string_view, double fraction) { last_fraction = fraction; };
  hooks.cancel_requested = [&] { return ++polls > 8; };  // polls are serialized: one vertex chunk at a time
  set_thread_count(1);
  Result<RotationCentres> centres = rotation_centres(c.mesh, c.weights, CorParams{}, hooks, nullptr);
  set_thread_count(0);
  EXPECT_EQ(centres.status().code(), StatusCode::kCancelled);
  EXPECT_NE(centres.status().message().find("cor"), std::string::npos) << centres.status().message();
  EXPECT_GT(last_fraction, 0.1);
  EXPECT_LT(last_fraction, 1.0);
}

TEST(RotationCentres, ReportProgressUnderTheCorStageUpToOne) {
  const Case c = std::move(small_cases()[2]);
  std::vector<double> seen;
  ProgressHooks hooks;
  hooks.on_progress = [&](std::string_view stage, double fraction) {
    EXPECT_EQ(stage, "cor");
    seen.push_back(fraction);
  };
  ASSERT_TRUE(rotation_centres(c.mesh, c.weights, CorParams{}, hooks, nullptr).ok());
  ASSERT_GE(seen.size(), 3u);
  EXPECT_TRUE(std::is_sorted(seen.begin(), seen.end()));
  EXPECT_DOUBLE_EQ(seen.back(), 1.0);
}

// Not a timing assertion: prints what a body-sized mesh costs, so regressions in scaling are visible in the log.
// A timing print, not an assertion: run with --gtest_also_run_disabled_tests (benchmarks live in bench/).
TEST(RotationCentres, DISABLED_ScaleToAHundredAndSeventyThousandVertices) {
  const TetMesh mesh = make_bar(40, 40, 100, 2.0, -100.0, 16);
  const std::vector<std::pair<const char*, WeightField>> fields = {
      {"6 stacked bones", stacked_field(6, -100.0, 200.0 / 6.0)},
      {"16 scattered bones", scattered_field(16, -100.0, 100.0, 25.0)}};
  for (const auto& [name, field] : fields) {
    const SkinWeights weights = sample_weights(mesh, 4, field);
    CorStats stats;
    Result<RotationCentres> centres = rotation_centres(mesh, weights, CorParams{}, ProgressHooks{}, &stats);
    ASSERT_TRUE(centres.ok()) << centres.status().to_string();
    EXPECT_TRUE(centres->centre.allFinite());
    EXPECT_EQ(stats.rigid_vertices + stats.centred_vertices + stats.unsupported_vertices, mesh.vertex_count());
    std::printf(
        "[ cor      ] %s, %lld vertices, %lld tets, %d threads: %.3f s; %lld pair buckets, %lld clusters; "
        "%lld centred, %lld rigid, %lld unsupported\n",
        name, static_cast<long long>(mesh.vertex_count()), static_cast<long long>(mesh.tet_count()), thread_count(),
        stats.seconds, static_cast<long long>(stats.pair_buckets), static_cast<long long>(stats.clusters),
        static_cast<long long>(stats.centred_vertices), static_cast<long long>(stats.rigid_vertices),
        static_cast<long long>(stats.unsupported_vertices));
  }
}

}  // namespace
}  // namespace posewarp::cor
