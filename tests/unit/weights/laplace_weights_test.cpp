#include "posewarp/weights/laplace_weights.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <map>
#include <numeric>
#include <set>
#include <string>
#include <vector>

#include "posewarp/common/parallel.h"
#include "posewarp/weights/fem_laplacian.h"
#include "weights/grid_mesh.h"

namespace posewarp::weights {
namespace {

using testing::grid_mesh;
using testing::three_bone_bar;
using testing::two_bone_bar;

// Segment of every vertex of a bone tet of exactly one segment, -1 elsewhere; -2 where segments meet.
std::vector<int> bone_segment_of_vertices(const TetMesh& mesh) {
  std::vector<int> segment(static_cast<size_t>(mesh.vertex_count()), -1);
  for (Eigen::Index t = 0; t < mesh.tet_count(); ++t) {
    const int s = mesh.tet_class[t] - kFirstBoneClass;
    if (s < 0) continue;
    for (int a = 0; a < 4; ++a) {
      int& v = segment[mesh.tets(t, a)];
      v = (v == -1 || v == s) ? s : -2;
    }
  }
  return segment;
}

Result<SkinWeights> run(const TetMesh& mesh, const WeightsParams& params = {}, WeightStats* stats = nullptr) {
  return laplace_weights(mesh, params, ProgressHooks{}, stats);
}

TEST(Weights, SumToOneAtEveryVertex) {
  const TetMesh mesh = three_bone_bar(0.2);
  WeightStats stats;
  const Result<SkinWeights> weights = run(mesh, {}, &stats);
  ASSERT_TRUE(weights.ok()) << weights.status().to_string();
  ASSERT_EQ(weights->vertex_count(), mesh.vertex_count());
  EXPECT_EQ(weights->influences, 3);
  EXPECT_EQ(weights->segment_count, 3);
  for (Eigen::Index v = 0; v < weights->vertex_count(); ++v) {
    double sum = 0.0;
    for (int i = 0; i < weights->influences; ++i) sum += weights->weight(v, i);
    EXPECT_NEAR(sum, 1.0, 1e-6) << "vertex " << v;
  }
  EXPECT_LE(stats.max_partition_error, 1e-9);
  EXPECT_LE(stats.max_partition_error_float, 1e-6);
  EXPECT_LE(stats.max_partition_error_raw, 1e-9);
  EXPECT_GT(stats.free_vertices, 0);
  EXPECT_EQ(stats.free_vertices + stats.fixed_vertices, mesh.vertex_count());
}

TEST(Weights, AreOneOnTheirOwnSegmentAtBoneVertices) {
  const TetMesh mesh = three_bone_bar(0.2);
  const Result<SkinWeights> weights = run(mesh);
  ASSERT_TRUE(weights.ok()) << weights.status().to_string();
  const std::vector<int> bone = bone_segment_of_vertices(mesh);
  int64_t checked = 0;
  for (Eigen::Index v = 0; v < mesh.vertex_count(); ++v) {
    if (bone[v] < 0) continue;
    EXPECT_EQ(weights->segment(v, 0), bone[v]);
    EXPECT_EQ(weights->weight(v, 0), 1.0f);
    for (int i = 1; i < weights->influences; ++i) {
      EXPECT_EQ(weights->segment(v, i), -1);
      EXPECT_EQ(weights->weight(v, i), 0.0f);
    }
    ++checked;
  }
  EXPECT_GT(checked, 0);
}

TEST(Weights, VaryLinearlyAndMonotonicallyAlongABarBetweenTwoBones) {
  // Bone 0 covers x in [0, 3] mm, bone 1 x in [9, 12] mm; the harmonic function between them is linear in x, which
  // linear FEM reproduces exactly on any mesh.
  const TetMesh mesh = two_bone_bar(12, 3);
  const Result<Eigen::MatrixXd> dense = laplace_weights_dense(mesh, {}, ProgressHooks{}, nullptr);
  ASSERT_TRUE(dense.ok()) << dense.status().to_string();
  std::vector<Eigen::Index> by_x(static_cast<size_t>(mesh.vertex_count()));
  std::iota(by_x.begin(), by_x.end(), 0);
  std::stable_sort(by_x.begin(), by_x.end(),
                   [&](Eigen::Index a, Eigen::Index b) { return mesh.vertices(a, 0) < mesh.vertices(b, 0); });
  double previous = 1.0;
  for (const Eigen::Index v : by_x) {
    const double x = mesh.vertices(v, 0);
    const double expected = std::clamp((9.0 - x) / 6.0, 0.0, 1.0);
    EXPECT_NEAR((*dense)(v, 0), expected, 1e-9) << "x = " << x;
    EXPECT_NEAR((*dense)(v, 1), 1.0 - expected, 1e-9) << "x = " << x;
    EXPECT_LE((*dense)(v, 0), previous + 1e-12) << "weight of bone 0 grows along the bar at x = " << x;
    previous = (*dense)(v, 0);
  }

  const Result<SkinWeights> sparse = run(mesh);
  ASSERT_TRUE(sparse.ok());
  for (Eigen::Index v = 0; v < mesh.vertex_count(); ++v) {
    const double x = mesh.vertices(v, 0);
    const double w0 = std::clamp((9.0 - x) / 6.0, 0.0, 1.0);
    const double largest = std::max(w0, 1.0 - w0);
    EXPECT_NEAR(sparse->weight(v, 0), largest, 1e-6);
    if (std::abs(w0 - 0.5) > 1e-6) {
      EXPECT_EQ(sparse->segment(v, 0), w0 > 0.5 ? 0 : 1) << "x = " << x;
    }
  }
}

TEST(Weights, SolveTheLaplaceEquationToASmallResidual) {
  const TetMesh mesh = three_bone_bar(0.25, 3);
  WeightStats stats;
  const Result<Eigen::MatrixXd> dense = laplace_weights_dense(mesh, {}, ProgressHooks{}, &stats);
  ASSERT_TRUE(dense.ok()) << dense.status().to_string();
  EXPECT_LT(stats.max_laplace_residual, 1e-8);
  // Independent check: (K W) vanishes on every row that is not a bone vertex.
  const Eigen::SparseMatrix<double> k = fem_laplacian(mesh);
  const Eigen::MatrixXd kw = k * (*dense);
  const Eigen::VectorXd row_scale = k.cwiseAbs() * Eigen::VectorXd::Ones(k.cols());
  const std::vector<int> bone = bone_segment_of_vertices(mesh);
  double worst = 0.0;
  for (Eigen::Index v = 0; v < mesh.vertex_count(); ++v) {
    if (bone[v] == -1) worst = std::max(worst, kw.row(v).cwiseAbs().maxCoeff());
  }
  EXPECT_LT(worst / row_scale.maxCoeff(), 1e-8);
}

TEST(Weights, GiveAVertexSharedByTwoBonesToTheSegmentWithMostTets) {
  // Bones 0 and 1 touch at x = 3 mm; soft tissue beyond x = 6 mm.
  const TetMesh mesh = grid_mesh(
      8, 3, 3, 1.0,
      [](const Eigen::Vector3d& c) {
        return c.x() < 3 ? kFirstBoneClass : c.x() < 6 ? kFirstBoneClass + 1 : kSoftTissueClass;
      },
      2);
  std::vector<std::map<int, int>> incident(static_cast<size_t>(mesh.vertex_count()));
  for (Eigen::Index t = 0; t < mesh.tet_count(); ++t) {
    if (mesh.tet_class[t] < kFirstBoneClass) continue;
    for (int a = 0; a < 4; ++a) ++incident[mesh.tets(t, a)][mesh.tet_class[t] - kFirstBoneClass];
  }
  WeightStats stats;
  const Result<SkinWeights> weights = run(mesh, {}, &stats);
  ASSERT_TRUE(weights.ok()) << weights.status().to_string();
  std::set<int> owners_seen;
  int64_t shared = 0;
  for (Eigen::Index v = 0; v < mesh.vertex_count(); ++v) {
    if (incident[v].size() < 2) continue;
    ++shared;
    const int expected = incident[v][1] > incident[v][0] ? 1 : 0;  // ties go to the lower segment
    owners_seen.insert(expected);
    EXPECT_EQ(weights->segment(v, 0), expected) << "vertex " << v;
    EXPECT_EQ(weights->weight(v, 0), 1.0f);
  }
  EXPECT_EQ(shared, 16);  // the 4 x 4 vertices of the plane x = 3
  EXPECT_EQ(stats.multi_segment_vertices, shared);
  EXPECT_EQ(owners_seen, (std::set<int>{0, 1}));  // both rules are exercised
}

// The two-bone bar with a loose block of soft tissue beyond bone 1 (x in [15, 17] mm) and a vertex in no tet
// next to bone 0.
TetMesh bar_with_islands() {
  TetMesh mesh = grid_mesh(
      17, 3, 3, 1.0,
      [](const Eigen::Vector3d& c) {
        if (c.x() < 3) return kFirstBoneClass;
        if (c.x() < 9) return kSoftTissueClass;
        if (c.x() < 12) return kFirstBoneClass + 1;
        if (c.x() < 15) return 0;
        return kSoftTissueClass;
      },
      2);
  mesh.vertices.conservativeResize(mesh.vertex_count() + 1, 3);
  mesh.vertices.row(mesh.vertex_count() - 1) << -2.0, 1.0, 1.0;
  return mesh;
}

TEST(Weights, AttachAnIslandWithoutBoneToTheNearestSegment) {
  const TetMesh mesh = bar_with_islands();
  WeightStats stats;
  WeightsParams params;
  params.islands = IslandPolicy::kAttachNearest;
  const Result<SkinWeights> weights = run(mesh, params, &stats);
  ASSERT_TRUE(weights.ok()) << weights.status().to_string();
  EXPECT_EQ(stats.islands_attached, 2);
  EXPECT_EQ(stats.island_vertices, 3 * 4 * 4 + 1);
  for (Eigen::Index v = 0; v < mesh.vertex_count(); ++v) {
    const double x = mesh.vertices(v, 0);
    if (x >= 15.0) {
      EXPECT_EQ(weights->segment(v, 0), 1);
      EXPECT_EQ(weights->weight(v, 0), 1.0f);
    }
    if (x < 0.0) {
      EXPECT_EQ(weights->segment(v, 0), 0);
      EXPECT_EQ(weights->weight(v, 0), 1.0f);
    }
  }
  EXPECT_LE(stats.max_partition_error, 1e-9);
}

TEST(Weights, FailOnAnIslandWithoutBoneWhenAskedTo) {
  WeightsParams params;
  params.islands = IslandPolicy::kFail;
  const Result<SkinWeights> weights = run(bar_with_islands(), params);
  ASSERT_FALSE(weights.ok());
  EXPECT_EQ(weights.status().code(), StatusCode::kFailedPrecondition);
  const std::string message = weights.status().message();
  EXPECT_NE(message.find("2 piece(s)"), std::string::npos) << message;
  EXPECT_NE(message.find("49 vertices"), std::string::npos) << message;
  EXPECT_NE(message.find("(16.0, 1.5, 1.5) mm"), std::string::npos) << message;  // the block's centroid
  EXPECT_NE(message.find("kAttachNearest"), std::string::npos) << message;
}

TEST(Weights, FailClearlyWithoutBoneTets) {
  const TetMesh mesh = grid_mesh(
      3, 3, 3, 1.0, [](const Eigen::Vector3d&) { return kSoftTissueClass; }, 2);
  const Result<SkinWeights> weights = run(mesh);
  ASSERT_FALSE(weights.ok());
  EXPECT_EQ(weights.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(weights.status().message().find("no tet of the mesh is bone"), std::string::npos);
}

TEST(Weights, RejectMalformedMeshes) {
  const TetMesh good = two_bone_bar();
  ASSERT_TRUE(run(good).ok());
  const auto expect_invalid = [](const TetMesh& mesh, const std::string& words) {
    const Result<SkinWeights> weights = run(mesh);
    ASSERT_FALSE(weights.ok()) << words;
    EXPECT_EQ(weights.status().code(), StatusCode::kInvalidArgument) << weights.status().to_string();
    EXPECT_NE(weights.status().message().find(words), std::string::npos) << weights.status().to_string();
  };
  TetMesh mesh = good;
  mesh.segment_count = 0;
  expect_invalid(mesh, "segment_count is 0");
  mesh = good;
  mesh.tets(5, 2) = static_cast<int>(good.vertex_count());
  expect_invalid(mesh, "index a vertex outside");
  mesh = good;
  mesh.tets(5, 2) = -1;
  expect_invalid(mesh, "index a vertex outside");
  mesh = good;
  std::swap(mesh.tets(7, 1), mesh.tets(7, 2));
  expect_invalid(mesh, "inverted or flat, the first is tet 7");
  mesh = good;
  mesh.tet_class[3] = kFirstBoneClass + 2;
  expect_invalid(mesh, "class outside");
  mesh = good;
  mesh.tet_class[3] = 0;
  expect_invalid(mesh, "class outside");
  mesh = good;
  mesh.tet_class.resize(4);
  expect_invalid(mesh, "tet classes");
  mesh = good;
  mesh.vertices(0, 1) = std::nan("");
  expect_invalid(mesh, "non-finite");
  expect_invalid(TetMesh{Eigen::MatrixXd(0, 3), Eigen::MatrixXi(0, 4), Eigen::VectorXi(0), 1}, "empty");
}

TEST(Weights, RejectBadParameters) {
  for (const int k : {0, 9, -1}) {
    WeightsParams params;
    params.max_influences = k;
    EXPECT_EQ(validate(params).code(), StatusCode::kInvalidArgument);
    EXPECT_EQ(run(two_bone_bar(), params).status().code(), StatusCode::kInvalidArgument);
  }
  WeightsParams params;
  params.prune_below = 0.5;
  EXPECT_EQ(validate(params).code(), StatusCode::kInvalidArgument);
  params.prune_below = std::nan("");
  EXPECT_EQ(validate(params).code(), StatusCode::kInvalidArgument);
  EXPECT_TRUE(validate(WeightsParams{}).ok());
}

// A 6 mm cube of soft tissue with four bones (2 mm cubes) in alternate corners: inner vertices see all four.
TetMesh four_corner_block(double jitter, unsigned seed) {
  return grid_mesh(
      6, 6, 6, 1.0,
      [](const Eigen::Vector3d& c) {
        const bool x0 = c.x()<2, x1 = c.x()> 4, y0 = c.y()<2, y1 = c.y()> 4, z0 = c.z()<2, z1 = c.z()> 4;
        if (x0 && y0 && z0) return kFirstBoneClass;
        if (x1 && y1 && z0) return kFirstBoneClass + 1;
        if (x1 && y0 && z1) return kFirstBoneClass + 2;
        if (x0 && y1 && z1) return kFirstBoneClass + 3;
        return kSoftTissueClass;
      },
      4, jitter, seed);
}

TEST(Weights, KeepTheLargestKSortedDescending) {
  const TetMesh mesh = four_corner_block(0.1, 1);
  const Result<Eigen::MatrixXd> dense = laplace_weights_dense(mesh, {}, ProgressHooks{}, nullptr);
  ASSERT_TRUE(dense.ok()) << dense.status().to_string();
  WeightsParams params;
  params.max_influences = 2;
  const Result<SkinWeights> weights = run(mesh, params);
  ASSERT_TRUE(weights.ok()) << weights.status().to_string();
  ASSERT_EQ(weights->influences, 2);
  int64_t blended = 0;
  for (Eigen::Index v = 0; v < mesh.vertex_count(); ++v) {
    Eigen::VectorXd raw = dense->row(v).transpose().cwiseMax(0.0).cwiseMin(1.0);
    raw /= raw.sum();
    std::vector<int> order(4);
    std::iota(order.begin(), order.end(), 0);
    std::stable_sort(order.begin(), order.end(), [&](int a, int b) { return raw[a] > raw[b]; });
    if (raw[order[1]] < 1e-6) continue;  // a bone vertex or nearly so
    ++blended;
    EXPECT_EQ(weights->segment(v, 0), order[0]);
    EXPECT_EQ(weights->segment(v, 1), order[1]);
    EXPECT_GE(weights->weight(v, 0), weights->weight(v, 1));
    EXPECT_NEAR(weights->weight(v, 0), raw[order[0]] / (raw[order[0]] + raw[order[1]]), 1e-6);
    EXPECT_NEAR(weights->weight(v, 0) + weights->weight(v, 1), 1.0, 1e-6);
    if (raw[order[3]] > 1e-6) {
      EXPECT_GT(raw[order[2]], 0.0);  // a vertex that really had four influences lost two
    }
  }
  EXPECT_GT(blended, 50);
}

TEST(Weights, DropWeightsBelowThePruneThreshold) {
  // A 2 x 2 mm channel walled by bone 0 leads away from bone 1 (z < 2 mm): bone 1's weight decays by about a
  // factor 10 per mm along it, far below prune_below at its closed end.
  const TetMesh mesh = grid_mesh(
      4, 4, 16, 1.0,
      [](const Eigen::Vector3d& c) {
        if (c.z() < 2) return kFirstBoneClass + 1;
        const bool wall = c.x() < 1 || c.x() > 3 || c.y() < 1 || c.y() > 3 || c.z() > 15;
        return c.z() > 4 && wall ? kFirstBoneClass : kSoftTissueClass;
      },
      2);
  WeightsParams keep_all;
  keep_all.prune_below = 0.0;
  const Result<SkinWeights> unpruned = run(mesh, keep_all);
  const Result<SkinWeights> pruned = run(mesh);
  ASSERT_TRUE(unpruned.ok() && pruned.ok());
  int64_t tiny = 0;
  for (Eigen::Index v = 0; v < mesh.vertex_count(); ++v) {
    if (unpruned->segment(v, 1) < 0 || unpruned->weight(v, 1) >= 1e-6f) continue;
    ++tiny;  // a positive weight below the default threshold
    EXPECT_GT(unpruned->weight(v, 1), 0.0f);
    EXPECT_EQ(pruned->segment(v, 0), unpruned->segment(v, 0));
    EXPECT_EQ(pruned->weight(v, 0), 1.0f);
    EXPECT_EQ(pruned->segment(v, 1), -1);
  }
  EXPECT_GT(tiny, 0);
}

TEST(Weights, AreTheSameWithCholmodAndSimplicialLdlt) {
  const TetMesh mesh = three_bone_bar(0.2, 5);
  WeightsParams cholmod_params, ldlt_params;
  cholmod_params.prefer_cholmod = true;
  ldlt_params.prefer_cholmod = false;
  WeightStats cholmod_stats, ldlt_stats;
  const Result<Eigen::MatrixXd> a = laplace_weights_dense(mesh, cholmod_params, ProgressHooks{}, &cholmod_stats);
  const Result<Eigen::MatrixXd> b = laplace_weights_dense(mesh, ldlt_params, ProgressHooks{}, &ldlt_stats);
  ASSERT_TRUE(a.ok()) << a.status().to_string();
  ASSERT_TRUE(b.ok()) << b.status().to_string();
  EXPECT_EQ(cholmod_stats.solver, "cholmod-supernodal-llt") << cholmod_stats.cholmod_failure;
  EXPECT_EQ(ldlt_stats.solver, "simplicial-ldlt");
  EXPECT_LT((*a - *b).cwiseAbs().maxCoeff(), 1e-8);
}

TEST(Weights, AreTheSameForEveryThreadCount) {
  const TetMesh mesh = three_bone_bar(0.2, 9);
  set_thread_count(1);
  const Result<SkinWeights> one = run(mesh);
  set_thread_count(2);
  const Result<SkinWeights> two = run(mesh);
  set_thread_count(0);
  ASSERT_TRUE(one.ok() && two.ok());
  EXPECT_EQ(one->segment, two->segment);
  EXPECT_EQ(one->weight, two->weight);
}

TEST(Weights, StayInTheUnitIntervalWhereLinearFemOvershoots) {
  // The four-corner block flattened to 0.1 mm in z and jittered: its obtuse tets have positive off-diagonal
  // stiffness, which breaks the discrete maximum principle.
  TetMesh mesh = four_corner_block(0.1, 3);
  mesh.vertices.col(2) *= 0.1;
  WeightStats stats;
  const Result<SkinWeights> weights = run(mesh, {}, &stats);
  ASSERT_TRUE(weights.ok()) << weights.status().to_string();
  EXPECT_LT(stats.min_raw_weight, -1e-3);
  EXPECT_GT(stats.max_raw_weight, 1.0 + 1e-3);
  EXPECT_GE(weights->weight.minCoeff(), 0.0f);
  EXPECT_LE(weights->weight.maxCoeff(), 1.0f);
  EXPECT_LE(stats.max_partition_error, 1e-9);
  EXPECT_LE(stats.max_partition_error_raw, 1e-9);  // the raw weights still sum to one
}

TEST(Weights, StopWhenCancelled) {
  ProgressHooks hooks;
  hooks.cancel_requested = [] { return true; };
  const Result<SkinWeights> weights = laplace_weights(three_bone_bar(), {}, hooks, nullptr);
  ASSERT_FALSE(weights.ok());
  EXPECT_EQ(weights.status().code(), StatusCode::kCancelled);
}

TEST(Weights, ReportProgressUnderTheStageName) {
  std::vector<std::pair<std::string, double>> reports;
  ProgressHooks hooks;
  hooks.on_progress = [&](std::string_view stage, double fraction) { reports.emplace_back(stage, fraction); };
  ASSERT_TRUE(laplace_weights(three_bone_bar(), {}, hooks, nullptr).ok());
  ASSERT_GE(reports.size(), 3u);
  for (size_t i = 0; i < reports.size(); ++i) {
    EXPECT_EQ(reports[i].first, "weights");
    if (i > 0) {
      EXPECT_GE(reports[i].second, reports[i - 1].second);
    }
  }
  EXPECT_EQ(reports.back().second, 1.0);
}

// Not a benchmark (nothing is asserted about time): prints where the time goes on a body-sized mesh, a 39 x 39 x 127
// mm bar of 1 mm cubes (~200k vertices, ~1.1M tets) with five bones along its axis. Disabled because it takes
// seconds to minutes (the factorization's speed is the BLAS's); run it with --gtest_also_run_disabled_tests.
TEST(WeightsTiming, DISABLED_PrintsTheTimeOfEachStepOnA200kVertexMesh) {
  const TetMesh mesh = grid_mesh(
      39, 39, 127, 1.0,
      [](const Eigen::Vector3d& c) {
        const double r2 = (c.x() - 19.5) * (c.x() - 19.5) + (c.y() - 19.5) * (c.y() - 19.5);
        if (r2 > 64.0) return kSoftTissueClass;
        const int slot = static_cast<int>(c.z()) / 25;  // bones 21 mm long, joints 4 mm
        return static_cast<int>(c.z()) % 25 < 21 ? kFirstBoneClass + std::min(slot, 4) : kSoftTissueClass;
      },
      5, 0.1);
  {
    WeightStats stats;
    const WeightsParams params;
    const Result<SkinWeights> weights = run(mesh, params, &stats);
    ASSERT_TRUE(weights.ok()) << weights.status().to_string();
    std::printf(
        "[ timing   ] %lld vertices, %lld tets, %lld free, %d segments, %s: assemble %.3f s, factor %.3f s (ordering "
        "%.3f s), "
        "solve %.3f s, finish %.3f s; %s ordering, nnz(L) %lld, %.1f Gflop; residual %.2e, raw range [%.4f, %.4f], "
        "partition error %.1e (float %.1e)\n",
        static_cast<long long>(mesh.vertex_count()), static_cast<long long>(mesh.tet_count()),
        static_cast<long long>(stats.free_vertices), stats.segments, stats.solver.c_str(), stats.assemble_seconds,
        stats.factor_seconds, stats.ordering_seconds, stats.solve_seconds, stats.finish_seconds, stats.ordering.c_str(),
        static_cast<long long>(stats.factor_nonzeros), stats.factor_flops * 1e-9, stats.max_laplace_residual,
        stats.min_raw_weight, stats.max_raw_weight, stats.max_partition_error, stats.max_partition_error_float);
  }
}

}  // namespace
}  // namespace posewarp::weights
