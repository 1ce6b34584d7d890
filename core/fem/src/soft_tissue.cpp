// Projective co-rotational steady state of the soft tissue (see soft_tissue.h).
#include "posewarp/fem/soft_tissue.h"

#include <Eigen/CholmodSupport>
#include <Eigen/Dense>
#include <Eigen/Sparse>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <functional>
#include <limits>
#include <memory>
#include <mutex>
#include <optional>
#include <queue>
#include <string>
#include <tuple>
#include <unordered_map>
#include <utility>

#include "posewarp/common/parallel.h"
#include "posewarp/common/stopwatch.h"
#include "internal.h"

namespace posewarp::fem {
namespace internal {

// Vertex c's gradient row in tet t: F = sum_c x_c g_c^T with g_1..3 the rows of the rest edge matrix's inverse and
// g_0 = -(g_1 + g_2 + g_3).
Eigen::Vector3d gradient(const skinning::RestTetFrames& frames, int64_t t, int c) {
  const auto& m = frames.rest_inverse;
  if (c > 0) return {m(t, 3 * (c - 1)), m(t, 3 * (c - 1) + 1), m(t, 3 * (c - 1) + 2)};
  return -Eigen::Vector3d(m(t, 0) + m(t, 3) + m(t, 6), m(t, 1) + m(t, 4) + m(t, 7), m(t, 2) + m(t, 5) + m(t, 8));
}

// F = U diag(sigma) V^T with U and V rotations (det +1) and sigma descending but for its last entry, which is
// negative when F is inverted (the signed SVD of McAdams et al. 2011), from the eigen-decomposition of F^T F in
// closed form (a few times faster than an iterative SVD on 3 x 3).
void signed_svd(const Eigen::Matrix3d& f, Eigen::Matrix3d& u, Eigen::Vector3d& sigma, Eigen::Matrix3d& v) {
  Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen;
  eigen.computeDirect(f.transpose() * f);
  for (int i = 0; i < 3; ++i) {  // descending
    v.col(i) = eigen.eigenvectors().col(2 - i);
    sigma(i) = std::sqrt(std::max(0.0, eigen.eigenvalues()(2 - i)));
  }
  if (v.determinant() < 0.0) v.col(2) = -v.col(2);
  const double tiny = 1e-12 * std::max(1.0, sigma(0));
  u.col(0) = sigma(0) > tiny ? Eigen::Vector3d(f * v.col(0) / sigma(0)) : Eigen::Vector3d::UnitX();
  Eigen::Vector3d second = f * v.col(1);
  second -= second.dot(u.col(0)) * u.col(0);
  if (second.norm() > tiny) {
    u.col(1) = second.normalized();
  } else {  // any direction perpendicular to the first
    const Eigen::Vector3d other = std::abs(u(0, 0)) < 0.9 ? Eigen::Vector3d::UnitX() : Eigen::Vector3d::UnitY();
    u.col(1) = u.col(0).cross(other).normalized();
  }
  u.col(2) = u.col(0).cross(u.col(1));
  sigma(1) = u.col(1).dot(f * v.col(1));
  sigma(2) = u.col(2).dot(f * v.col(2));
}

}  // namespace internal

namespace {

using internal::gradient;
using internal::signed_svd;

using SparseMatrix = Eigen::SparseMatrix<double>;

// Builds a compressed row list of `count` rows from (row, value) pairs.
void compress(int64_t count, const std::vector<std::pair<int32_t, int32_t>>& pairs, std::vector<int64_t>& start,
              std::vector<int32_t>& values) {
  start.assign(static_cast<size_t>(count) + 1, 0);
  for (const auto& [row, value] : pairs) ++start[static_cast<size_t>(row) + 1];
  for (size_t i = 1; i < start.size(); ++i) start[i] += start[i - 1];
  values.resize(pairs.size());
  std::vector<int64_t> at(start.begin(), start.end() - 1);
  for (const auto& [row, value] : pairs) values[static_cast<size_t>(at[static_cast<size_t>(row)]++)] = value;
}

// The nearest rotation R and nearest volume-preserving matrix S of F, blended: (R + w S) / (1 + w), with the tet's
// energy per unit volume, (|F - R|^2 + w |F - S|^2) / (1 + w). S keeps F's singular directions and moves its singular
// values the least distance to a product of 1 (Bouaziz et al. 2014, appendix); an inverted F (det <= 0) gets R for
// both, which turns it back.
struct Projection {
  Eigen::Matrix3d target;
  double energy = 0.0;
};

Projection projection(const Eigen::Matrix3d& f, double volume_weight) {
  Eigen::Matrix3d u, v;
  Eigen::Vector3d sigma;
  signed_svd(f, u, sigma, v);
  // With F = U diag(sigma) V^T: R = U V^T, S = U diag(sigma + d) V^T, so |F - R|^2 = |sigma - 1|^2, |F - S|^2 = |d|^2
  // and the blend is U diag(1 + w (sigma + d)) V^T / (1 + w).
  if (sigma(2) <= 0.0) return {u * v.transpose(), (sigma.array() - 1.0).square().sum()};
  Eigen::Vector3d d = Eigen::Vector3d::Zero();
  for (int i = 0; i < 8; ++i) {
    const Eigen::Vector3d s = sigma + d;
    const double c = s(0) * s(1) * s(2) - 1.0;
    const Eigen::Vector3d grad(s(1) * s(2), s(0) * s(2), s(0) * s(1));
    const double norm = grad.squaredNorm();
    if (norm < 1e-20) break;
    d = (grad.dot(d) - c) / norm * grad;
    if (std::abs(c) < 1e-10) break;
  }
  const Eigen::Vector3d blend = (Eigen::Vector3d::Ones() + volume_weight * (sigma + d)) / (1.0 + volume_weight);
  return {u * blend.asDiagonal() * v.transpose(),
          ((sigma.array() - 1.0).square().sum() + volume_weight * d.squaredNorm()) / (1.0 + volume_weight)};
}

}  // namespace

namespace internal {

Status validate_iterations(int max_iterations, double tolerance_mm, double margin_mm) {
  if (max_iterations < 1 || max_iterations > 10000) {
    return invalid_argument_error("fem max_iterations must be in [1, 10000], got " + std::to_string(max_iterations));
  }
  if (!(tolerance_mm > 0.0 && tolerance_mm <= 100.0)) {
    return invalid_argument_error("fem tolerance_mm must be in (0, 100], got " + std::to_string(tolerance_mm));
  }
  if (!(margin_mm >= 0.0 && margin_mm <= 1000.0)) {
    return invalid_argument_error("fem margin_mm must be in [0, 1000], got " + std::to_string(margin_mm));
  }
  return ok_status();
}

}  // namespace internal

Status validate(const FemParams& params) {
  if (!(params.volume_weight >= 0.0 && params.volume_weight <= 1e6)) {
    return invalid_argument_error("fem volume_weight must be in [0, 1e6], got " + std::to_string(params.volume_weight));
  }
  if (!(params.time_budget_seconds >= 0.0 && params.time_budget_seconds <= 3600.0)) {
    return invalid_argument_error("fem time_budget_seconds must be in [0, 3600], got " +
                                  std::to_string(params.time_budget_seconds));
  }
  if (!(params.untangle_volume_weight >= 0.0 && params.untangle_volume_weight <= 1e6)) {
    return invalid_argument_error("fem untangle_volume_weight must be in [0, 1e6], got " +
                                  std::to_string(params.untangle_volume_weight));
  }
  return internal::validate_iterations(params.max_iterations, params.tolerance_mm, params.margin_mm);
}

Topology topology(const TetMesh& rest, std::vector<uint8_t> skin) {
  Topology topo;
  const int64_t n = rest.vertex_count();
  std::vector<std::pair<int32_t, int32_t>> vertex_tet;
  vertex_tet.reserve(static_cast<size_t>(rest.tet_count()) * 4);
  topo.bone.assign(static_cast<size_t>(n), 0);
  for (int64_t t = 0; t < rest.tet_count(); ++t) {
    const bool bone = rest.tet_class.size() == rest.tet_count() && rest.tet_class(t) >= kFirstBoneClass;
    for (int a = 0; a < 4; ++a) {
      const int32_t v = rest.tets(t, a);
      vertex_tet.emplace_back(v, static_cast<int32_t>(t));
      if (bone) topo.bone[static_cast<size_t>(v)] = 1;
    }
  }
  compress(n, vertex_tet, topo.tet_start, topo.tets);
  // Each vertex's neighbours: the other corners of its tets, sorted and unique per vertex.
  std::vector<std::vector<int32_t>> neighbours(static_cast<size_t>(n));
  parallel_for(0, n, 4096, [&](int64_t v0, int64_t v1) {
    for (int64_t v = v0; v < v1; ++v) {
      std::vector<int32_t>& list = neighbours[static_cast<size_t>(v)];
      for (int64_t e = topo.tet_start[static_cast<size_t>(v)]; e < topo.tet_start[static_cast<size_t>(v) + 1]; ++e) {
        for (int c = 0; c < 4; ++c) {
          const int32_t w = rest.tets(topo.tets[static_cast<size_t>(e)], c);
          if (w != v) list.push_back(w);
        }
      }
      std::sort(list.begin(), list.end());
      list.erase(std::unique(list.begin(), list.end()), list.end());
    }
  });
  topo.edge_start.assign(static_cast<size_t>(n) + 1, 0);
  for (int64_t v = 0; v < n; ++v) {
    topo.edge_start[static_cast<size_t>(v) + 1] =
        topo.edge_start[static_cast<size_t>(v)] + static_cast<int64_t>(neighbours[static_cast<size_t>(v)].size());
  }
  topo.edges.reserve(static_cast<size_t>(topo.edge_start.back()));
  for (const std::vector<int32_t>& list : neighbours) topo.edges.insert(topo.edges.end(), list.begin(), list.end());
  // The skin's faces: a tet face whose corners are all skin and that no other tet shares, turned to face out.
  topo.skin = static_cast<int64_t>(skin.size()) == n ? std::move(skin) : skin_vertices(rest);
  for (int64_t t = 0; t < rest.tet_count(); ++t) {
    for (int opposite = 0; opposite < 4; ++opposite) {
      std::array<int32_t, 3> face{};
      for (int c = 0, k = 0; c < 4; ++c) {
        if (c != opposite) face[static_cast<size_t>(k++)] = rest.tets(t, c);
      }
      if (!topo.skin[static_cast<size_t>(face[0])] || !topo.skin[static_cast<size_t>(face[1])] ||
          !topo.skin[static_cast<size_t>(face[2])]) {
        continue;
      }
      bool shared = false;
      for (int64_t e = topo.tet_start[static_cast<size_t>(face[0])];
           e < topo.tet_start[static_cast<size_t>(face[0]) + 1] && !shared; ++e) {
        const int32_t u = topo.tets[static_cast<size_t>(e)];
        if (u == t) continue;
        int common = 0;
        for (int c = 0; c < 4; ++c) common += rest.tets(u, c) == face[1] || rest.tets(u, c) == face[2];
        shared = common == 2;
      }
      if (shared) continue;
      const Eigen::Vector3d a = rest.vertices.row(face[0]).transpose();
      const Eigen::Vector3d out = a - rest.vertices.row(rest.tets(t, opposite)).transpose();
      const Eigen::Vector3d ab = rest.vertices.row(face[1]).transpose() - a;
      const Eigen::Vector3d ac = rest.vertices.row(face[2]).transpose() - a;
      if (ab.cross(ac).dot(out) < 0.0) {
        std::swap(face[1], face[2]);
      }
      topo.skin_faces.push_back(face);
    }
  }
  return topo;
}

// The solve's system for one set of free vertices: the tets touching them packed with their corners (solve vertex
// numbers: the free ones first, in free order, then the fixed corners), gradient rows and rest volumes; each free
// vertex's (tet, corner) pairs; and the matrix L_ff (the tet Laplacian weighted by rest volume) factored.
struct SolveSystem {
  std::vector<int32_t> free_vertices;                  // solve vertex i < nf -> mesh vertex
  std::vector<int32_t> solve_vertices;                 // every solve vertex -> mesh vertex (free ones first)
  std::vector<int32_t> solve_tets;                     // slot -> tet
  std::vector<std::array<int32_t, 4>> slot_corners;    // slot -> its corners' solve vertices
  std::vector<Eigen::Matrix<double, 3, 4>> gradients;  // slot -> its corners' gradient rows
  std::vector<double> slot_volume;                     // slot -> rest volume
  std::vector<int64_t> corner_start;                   // nf + 1: free vertex i's pairs are corners[corner_start[i] ..)
  std::vector<std::pair<int32_t, int32_t>> corners;    // (slot, corner)
  std::vector<std::tuple<int32_t, int32_t, double>> coupling;  // (free i, fixed solve vertex j, L_ij)
  double pull = 0.0;                                   // the faint pull toward the warm start on the diagonal
  std::vector<int32_t> contact;                        // the free skin vertices (solve numbers)
  std::vector<double> contact_stiffness;               // their tets' stiffness (L_ii), for the untangling's planes
  std::vector<int32_t> bone_segment;                   // solve vertex -> its bone's segment, -1 off bone
  Eigen::CholmodSupernodalLLT<SparseMatrix, Eigen::Lower> llt;
  // Where the last solve on this system started (the warm start) and ended, free vertices only.
  Eigen::MatrixXd last_warm, last_solution;
};

SolveCache::SolveCache() = default;
SolveCache::~SolveCache() = default;

std::unique_ptr<SolveSystem> SolveCache::take(const std::vector<int32_t>& free_vertices) {
  const std::lock_guard<std::mutex> lock(mutex_);
  if (system_ && system_->free_vertices == free_vertices) return std::move(system_);
  return nullptr;
}

void SolveCache::put(std::unique_ptr<SolveSystem> system) {
  const std::lock_guard<std::mutex> lock(mutex_);
  system_ = std::move(system);
}

namespace {

Result<std::unique_ptr<SolveSystem>> prepare(const SolveInputs& in, std::vector<int32_t> free_vertices) {
  const TetMesh& mesh = in.rest;
  auto system = std::make_unique<SolveSystem>();
  SolveSystem& sys = *system;
  const auto nf = static_cast<Eigen::Index>(free_vertices.size());
  std::vector<int32_t> local(static_cast<size_t>(mesh.vertex_count()), -1);  // mesh vertex -> solve vertex
  for (Eigen::Index i = 0; i < nf; ++i) local[static_cast<size_t>(free_vertices[static_cast<size_t>(i)])] = static_cast<int32_t>(i);
  sys.solve_vertices = free_vertices;
  sys.free_vertices = std::move(free_vertices);
  // The tets touching a free vertex.
  std::vector<int32_t> solve_slot(static_cast<size_t>(mesh.tet_count()), -1);  // tet -> slot, -1 outside the solve
  for (const int32_t v : sys.free_vertices) {
    for (int64_t e = in.topology.tet_start[static_cast<size_t>(v)]; e < in.topology.tet_start[static_cast<size_t>(v) + 1]; ++e) {
      const int32_t t = in.topology.tets[static_cast<size_t>(e)];
      if (solve_slot[static_cast<size_t>(t)] < 0) {
        solve_slot[static_cast<size_t>(t)] = static_cast<int32_t>(sys.solve_tets.size());
        sys.solve_tets.push_back(t);
      }
    }
  }
  const size_t slots = sys.solve_tets.size();
  sys.gradients.resize(slots);
  sys.slot_corners.resize(slots);
  sys.slot_volume.resize(slots);
  for (size_t s = 0; s < slots; ++s) {
    const int32_t t = sys.solve_tets[s];
    for (int c = 0; c < 4; ++c) {
      sys.gradients[s].col(c) = gradient(in.frames, t, c);
      const int32_t v = mesh.tets(t, c);
      if (local[static_cast<size_t>(v)] < 0) {
        local[static_cast<size_t>(v)] = static_cast<int32_t>(sys.solve_vertices.size());
        sys.solve_vertices.push_back(v);
      }
      sys.slot_corners[s][static_cast<size_t>(c)] = local[static_cast<size_t>(v)];
    }
    sys.slot_volume[s] = in.frames.rest_volume(t);
  }
  sys.corner_start.assign(static_cast<size_t>(nf) + 1, 0);
  for (Eigen::Index i = 0; i < nf; ++i) {
    const int32_t v = sys.free_vertices[static_cast<size_t>(i)];
    for (int64_t e = in.topology.tet_start[static_cast<size_t>(v)]; e < in.topology.tet_start[static_cast<size_t>(v) + 1]; ++e) {
      const int32_t t = in.topology.tets[static_cast<size_t>(e)];
      int c = 0;
      while (mesh.tets(t, c) != v) ++c;
      sys.corners.emplace_back(solve_slot[static_cast<size_t>(t)], c);
    }
    sys.corner_start[static_cast<size_t>(i) + 1] = static_cast<int64_t>(sys.corners.size());
  }
  // L_ff, and L_fc for the right-hand side's constant part.
  std::vector<Eigen::Triplet<double>> triplets;
  triplets.reserve(slots * 16 + static_cast<size_t>(nf));
  double diagonal = 0.0;
  Eigen::VectorXd own(nf);  // L_ii
  own.setZero();
  for (size_t s = 0; s < slots; ++s) {
    const auto& corner = sys.slot_corners[s];
    for (int a = 0; a < 4; ++a) {
      const int32_t ia = corner[static_cast<size_t>(a)];
      if (ia >= nf) continue;
      for (int b = 0; b < 4; ++b) {
        const int32_t ib = corner[static_cast<size_t>(b)];
        const double l = sys.slot_volume[s] * sys.gradients[s].col(a).dot(sys.gradients[s].col(b));
        if (ib < nf) {
          triplets.emplace_back(ia, ib, l);
          if (ia == ib) {
            diagonal += l;
            own(ia) += l;
          }
        } else {
          sys.coupling.emplace_back(ia, ib, l);
        }
      }
    }
  }
  // A faint pull towards the warm start keeps the system definite where a free piece touches nothing fixed.
  sys.pull = 1e-9 * diagonal / static_cast<double>(nf);
  for (Eigen::Index i = 0; i < nf; ++i) triplets.emplace_back(i, i, sys.pull);
  // The free skin vertices, which contacts may push (Contacts), with their stiffness.
  for (Eigen::Index i = 0; i < nf && !in.topology.skin.empty(); ++i) {
    if (!in.topology.skin[static_cast<size_t>(sys.free_vertices[static_cast<size_t>(i)])]) continue;
    sys.contact.push_back(static_cast<int32_t>(i));
    sys.contact_stiffness.push_back(own(i));
  }
  // Which bone each fixed corner belongs to, for the untangling to tell a joint's gap (the free are never bone).
  sys.bone_segment = internal::bone_segments(in, sys.solve_vertices, static_cast<size_t>(nf));
  SparseMatrix matrix(nf, nf);
  matrix.setFromTriplets(triplets.begin(), triplets.end());
  sys.llt.compute(matrix);
  if (sys.llt.info() != Eigen::Success) {
    return internal_error("the soft-tissue system (" + std::to_string(nf) + " vertices) could not be factored");
  }
  return system;
}

// The solve's system for these free vertices: the cached one when the last solve had the same ones, else prepared.
Result<std::unique_ptr<SolveSystem>> take_or_prepare(const SolveInputs& in, std::vector<int32_t> free_vertices,
                                                     FemStats& st) {
  std::unique_ptr<SolveSystem> system = in.cache ? in.cache->take(free_vertices) : nullptr;
  if (!system) {
    POSEWARP_ASSIGN_OR_RETURN(system, prepare(in, std::move(free_vertices)));
  } else {
    st.reused_system = true;
  }
  return system;
}

// The right-hand side's constant part, -L_fc x_c + the warm-start pull, from this pose's fixed positions.
Eigen::MatrixXd constant_rhs(const SolveSystem& sys, const Eigen::MatrixXd& warm) {
  const auto nf = static_cast<Eigen::Index>(sys.free_vertices.size());
  Eigen::MatrixXd constant(nf, 3);
  for (Eigen::Index i = 0; i < nf; ++i) {
    constant.row(i) = sys.pull * warm.row(sys.free_vertices[static_cast<size_t>(i)]);
  }
  for (const auto& [i, j, l] : sys.coupling) {
    constant.row(i) -= l * warm.row(sys.solve_vertices[static_cast<size_t>(j)]);
  }
  return constant;
}

using internal::Positions;

// Where the iteration starts: the warm start; a preview goes on from where the last solve on these free vertices
// ended, its correction of the warm start carried to this pose's warm start.
Positions start_positions(const SolveSystem& sys, const SolveInputs& in, const FemParams& params, FemStats& st) {
  const auto nf = static_cast<Eigen::Index>(sys.free_vertices.size());
  Positions x_solve(static_cast<Eigen::Index>(sys.solve_vertices.size()), 3);
  for (size_t i = 0; i < sys.solve_vertices.size(); ++i) {
    x_solve.row(static_cast<Eigen::Index>(i)) = in.warm.row(sys.solve_vertices[i]);
  }
  if (params.continue_from_last && sys.last_solution.rows() == nf) {
    x_solve.topRows(nf) += sys.last_solution - sys.last_warm;
    st.continued = true;
  }
  return x_solve;
}

// The local step's result per solved tet: its target V (R + w S) / (1 + w) and its energy.
struct LocalTargets {
  explicit LocalTargets(size_t slots) : target(slots), energy(slots) {}
  std::vector<Eigen::Matrix3d> target;
  std::vector<double> energy;
};

// The local step at the current positions: each tet's target; returns the total energy.
double local_step(const SolveSystem& sys, const Positions& x_solve, double volume_weight, LocalTargets& local) {
  parallel_for(0, static_cast<int64_t>(sys.solve_tets.size()), 2048, [&](int64_t s0, int64_t s1) {
    for (int64_t s = s0; s < s1; ++s) {
      const std::array<int32_t, 4>& corner = sys.slot_corners[static_cast<size_t>(s)];
      Eigen::Matrix<double, 3, 4> x;
      for (int c = 0; c < 4; ++c) x.col(c) = x_solve.row(corner[static_cast<size_t>(c)]).transpose();
      const Eigen::Matrix3d f = x * sys.gradients[static_cast<size_t>(s)].transpose();
      const Projection p = projection(f, volume_weight);
      local.target[static_cast<size_t>(s)] = sys.slot_volume[static_cast<size_t>(s)] * p.target;
      local.energy[static_cast<size_t>(s)] = sys.slot_volume[static_cast<size_t>(s)] * p.energy;
    }
  });
  double total = 0.0;
  for (const double e : local.energy) total += e;
  return total;
}

// The global step's right-hand side: the constant part plus, per free vertex, its tets' targets times its gradient
// rows.
void global_rhs(const SolveSystem& sys, const Eigen::MatrixXd& constant, const LocalTargets& local,
                Eigen::MatrixXd& rhs) {
  const auto nf = static_cast<Eigen::Index>(sys.free_vertices.size());
  parallel_for(0, nf, 2048, [&](int64_t i0, int64_t i1) {
    for (int64_t i = i0; i < i1; ++i) {
      Eigen::Vector3d b = constant.row(i).transpose();
      const int64_t corners_end = sys.corner_start[static_cast<size_t>(i) + 1];
      for (int64_t c0 = sys.corner_start[static_cast<size_t>(i)]; c0 < corners_end; ++c0) {
        const auto [slot, c] = sys.corners[static_cast<size_t>(c0)];
        b += local.target[static_cast<size_t>(slot)] * sys.gradients[static_cast<size_t>(slot)].col(c);
      }
      rhs.row(i) = b.transpose();
    }
  });
}

// Anderson acceleration of the local/global fixed point (Peng et al. 2018): the next positions combine the last
// few global steps so that their residuals cancel; a combination that raises the energy is dropped for the plain
// step, and the history starts again. On the bar it converges in a fifth of the iterations.
struct AndersonHistory {
  static constexpr int kHistory = 5;
  std::vector<Eigen::MatrixXd> residual_changes, step_changes;
  Eigen::MatrixXd last_residual, last_step_result, plain;
  bool accelerated = false;
  double last_energy = std::numeric_limits<double>::infinity();

  // Forgets the history, after a combination that raised the energy.
  void restart() {
    residual_changes.clear();
    step_changes.clear();
    last_residual.resize(0, 0);
  }

  // Adds the changes since the last global step (keeping the newest kHistory) and remembers this one.
  void record(const Eigen::MatrixXd& global, const Eigen::MatrixXd& residual) {
    if (last_residual.size() > 0) {
      residual_changes.push_back(residual - last_residual);
      step_changes.push_back(global - last_step_result);
      if (static_cast<int>(residual_changes.size()) > kHistory) {
        residual_changes.erase(residual_changes.begin());
        step_changes.erase(step_changes.begin());
      }
    }
    last_residual = residual;
    last_step_result = global;
    plain = global;
  }

  // The combination of the recorded steps whose residuals cancel best (least squares, faintly regularized).
  void combine(const Eigen::MatrixXd& global, const Eigen::MatrixXd& residual, Eigen::MatrixXd& current) const {
    const auto m = static_cast<Eigen::Index>(residual_changes.size());
    Eigen::MatrixXd normal(m, m);
    Eigen::VectorXd right(m);
    for (Eigen::Index a = 0; a < m; ++a) {
      right(a) = (residual_changes[static_cast<size_t>(a)].array() * residual.array()).sum();
      for (Eigen::Index b = 0; b <= a; ++b) {
        normal(a, b) = normal(b, a) =
            (residual_changes[static_cast<size_t>(a)].array() * residual_changes[static_cast<size_t>(b)].array()).sum();
      }
    }
    normal.diagonal().array() += 1e-10 * (1.0 + normal.diagonal().maxCoeff());
    const Eigen::VectorXd theta = normal.ldlt().solve(right);
    current = global;
    for (Eigen::Index a = 0; a < m; ++a) current -= theta(a) * step_changes[static_cast<size_t>(a)];
  }
};

// Writes the free vertices' solution into the posed mesh and remembers it, with its warm start, for a preview.
void keep_solution(const SolveInputs& in, const Positions& x_solve, SolveSystem& sys, Eigen::MatrixXd& posed) {
  const auto nf = static_cast<Eigen::Index>(sys.free_vertices.size());
  for (Eigen::Index i = 0; i < nf; ++i) posed.row(sys.free_vertices[static_cast<size_t>(i)]) = x_solve.row(i);
  sys.last_solution = x_solve.topRows(nf);
  sys.last_warm.resize(nf, 3);
  for (Eigen::Index i = 0; i < nf; ++i) sys.last_warm.row(i) = in.warm.row(sys.free_vertices[static_cast<size_t>(i)]);
}

}  // namespace

namespace internal {

Status check_inputs(const SolveInputs& in) {
  const TetMesh& mesh = in.rest;
  const int64_t n = mesh.vertex_count();
  if (in.warm.rows() != n || in.warm.cols() != 3 || in.weights.vertex_count() != n ||
      static_cast<int64_t>(in.topology.bone.size()) != n || in.frames.rest_inverse.rows() != mesh.tet_count() ||
      static_cast<int>(in.transforms.size()) < in.weights.segment_count) {
    return invalid_argument_error("the soft-tissue solve's inputs do not fit the mesh (" + std::to_string(n) +
                                  " vertices); rebuild the rig");
  }
  if (!in.topology.skin.empty() && static_cast<int64_t>(in.topology.skin.size()) != n) {
    return invalid_argument_error("the soft-tissue solve's topology does not fit the mesh; rebuild the rig");
  }
  return ok_status();
}

std::vector<int32_t> bone_segments(const SolveInputs& in, const std::vector<int32_t>& solve_vertices,
                                   size_t free_count) {
  std::vector<int32_t> segment(solve_vertices.size(), -1);
  for (size_t j = free_count; j < solve_vertices.size(); ++j) {
    const int32_t v = solve_vertices[j];
    if (in.topology.bone[static_cast<size_t>(v)]) segment[j] = in.weights.segment(v, 0);
  }
  return segment;
}

void record(const UntangleStats& untangled, FemStats& st) {
  st.inverted_before_untangle = untangled.inverted_before;
  st.inverted = untangled.inverted_after;
  st.untangle_undone = untangled.undone;
  st.untangle_vertices = untangled.vertices;
  st.untangle_iterations = untangled.iterations;
  st.untangle_seconds = untangled.seconds;
}

std::vector<int32_t> free_vertices(const SolveInputs& in, double margin_mm) {
  const TetMesh& mesh = in.rest;
  const int64_t n = mesh.vertex_count();
  // 1. The tissue the pose bends: vertices whose influences move them to different places.
  std::vector<double> distance(static_cast<size_t>(n), std::numeric_limits<double>::infinity());
  using Entry = std::pair<double, int32_t>;
  std::priority_queue<Entry, std::vector<Entry>, std::greater<>> queue;
  for (int64_t v = 0; v < n; ++v) {
    const Eigen::Vector3d x = mesh.vertices.row(v).transpose();
    const int32_t first = in.weights.segment(v, 0);
    if (first < 0) continue;
    const Eigen::Vector3d moved = in.transforms.rotation[static_cast<size_t>(first)] * x +
                                  in.transforms.translation[static_cast<size_t>(first)];
    double spread = 0.0;
    for (int k = 1; k < in.weights.influences; ++k) {
      const int32_t s = in.weights.segment(v, k);
      if (s < 0 || in.weights.weight(v, k) <= 0.0f) continue;
      spread = std::max(spread, (in.transforms.rotation[static_cast<size_t>(s)] * x +
                                 in.transforms.translation[static_cast<size_t>(s)] - moved).norm());
    }
    if (spread > 1e-3) {
      distance[static_cast<size_t>(v)] = 0.0;
      queue.emplace(0.0, static_cast<int32_t>(v));
    }
  }
  // ... and the tissue within the margin of it, along mesh edges.
  while (!queue.empty()) {
    const auto [d, v] = queue.top();
    queue.pop();
    if (d > distance[static_cast<size_t>(v)]) continue;
    for (int64_t e = in.topology.edge_start[static_cast<size_t>(v)]; e < in.topology.edge_start[static_cast<size_t>(v) + 1]; ++e) {
      const int32_t w = in.topology.edges[static_cast<size_t>(e)];
      const double dw = d + (mesh.vertices.row(w) - mesh.vertices.row(v)).norm();
      if (dw <= margin_mm && dw < distance[static_cast<size_t>(w)]) {
        distance[static_cast<size_t>(w)] = dw;
        queue.emplace(dw, w);
      }
    }
  }
  std::vector<int32_t> free_vertices;
  for (int64_t v = 0; v < n; ++v) {
    if (std::isfinite(distance[static_cast<size_t>(v)]) && !in.topology.bone[static_cast<size_t>(v)]) {
      free_vertices.push_back(static_cast<int32_t>(v));
    }
  }
  return free_vertices;
}

}  // namespace internal

namespace {

// The projective steady state of the free vertices (run_solve has checked the inputs and found them).
Result<Eigen::MatrixXd> projective_steady_state(const SolveInputs& in, const FemParams& params,
                                                std::vector<int32_t> free_vertices, StageProgress& progress,
                                                FemStats& st, const Stopwatch& start) {
  Eigen::MatrixXd posed = in.warm;
  const auto nf = static_cast<Eigen::Index>(free_vertices.size());

  // 2. The solve's system for these free vertices: from the cache when the last solve had the same ones.
  POSEWARP_ASSIGN_OR_RETURN(std::unique_ptr<SolveSystem> system, take_or_prepare(in, std::move(free_vertices), st));
  SolveSystem& sys = *system;
  st.tets = static_cast<int64_t>(sys.solve_tets.size());
  st.fixed_vertices = static_cast<int64_t>(sys.solve_vertices.size()) - nf;
  const Eigen::MatrixXd constant = constant_rhs(sys, in.warm);
  st.factor_seconds = start.seconds();
  POSEWARP_RETURN_IF_ERROR(progress.check_cancel());

  // 3. Local and global steps until no vertex moves more than the tolerance, on the solve's packed vertices.
  const Stopwatch iterate_start;
  Positions x_solve = start_positions(sys, in, params, st);
  LocalTargets local(sys.solve_tets.size());
  Eigen::MatrixXd rhs(nf, 3);
  AndersonHistory anderson;
  Eigen::MatrixXd current(nf, 3);
  current = x_solve.topRows(nf);
  std::optional<internal::Contacts> contacts;
  if (params.contact && !sys.contact.empty())
    contacts.emplace(in, sys.solve_vertices, sys.contact, sys.contact_stiffness);
  // Which skin is inside which tissue, looked up again every kLookUpEvery iterations and before the solve stops.
  constexpr int kLookUpEvery = 5;
  const Stopwatch loop_start;  // the budget's mean iteration: the iterations only
  for (int iteration = 0; iteration < params.max_iterations; ++iteration) {
    if (contacts && iteration % kLookUpEvery == 0 && (contacts->detect(x_solve), contacts->changed())) {
      anderson.restart();  // another contact set is another fixed point
      anderson.accelerated = false;
    }
    double e = local_step(sys, x_solve, params.volume_weight, local);
    if (anderson.accelerated && e > anderson.last_energy) {  // the combination raised the energy: the plain step
      current = anderson.plain;
      x_solve.topRows(nf) = current;
      e = local_step(sys, x_solve, params.volume_weight, local);
      anderson.restart();
      ++st.restarts;
    }
    anderson.last_energy = e;
    global_rhs(sys, constant, local, rhs);
    const Eigen::MatrixXd global = sys.llt.solve(rhs);
    const Eigen::MatrixXd residual = global - current;
    st.iterations = iteration + 1;
    st.last_step_mm = residual.rowwise().norm().maxCoeff();
    anderson.record(global, residual);
    // Where the energy keeps rejecting the combinations (tissue pressed through tissue has no steady state to
    // reach), plain steps are cheaper: acceleration stops after a few rejections.
    constexpr int kMaxRestarts = 4;
    if (st.last_step_mm <= params.tolerance_mm || anderson.residual_changes.empty() || st.restarts >= kMaxRestarts) {
      current = global;
      anderson.accelerated = false;
    } else {
      anderson.combine(global, residual, current);
      anderson.accelerated = true;
    }
    x_solve.topRows(nf) = current;
    // The skin inside tissue from elsewhere, put back outside the face it is paired with. The fixed point is then
    // the global step's followed by this projection, but the step is measured before it, so a pose whose skin is
    // pressed runs every iteration (the step the projection undoes does not shrink). Measuring it after the
    // projection left more skin inside on the limb bent 150 degrees (14 of 24 instead of 9) and a tet inverted.
    if (contacts) {
      contacts->project(x_solve);
      current = x_solve.topRows(nf);
    }
    progress.update(static_cast<double>(iteration + 1) / params.max_iterations);
    POSEWARP_RETURN_IF_ERROR(progress.check_cancel());
    if (st.last_step_mm <= params.tolerance_mm) {
      if (!contacts || contacts->detect(x_solve) == 0) break;
      anderson.restart();  // skin newly inside tissue: on with the new contact set
      anderson.accelerated = false;
    }
    if (params.time_budget_seconds > 0.0 && iteration + 1 < params.max_iterations &&
        start.seconds() + loop_start.seconds() / (iteration + 1) > params.time_budget_seconds) {
      st.out_of_time = true;
      break;
    }
  }
  st.iterate_seconds = iterate_start.seconds();
  if (params.untangle) {  // the tets the steady state left inverted, turned back
    const internal::PackedTets packed{sys.slot_corners, sys.gradients, sys.slot_volume,
                                      sys.corner_start, sys.corners,   sys.bone_segment};
    internal::UntangleParams untangle_params;
    untangle_params.piece_volume_weight = params.untangle_volume_weight;
    POSEWARP_ASSIGN_OR_RETURN(const internal::UntangleStats untangled,
                              internal::untangle(packed, nf, x_solve, untangle_params,
                                                 contacts ? internal::ContactLookUp([&](const Positions& x) {
                                                   contacts->detect(x);
                                                   return contacts->planes(x);
                                                 })
                                                          : internal::ContactLookUp{},
                                                 [&] { return progress.check_cancel(); }));
    internal::record(untangled, st);
  }
  if (contacts) {
    st.contacts = contacts->pressed(x_solve);
    st.contact_seconds = contacts->seconds();
  }
  keep_solution(in, x_solve, sys, posed);
  if (in.cache) in.cache->put(std::move(system));
  progress.finish();
  return posed;
}

}  // namespace

Result<Eigen::MatrixXd> solve(const SolveInputs& in, const FemParams& params, const ProgressHooks& hooks,
                              FemStats* stats) {
  return internal::run_solve(in, params, hooks, stats, projective_steady_state);
}

}  // namespace posewarp::fem
