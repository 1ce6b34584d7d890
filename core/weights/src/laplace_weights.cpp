// laplace_weights: bone ownership, mesh pieces, one factorization for all segments (sparse_solve.cpp), clamp and
// top-k.
#include "posewarp/common/exception_wall.h"
#include "posewarp/weights/laplace_weights.h"

#include <Eigen/Geometry>
#include <Eigen/SparseCore>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <exception>
#include <functional>
#include <limits>
#include <mutex>
#include <new>
#include <numeric>
#include <utility>
#include <vector>
#include <string_view>

#include "point_kd_tree.h"
#include "sparse_solve.h"
#include "posewarp/common/parallel.h"
#include "posewarp/weights/fem_laplacian.h"
#include "posewarp/common/stopwatch.h"

namespace posewarp::weights {
namespace {

using SparseMatrix = Eigen::SparseMatrix<double>;

constexpr int kMaxInfluences = 8;
constexpr double kMaxPruneBelow = 0.01;

// Fractions of the stage's progress at the end of each step.
constexpr double kAssembledFraction = 0.25;
constexpr double kFactoredFraction = 0.75;
constexpr double kSolvedFraction = 0.85;

std::string format_mm(const Eigen::Vector3d& p) {
  char text[96];
  std::snprintf(text, sizeof(text), "(%.1f, %.1f, %.1f) mm", p.x(), p.y(), p.z());
  return text;
}

// Keeps the largest of values reported by parallel chunks.
class MaxReduction {
 public:
  void report(double value) {
    std::lock_guard<std::mutex> lock(mutex_);
    value_ = std::max(value_, value);
  }
  double value() const { return value_; }

 private:
  std::mutex mutex_;
  double value_ = 0.0;
};

Status check_mesh(const TetMesh& mesh) {
  if (mesh.segment_count < 1) {
    return invalid_argument_error("mesh.segment_count is " + std::to_string(mesh.segment_count) +
                                  "; skinning weights need at least one bone segment (tet class 2 + k)");
  }
  if (mesh.vertices.cols() != 3 || mesh.tets.cols() != 4) {
    return invalid_argument_error("mesh arrays have the wrong shape: vertices are #V x " +
                                  std::to_string(mesh.vertices.cols()) + " (need 3) and tets #T x " +
                                  std::to_string(mesh.tets.cols()) + " (need 4)");
  }
  if (mesh.tet_class.size() != mesh.tets.rows()) {
    return invalid_argument_error("mesh has " + std::to_string(mesh.tets.rows()) + " tets but " +
                                  std::to_string(mesh.tet_class.size()) + " tet classes; give one class per tet");
  }
  if (mesh.vertex_count() == 0 || mesh.tet_count() == 0) {
    return invalid_argument_error("mesh is empty (" + std::to_string(mesh.vertex_count()) + " vertices, " +
                                  std::to_string(mesh.tet_count()) + " tets); mesh the body first");
  }
  for (int64_t v = 0; v < mesh.vertex_count(); ++v) {
    if (!mesh.vertices.row(v).allFinite()) {
      return invalid_argument_error("mesh vertex " + std::to_string(v) + " has a non-finite coordinate");
    }
  }
  const int64_t vertex_count = mesh.vertex_count();
  const int last_class = kFirstBoneClass + mesh.segment_count - 1;
  int64_t bad_index = 0, bad_class = 0, bad_volume = 0;
  int64_t first_bad_index = -1, first_bad_class = -1, first_bad_volume = -1;
  double first_bad_volume_mm3 = 0.0;
  for (int64_t t = 0; t < mesh.tet_count(); ++t) {
    bool indices_ok = true;
    for (int a = 0; a < 4; ++a) indices_ok = indices_ok && mesh.tets(t, a) >= 0 && mesh.tets(t, a) < vertex_count;
    if (!indices_ok) {
      if (bad_index++ == 0) first_bad_index = t;
      continue;
    }
    const int cls = mesh.tet_class[t];
    if (cls < kSoftTissueClass || cls > last_class) {
      if (bad_class++ == 0) first_bad_class = t;
    }
    const Eigen::Vector3d p0 = mesh.vertices.row(mesh.tets(t, 0)).transpose();
    const Eigen::Vector3d e1 = mesh.vertices.row(mesh.tets(t, 1)).transpose() - p0;
    const Eigen::Vector3d e2 = mesh.vertices.row(mesh.tets(t, 2)).transpose() - p0;
    const Eigen::Vector3d e3 = mesh.vertices.row(mesh.tets(t, 3)).transpose() - p0;
    const double det = e1.dot(e2.cross(e3));
    if (!(det > 0.0) || !std::isfinite(det)) {
      if (bad_volume++ == 0) {
        first_bad_volume = t;
        first_bad_volume_mm3 = det / 6.0;
      }
    }
  }
  if (bad_index > 0) {
    return invalid_argument_error(std::to_string(bad_index) + " tets index a vertex outside [0, " +
                                  std::to_string(vertex_count) + "), the first is tet " +
                                  std::to_string(first_bad_index) + "; the tets and vertices do not belong together");
  }
  if (bad_class > 0) {
    return invalid_argument_error(
        std::to_string(bad_class) + " tets have a class outside [1, " + std::to_string(last_class) +
        "] (1 soft tissue, 2 + k bone segment k < " + std::to_string(mesh.segment_count) + "), the first is tet " +
        std::to_string(first_bad_class) + " with class " + std::to_string(mesh.tet_class[first_bad_class]) +
        "; drop outside tets (class 0) and check segment_count");
  }
  if (bad_volume > 0) {
    return invalid_argument_error(std::to_string(bad_volume) + " tets are inverted or flat, the first is tet " +
                                  std::to_string(first_bad_volume) + " with signed volume " +
                                  std::to_string(first_bad_volume_mm3) +
                                  " mm^3; tets must be positively oriented (det[v1-v0, v2-v0, v3-v0] > 0): "
                                  "swap two corners of inverted tets, or re-mesh to remove flat ones");
  }
  return ok_status();
}

// Union-find over vertices, for the pieces of the mesh that tets connect.
class VertexPieces {
 public:
  explicit VertexPieces(int64_t vertex_count) : parent_(static_cast<size_t>(vertex_count)) {
    std::iota(parent_.begin(), parent_.end(), 0);
  }
  int32_t root(int32_t v) {
    while (parent_[v] != v) {
      parent_[v] = parent_[parent_[v]];
      v = parent_[v];
    }
    return v;
  }
  // The lower root wins, so roots (and everything derived from them) do not depend on the order of unions.
  void join(int32_t a, int32_t b) {
    a = root(a);
    b = root(b);
    if (a == b) return;
    if (a < b) {
      parent_[b] = a;
    } else {
      parent_[a] = b;
    }
  }

 private:
  std::vector<int32_t> parent_;
};

// The harmonic solve before clamping and sparsification.
struct HarmonicSolution {
  int segment_count = 0;
  std::vector<int32_t> owner;       // #V: segment of a bone or island vertex (weight 1 there), -1 for free ones
  std::vector<int32_t> free_index;  // #V: column of free_weights, -1 for bone and island vertices
  Eigen::MatrixXd free_weights;     // segment_count x #free raw weights, one column per free vertex
};

// Bone ownership: the segment with the most incident bone tets, ties to the lowest segment index.
void assign_bone_owners(const TetMesh& mesh, HarmonicSolution* solution, WeightStats* stats) {
  const int64_t vertex_count = mesh.vertex_count();
  std::vector<int32_t>& owner = solution->owner;
  owner.assign(static_cast<size_t>(vertex_count), -1);
  std::vector<uint8_t> contested(static_cast<size_t>(vertex_count), 0);
  for (int64_t t = 0; t < mesh.tet_count(); ++t) {
    const int segment = mesh.tet_class[t] - kFirstBoneClass;
    if (segment < 0) continue;
    for (int a = 0; a < 4; ++a) {
      const int v = mesh.tets(t, a);
      if (owner[v] < 0) {
        owner[v] = segment;
      } else if (owner[v] != segment) {
        contested[v] = 1;
      }
    }
  }
  // Count only around the (few) vertices where segments meet.
  std::vector<std::pair<int32_t, int32_t>> incidences;  // (vertex, segment), one per incident bone tet
  for (int64_t t = 0; t < mesh.tet_count(); ++t) {
    const int segment = mesh.tet_class[t] - kFirstBoneClass;
    if (segment < 0) continue;
    for (int a = 0; a < 4; ++a) {
      if (contested[mesh.tets(t, a)]) incidences.emplace_back(mesh.tets(t, a), segment);
    }
  }
  std::sort(incidences.begin(), incidences.end());
  int64_t multi = 0;
  for (size_t i = 0; i < incidences.size();) {
    const int32_t v = incidences[i].first;
    int32_t best_segment = -1;
    size_t best_count = 0;
    while (i < incidences.size() && incidences[i].first == v) {
      size_t j = i;
      while (j < incidences.size() && incidences[j] == incidences[i]) ++j;
      if (j - i > best_count) {  // strictly more: segments come in increasing order, so ties keep the lowest
        best_count = j - i;
        best_segment = incidences[i].second;
      }
      i = j;
    }
    owner[v] = best_segment;
    ++multi;
  }
  stats->multi_segment_vertices = multi;
}

// Finds the pieces of the mesh without a bone vertex, then attaches them (owner = segment of the nearest bone
// vertex) or fails, as the policy says.
Status handle_islands(const TetMesh& mesh, IslandPolicy policy, HarmonicSolution* solution, WeightStats* stats) {
  const int64_t vertex_count = mesh.vertex_count();
  std::vector<int32_t>& owner = solution->owner;
  VertexPieces pieces(vertex_count);
  std::vector<uint8_t> in_tet(static_cast<size_t>(vertex_count), 0);
  for (int64_t t = 0; t < mesh.tet_count(); ++t) {
    for (int a = 0; a < 4; ++a) in_tet[mesh.tets(t, a)] = 1;
    for (int a = 1; a < 4; ++a) pieces.join(mesh.tets(t, 0), mesh.tets(t, a));
  }
  std::vector<uint8_t> piece_has_bone(static_cast<size_t>(vertex_count), 0);
  std::vector<int32_t> root(static_cast<size_t>(vertex_count));
  for (int32_t v = 0; v < vertex_count; ++v) {
    root[v] = pieces.root(v);
    if (owner[v] >= 0) piece_has_bone[root[v]] = 1;
  }
  // Island vertices grouped by piece (roots ascending, vertices ascending within a piece).
  std::vector<std::pair<int32_t, int32_t>> island;  // (root, vertex)
  for (int32_t v = 0; v < vertex_count; ++v) {
    if (!piece_has_bone[root[v]]) island.emplace_back(root[v], v);
  }
  if (island.empty()) return ok_status();
  std::sort(island.begin(), island.end());
  std::vector<size_t> piece_begin;
  for (size_t i = 0; i < island.size(); ++i) {
    if (i == 0 || island[i].first != island[i - 1].first) piece_begin.push_back(i);
  }
  piece_begin.push_back(island.size());
  const size_t piece_count = piece_begin.size() - 1;

  if (policy == IslandPolicy::kFail) {
    size_t largest = 0;
    for (size_t p = 1; p < piece_count; ++p) {
      if (piece_begin[p + 1] - piece_begin[p] > piece_begin[largest + 1] - piece_begin[largest]) largest = p;
    }
    Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
    for (size_t i = piece_begin[largest]; i < piece_begin[largest + 1]; ++i) {
      centroid += mesh.vertices.row(island[i].second).transpose();
    }
    const size_t largest_size = piece_begin[largest + 1] - piece_begin[largest];
    centroid /= static_cast<double>(largest_size);
    int64_t loose = 0;
    for (const auto& [piece, v] : island) loose += in_tet[v] ? 0 : 1;
    return failed_precondition_error(
        std::to_string(piece_count) + " piece(s) of the tet mesh (" + std::to_string(island.size()) + " vertices, " +
        std::to_string(loose) +
        " of them in no tet) touch no bone, so their weights are "
        "undetermined; the largest has " +
        std::to_string(largest_size) + " vertices around " + format_mm(centroid) +
        ". Remove the detached piece from the label map (often a fragment of skin, a "
        "table or a cable), or set WeightsParams::islands to kAttachNearest to give it the nearest bone's weights");
  }

  std::vector<PointKdTree::Point> bone_points;
  for (int32_t v = 0; v < vertex_count; ++v) {
    if (owner[v] >= 0) bone_points.push_back({mesh.vertices.row(v).transpose(), v});
  }
  const PointKdTree tree(std::move(bone_points));
  for (size_t p = 0; p < piece_count; ++p) {
    PointKdTree::Hit nearest;
    for (size_t i = piece_begin[p]; i < piece_begin[p + 1]; ++i) {
      tree.nearest(mesh.vertices.row(island[i].second).transpose(), &nearest);
    }
    const int32_t segment = owner[nearest.id];
    for (size_t i = piece_begin[p]; i < piece_begin[p + 1]; ++i) owner[island[i].second] = segment;
  }
  stats->islands_attached = static_cast<int>(piece_count);
  stats->island_vertices = static_cast<int64_t>(island.size());
  return ok_status();
}

// Bone owners, then the islands attached or refused: the vertices whose weights are fixed.
Status fix_boundary(const TetMesh& mesh, IslandPolicy islands, HarmonicSolution* solution, WeightStats* stats) {
  assign_bone_owners(mesh, solution, stats);
  int64_t fixed = 0;
  for (const int32_t o : solution->owner) fixed += o >= 0 ? 1 : 0;
  stats->fixed_vertices = fixed;
  if (fixed == 0) {
    return failed_precondition_error(
        "no tet of the mesh is bone (class 2 + k), so the weights have no boundary condition; check that the label "
        "map's bones are assigned to segments and that the mesher kept them (MeshHealth::lost_segments)");
  }
  return handle_islands(mesh, islands, solution, stats);
}

// Numbers the free vertices (those without an owner) and returns them in vertex order, so K_ff keeps K's sorted
// columns and lower triangle.
std::vector<int32_t> number_free_vertices(int64_t vertex_count, HarmonicSolution* solution) {
  solution->free_index.assign(static_cast<size_t>(vertex_count), -1);
  std::vector<int32_t> free_vertices;
  for (int32_t v = 0; v < vertex_count; ++v) {
    if (solution->owner[v] < 0) {
      solution->free_index[v] = static_cast<int32_t>(free_vertices.size());
      free_vertices.push_back(v);
    }
  }
  return free_vertices;
}

// The linear system of the free vertices: the lower triangle of K_ff and one right-hand side per segment.
struct FreeSystem {
  SparseMatrix k_ff;
  Eigen::MatrixXd rhs;  // #free x segment_count
};

// Lower triangle of K_ff, and rhs = -K_fb W_b: W_b is one-hot, so each bone neighbour subtracts its entry from its
// owner's column. K is symmetric, so column v of K is row v.
FreeSystem assemble_free_system(const SparseMatrix& stiffness, const HarmonicSolution& solution,
                                const std::vector<int32_t>& free_vertices) {
  const int64_t free_count = static_cast<int64_t>(free_vertices.size());
  const int* outer = stiffness.outerIndexPtr();
  const int* inner = stiffness.innerIndexPtr();
  const double* values = stiffness.valuePtr();
  const std::vector<int32_t>& owner = solution.owner;
  const std::vector<int32_t>& free_index = solution.free_index;
  std::vector<int> column_size(static_cast<size_t>(free_count), 0);
  parallel_for(0, free_count, 2048, [&](int64_t begin, int64_t end) {
    for (int64_t f = begin; f < end; ++f) {
      const int v = free_vertices[f];
      int size = 0;
      for (int k = outer[v]; k < outer[v + 1]; ++k) size += (inner[k] >= v && free_index[inner[k]] >= 0) ? 1 : 0;
      column_size[f] = size;
    }
  });
  FreeSystem system;
  SparseMatrix& k_ff = system.k_ff;
  k_ff.resize(free_count, free_count);
  int64_t k_ff_nonzeros = 0;
  for (const int size : column_size) k_ff_nonzeros += size;
  k_ff.resizeNonZeros(static_cast<Eigen::Index>(k_ff_nonzeros));
  int* ff_outer = k_ff.outerIndexPtr();
  ff_outer[0] = 0;
  for (int64_t f = 0; f < free_count; ++f) ff_outer[f + 1] = ff_outer[f] + column_size[f];
  std::vector<int>().swap(column_size);
  int* ff_inner = k_ff.innerIndexPtr();
  double* ff_values = k_ff.valuePtr();
  Eigen::MatrixXd& rhs = system.rhs;
  rhs = Eigen::MatrixXd::Zero(free_count, solution.segment_count);
  parallel_for(0, free_count, 2048, [&](int64_t begin, int64_t end) {
    for (int64_t f = begin; f < end; ++f) {
      const int v = free_vertices[f];
      int out = ff_outer[f];
      for (int k = outer[v]; k < outer[v + 1]; ++k) {
        const int u = inner[k];
        if (free_index[u] >= 0) {
          if (u >= v) {
            ff_inner[out] = free_index[u];
            ff_values[out] = values[k];
            ++out;
          }
        } else {
          rhs(f, owner[u]) -= values[k];
        }
      }
    }
  });
  return system;
}

// Solves the free system with CHOLMOD when preferred and it succeeds, else with the simplicial LDL^T; the solver
// used, or CHOLMOD's failure, goes to the stats.
Status solve_free_system(const FreeSystem& system, bool prefer_cholmod, StageProgress& progress, WeightStats* stats,
                         Eigen::MatrixXd* x) {
  if (prefer_cholmod) {
    std::string failure;
    POSEWARP_RETURN_IF_ERROR(
        detail::solve_cholmod(system.k_ff, system.rhs, progress, kFactoredFraction, stats, x, &failure));
    if (x->size() > 0) {
      stats->solver = "cholmod-supernodal-llt";
    } else {
      stats->cholmod_failure = failure;
    }
  }
  if (x->size() == 0) {
    POSEWARP_RETURN_IF_ERROR(detail::solve_simplicial(system.k_ff, system.rhs, progress, kFactoredFraction, stats, x));
    stats->solver = "simplicial-ldlt";
  }
  return ok_status();
}

// Residual of every free row against the full K (free and bone neighbours), and the raw weights' range.
void raw_weight_statistics(const SparseMatrix& stiffness, const HarmonicSolution& solution,
                           const std::vector<int32_t>& free_vertices, WeightStats* stats) {
  const int64_t free_count = static_cast<int64_t>(free_vertices.size());
  const int segment_count = solution.segment_count;
  const int* outer = stiffness.outerIndexPtr();
  const int* inner = stiffness.innerIndexPtr();
  const double* values = stiffness.valuePtr();
  const std::vector<int32_t>& owner = solution.owner;
  const std::vector<int32_t>& free_index = solution.free_index;
  const Eigen::MatrixXd& w = solution.free_weights;
  double row_scale = 0.0;
  for (const int v : free_vertices) {
    double sum = 0.0;
    for (int k = outer[v]; k < outer[v + 1]; ++k) sum += std::abs(values[k]);
    row_scale = std::max(row_scale, sum);
  }
  MaxReduction residual, partition_raw, above_one, below_zero;
  parallel_for(0, free_count, 2048, [&](int64_t begin, int64_t end) {
    Eigen::VectorXd row(segment_count);
    double chunk_residual = 0.0, chunk_partition = 0.0, chunk_max = -std::numeric_limits<double>::infinity();
    double chunk_min = std::numeric_limits<double>::infinity();
    for (int64_t f = begin; f < end; ++f) {
      const int v = free_vertices[f];
      row.setZero();
      for (int k = outer[v]; k < outer[v + 1]; ++k) {
        const int u = inner[k];
        if (free_index[u] >= 0) {
          row += values[k] * w.col(free_index[u]);
        } else {
          row[owner[u]] += values[k];
        }
      }
      chunk_residual = std::max(chunk_residual, row.cwiseAbs().maxCoeff());
      chunk_partition = std::max(chunk_partition, std::abs(w.col(f).sum() - 1.0));
      chunk_max = std::max(chunk_max, w.col(f).maxCoeff());
      chunk_min = std::min(chunk_min, w.col(f).minCoeff());
    }
    residual.report(chunk_residual);
    partition_raw.report(chunk_partition);
    above_one.report(chunk_max);
    below_zero.report(-chunk_min);
  });
  stats->max_laplace_residual = row_scale > 0.0 ? residual.value() / row_scale : residual.value();
  stats->max_partition_error_raw = partition_raw.value();
  // Bone and island vertices hold exact 0 and 1.
  stats->min_raw_weight = std::min(0.0, -below_zero.value());
  stats->max_raw_weight = std::max(1.0, above_one.value());
}

// Everything up to the raw weights, with the residual and raw statistics.
Result<HarmonicSolution> solve_harmonic(const TetMesh& mesh, const WeightsParams& params, StageProgress& progress,
                                        WeightStats* stats) {
  POSEWARP_RETURN_IF_ERROR(validate(params));
  POSEWARP_RETURN_IF_ERROR(check_mesh(mesh));
  POSEWARP_RETURN_IF_ERROR(progress.check_cancel());
  const Stopwatch assemble_start;
  const int64_t vertex_count = mesh.vertex_count();
  const int segment_count = mesh.segment_count;
  stats->segments = segment_count;

  HarmonicSolution solution;
  solution.segment_count = segment_count;
  POSEWARP_RETURN_IF_ERROR(fix_boundary(mesh, params.islands, &solution, stats));
  const std::vector<int32_t> free_vertices = number_free_vertices(vertex_count, &solution);
  const int64_t free_count = static_cast<int64_t>(free_vertices.size());
  stats->free_vertices = free_count;
  if (free_count == 0) {
    stats->solver = "none";
    stats->max_raw_weight = 1.0;
    stats->assemble_seconds = assemble_start.seconds();
    progress.update(kSolvedFraction);
    return solution;
  }

  const SparseMatrix stiffness = fem_laplacian(mesh);
  POSEWARP_RETURN_IF_ERROR(progress.check_cancel());
  FreeSystem system = assemble_free_system(stiffness, solution, free_vertices);
  stats->assemble_seconds = assemble_start.seconds();
  progress.update(kAssembledFraction);
  POSEWARP_RETURN_IF_ERROR(progress.check_cancel());

  Eigen::MatrixXd x;
  POSEWARP_RETURN_IF_ERROR(solve_free_system(system, params.prefer_cholmod, progress, stats, &x));
  SparseMatrix().swap(system.k_ff);
  Eigen::MatrixXd().swap(system.rhs);
  progress.update(kSolvedFraction);
  POSEWARP_RETURN_IF_ERROR(progress.check_cancel());

  const Stopwatch finish_start;
  solution.free_weights = x.transpose();
  Eigen::MatrixXd().swap(x);
  raw_weight_statistics(stiffness, solution, free_vertices, stats);
  stats->finish_seconds = finish_start.seconds();
  return solution;
}

// What the exception wall says the weights were doing, and what to do when memory ran out.
std::string computing_weights(const TetMesh& mesh) {
  return "computing skinning weights for a mesh of " + std::to_string(mesh.vertex_count()) + " vertices and " +
         std::to_string(mesh.segment_count) + " segments";
}
constexpr std::string_view kWeightsAdvice =
    "mesh more coarsely (larger MeshParams cell sizes) or use a machine with more memory";

}  // namespace

Status validate(const WeightsParams& params) {
  if (params.max_influences < 1 || params.max_influences > kMaxInfluences) {
    return invalid_argument_error("WeightsParams::max_influences is " + std::to_string(params.max_influences) +
                                  "; it must be in [1, 8] (default 4)");
  }
  if (!(params.prune_below >= 0.0 && params.prune_below <= kMaxPruneBelow)) {
    return invalid_argument_error("WeightsParams::prune_below is " + std::to_string(params.prune_below) +
                                  "; it must be in [0, 0.01] (default 1e-6)");
  }
  if (params.islands != IslandPolicy::kAttachNearest && params.islands != IslandPolicy::kFail) {
    return invalid_argument_error("WeightsParams::islands is not a known IslandPolicy (default kAttachNearest)");
  }
  return ok_status();
}

Result<SkinWeights> laplace_weights(const TetMesh& mesh, const WeightsParams& params, const ProgressHooks& hooks,
                                    WeightStats* stats) {
  WeightStats local_stats;
  WeightStats* out_stats = stats ? stats : &local_stats;
  *out_stats = WeightStats();
  return guarded(computing_weights(mesh), kWeightsAdvice, [&]() -> Result<SkinWeights> {
    StageProgress progress(hooks, "weights");
    POSEWARP_ASSIGN_OR_RETURN(HarmonicSolution solution, solve_harmonic(mesh, params, progress, out_stats));
    const Stopwatch finish_start;
    const int segment_count = solution.segment_count;
    const int influences = std::min(params.max_influences, segment_count);
    const int64_t vertex_count = mesh.vertex_count();

    SkinWeights result;
    result.influences = influences;
    result.segment_count = segment_count;
    result.segment.setConstant(vertex_count, influences, -1);
    result.weight.setZero(vertex_count, influences);
    MaxReduction partition, partition_float;
    parallel_for(0, vertex_count, 2048, [&](int64_t begin, int64_t end) {
      std::vector<std::pair<double, int>> kept;  // (weight, segment)
      kept.reserve(static_cast<size_t>(segment_count));
      double chunk_partition = 0.0, chunk_partition_float = 0.0;
      for (int64_t v = begin; v < end; ++v) {
        kept.clear();
        const int32_t f = solution.free_index[v];
        if (f < 0) {
          kept.emplace_back(1.0, solution.owner[v]);
        } else {
          const auto raw = solution.free_weights.col(f);
          double sum = 0.0;
          for (int k = 0; k < segment_count; ++k) sum += std::clamp(raw[k], 0.0, 1.0);
          if (!(sum > 0.0)) {
            // Every raw weight clamped to 0: cannot happen for a solution that sums to 1, but keep a valid row.
            Eigen::Index largest = 0;
            raw.maxCoeff(&largest);
            kept.emplace_back(1.0, static_cast<int>(largest));
          } else {
            for (int k = 0; k < segment_count; ++k) {
              const double wk = std::clamp(raw[k], 0.0, 1.0) / sum;
              if (wk > 0.0 && wk >= params.prune_below) kept.emplace_back(wk, k);
            }
            if (kept.empty()) {  // many segments sharing a vertex evenly, all below prune_below
              Eigen::Index largest = 0;
              raw.maxCoeff(&largest);
              kept.emplace_back(1.0, static_cast<int>(largest));
            }
          }
        }
        const size_t count = std::min(kept.size(), static_cast<size_t>(influences));
        // Largest first; equal weights in segment order.
        std::partial_sort(kept.begin(), kept.begin() + static_cast<std::ptrdiff_t>(count), kept.end(),
                          [](const auto& a, const auto& b) {
                            return a.first > b.first || (a.first == b.first && a.second < b.second);
                          });
        double kept_sum = 0.0;
        for (size_t i = 0; i < count; ++i) kept_sum += kept[i].first;
        double sum_double = 0.0, sum_float = 0.0;
        for (size_t i = 0; i < count; ++i) {
          const double wi = kept[i].first / kept_sum;
          const float stored = static_cast<float>(wi);
          result.segment(v, static_cast<Eigen::Index>(i)) = kept[i].second;
          result.weight(v, static_cast<Eigen::Index>(i)) = stored;
          sum_double += wi;
          sum_float += static_cast<double>(stored);
        }
        chunk_partition = std::max(chunk_partition, std::abs(sum_double - 1.0));
        chunk_partition_float = std::max(chunk_partition_float, std::abs(sum_float - 1.0));
      }
      partition.report(chunk_partition);
      partition_float.report(chunk_partition_float);
    });
    out_stats->max_partition_error = partition.value();
    out_stats->max_partition_error_float = partition_float.value();
    out_stats->finish_seconds += finish_start.seconds();
    progress.finish();
    return result;
  });
}

Result<Eigen::MatrixXd> laplace_weights_dense(const TetMesh& mesh, const WeightsParams& params,
                                              const ProgressHooks& hooks, WeightStats* stats) {
  WeightStats local_stats;
  WeightStats* out_stats = stats ? stats : &local_stats;
  *out_stats = WeightStats();
  return guarded(computing_weights(mesh), kWeightsAdvice, [&]() -> Result<Eigen::MatrixXd> {
    StageProgress progress(hooks, "weights");
    POSEWARP_ASSIGN_OR_RETURN(HarmonicSolution solution, solve_harmonic(mesh, params, progress, out_stats));
    const int64_t vertex_count = mesh.vertex_count();
    Eigen::MatrixXd dense = Eigen::MatrixXd::Zero(vertex_count, solution.segment_count);
    for (int64_t v = 0; v < vertex_count; ++v) {
      const int32_t f = solution.free_index[v];
      if (f < 0) {
        dense(v, solution.owner[v]) = 1.0;
      } else {
        dense.row(v) = solution.free_weights.col(f).transpose();
      }
    }
    progress.finish();
    return dense;
  });
}

}  // namespace posewarp::weights
