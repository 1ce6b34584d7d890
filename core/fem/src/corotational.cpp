// The straightforward co-rotational linear FEM (Mueller and Gross 2004), the model of the paper's section 5: what the
// projective solve (soft_tissue.cpp) is measured against.
#include <Eigen/CholmodSupport>
#include <Eigen/Dense>
#include <Eigen/Sparse>

#include <algorithm>
#include <array>
#include <string>
#include <utility>
#include <vector>

#include "internal.h"
#include "posewarp/common/parallel.h"
#include "posewarp/fem/soft_tissue.h"
#include "posewarp/common/stopwatch.h"

namespace posewarp::fem {
namespace internal {

int64_t value_slot(const SparseMatrix& m, Eigen::Index row, Eigen::Index col) {
  const int* begin = m.innerIndexPtr() + m.outerIndexPtr()[col];
  const int* end = m.innerIndexPtr() + m.outerIndexPtr()[col + 1];
  const int* at = std::lower_bound(begin, end, static_cast<int>(row));
  return at != end && *at == row ? static_cast<int64_t>(at - m.innerIndexPtr()) : -1;
}

// Packs the tets that touch the free vertices.
Elements gather_elements(const SolveInputs& in, const std::vector<int32_t>& free_vertices) {
  const TetMesh& mesh = in.rest;
  Elements el;
  const auto nf = static_cast<Eigen::Index>(free_vertices.size());
  el.free_count = nf;
  std::vector<int32_t> local(static_cast<size_t>(mesh.vertex_count()), -1);
  el.solve_vertices = free_vertices;
  for (Eigen::Index i = 0; i < nf; ++i) {
    local[static_cast<size_t>(free_vertices[static_cast<size_t>(i)])] = static_cast<int32_t>(i);
  }
  std::vector<int32_t> solve_tets;
  std::vector<uint8_t> taken(static_cast<size_t>(mesh.tet_count()), 0);
  for (const int32_t v : free_vertices) {
    const auto first = in.topology.tet_start[static_cast<size_t>(v)];
    for (int64_t e = first; e < in.topology.tet_start[static_cast<size_t>(v) + 1]; ++e) {
      const int32_t t = in.topology.tets[static_cast<size_t>(e)];
      if (!std::exchange(taken[static_cast<size_t>(t)], uint8_t{1})) solve_tets.push_back(t);
    }
  }
  const size_t slots = solve_tets.size();
  el.corner.resize(slots);
  el.gradients.resize(slots);
  el.volume.resize(slots);
  for (size_t s = 0; s < slots; ++s) {
    for (int c = 0; c < 4; ++c) {
      const int32_t v = mesh.tets(solve_tets[s], c);
      if (local[static_cast<size_t>(v)] < 0) {
        local[static_cast<size_t>(v)] = static_cast<int32_t>(el.solve_vertices.size());
        el.solve_vertices.push_back(v);
      }
      el.corner[s][static_cast<size_t>(c)] = local[static_cast<size_t>(v)];
      el.gradients[s].col(c) = internal::gradient(in.frames, solve_tets[s], c);
    }
    el.volume[s] = in.frames.rest_volume(solve_tets[s]);
  }
  return el;
}

// The free-free blocks' pattern and where each tet's blocks go in its values.
BlockPattern block_pattern(const Elements& el) {
  const Eigen::Index nf = el.free_count;
  const size_t slots = el.corner.size();
  BlockPattern bp;
  SparseMatrix& matrix = bp.matrix;
  matrix.resize(3 * nf, 3 * nf);
  {
    std::vector<Eigen::Triplet<double>> pattern;
    pattern.reserve(slots * 144);
    for (size_t s = 0; s < slots; ++s)
      for (int a = 0; a < 4; ++a)
        for (int b = 0; b < 4; ++b) {
          const int32_t ia = el.corner[s][static_cast<size_t>(a)], ib = el.corner[s][static_cast<size_t>(b)];
          if (ia >= nf || ib >= nf) continue;
          for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c) pattern.emplace_back(3 * ia + r, 3 * ib + c, 1.0);
        }
    matrix.setFromTriplets(pattern.begin(), pattern.end());
    matrix.makeCompressed();
  }
  bp.where_start.assign(slots + 1, 0);
  for (size_t s = 0; s < slots; ++s) {
    for (int a = 0; a < 4; ++a)
      for (int b = 0; b < 4; ++b) {
        const int32_t ia = el.corner[s][static_cast<size_t>(a)], ib = el.corner[s][static_cast<size_t>(b)];
        if (ia >= nf || ib >= nf) continue;
        for (int r = 0; r < 3; ++r)
          for (int c = 0; c < 3; ++c) bp.where.push_back(value_slot(matrix, 3 * ia + r, 3 * ib + c));
      }
    bp.where_start[s + 1] = static_cast<int64_t>(bp.where.size());
  }
  return bp;
}

}  // namespace internal

namespace {

using internal::block_pattern;
using internal::BlockPattern;
using internal::Elements;
using internal::gather_elements;

using internal::Positions;
using internal::SparseMatrix;

// Lame's parameters with mu = 1: a steady state under prescribed positions does not depend on Young's modulus.
struct Lame {
  double mu = 1.0;
  double lambda = 0.0;
};

// Lame's parameters for a Poisson ratio, mu = 1.
Lame lame_parameters(double poisson_ratio) {
  const double mu = 1.0, lambda = 2.0 * poisson_ratio / (1.0 - 2.0 * poisson_ratio) * mu;
  return {mu, lambda};
}

// Slot s's rest stiffness block K_ab = V (lambda g_a g_b^T + mu g_b g_a^T + mu (g_a . g_b) I).
Eigen::Matrix3d stiffness_block(const Elements& el, const Lame& lame, size_t s, int a, int b) {
  const Eigen::Vector3d ga = el.gradients[s].col(a), gb = el.gradients[s].col(b);
  return el.volume[s] * (lame.lambda * ga * gb.transpose() + lame.mu * gb * ga.transpose() +
                         lame.mu * ga.dot(gb) * Eigen::Matrix3d::Identity());
}

// What the iteration carries: the solve vertices' current and rest positions, each tet's rotation, and the damping
// of steps that oscillate.
struct IterationState {
  Positions x, rest;
  std::vector<Eigen::Matrix3d> rotation;  // slot -> R
  double damping = 1.0, last_full_step = 0.0;
};

// The state before the first iteration: every solve vertex at its warm start, no damping.
IterationState initial_state(const SolveInputs& in, const Elements& el) {
  IterationState state;
  const auto rows = static_cast<Eigen::Index>(el.solve_vertices.size());
  state.x.resize(rows, 3);
  state.rest.resize(rows, 3);
  for (size_t i = 0; i < el.solve_vertices.size(); ++i) {
    state.x.row(static_cast<Eigen::Index>(i)) = in.warm.row(el.solve_vertices[i]);
    state.rest.row(static_cast<Eigen::Index>(i)) = in.rest.vertices.row(el.solve_vertices[i]);
  }
  state.rotation.resize(el.corner.size());
  return state;
}

// Each tet's rotation at the current positions: the polar decomposition of its F.
void update_rotations(const Elements& el, IterationState& state) {
  parallel_for(0, static_cast<int64_t>(el.corner.size()), 2048, [&](int64_t s0, int64_t s1) {
    for (int64_t s = s0; s < s1; ++s) {
      Eigen::Matrix3d f = Eigen::Matrix3d::Zero();
      for (int c = 0; c < 4; ++c) {
        f += state.x.row(el.corner[static_cast<size_t>(s)][static_cast<size_t>(c)]).transpose() *
             el.gradients[static_cast<size_t>(s)].col(c).transpose();
      }
      Eigen::Matrix3d u, v;
      Eigen::Vector3d sigma;
      internal::signed_svd(f, u, sigma, v);
      state.rotation[static_cast<size_t>(s)] = u * v.transpose();
    }
  });
}

// Writes sum_e R K_e R^T into the matrix's free-free values and returns the right-hand side of
// sum_e R K_e (R^T x - X) = 0, the fixed vertices held where they are.
Eigen::VectorXd assemble_rotated_system(const Elements& el, const Lame& lame, const IterationState& state,
                                        BlockPattern& bp) {
  const Eigen::Index nf = el.free_count;
  double* values = bp.matrix.valuePtr();
  std::fill(values, values + bp.matrix.nonZeros(), 0.0);
  Eigen::VectorXd rhs = Eigen::VectorXd::Zero(3 * nf);
  for (size_t s = 0; s < el.corner.size(); ++s) {
    const Eigen::Matrix3d& r = state.rotation[s];
    int64_t w = bp.where_start[s];
    for (int a = 0; a < 4; ++a) {
      const int32_t ia = el.corner[s][static_cast<size_t>(a)];
      if (ia >= nf) continue;
      for (int b = 0; b < 4; ++b) {
        const int32_t ib = el.corner[s][static_cast<size_t>(b)];
        const Eigen::Matrix3d k = stiffness_block(el, lame, s, a, b);
        // f_a = sum_b R K_ab (R^T x_b - X_b): R K_ab R^T x_b on the left, R K_ab X_b on the right.
        rhs.segment<3>(3 * ia) += r * (k * state.rest.row(ib).transpose());
        const Eigen::Matrix3d rkr = r * k * r.transpose();
        if (ib < nf) {
          for (int p = 0; p < 3; ++p)
            for (int q = 0; q < 3; ++q) values[bp.where[static_cast<size_t>(w++)]] += rkr(p, q);
        } else {
          rhs.segment<3>(3 * ia) -= rkr * state.x.row(ib).transpose();
        }
      }
    }
  }
  return rhs;
}

// A faint pull towards the warm start keeps the system definite where a free piece touches nothing fixed.
void add_warm_start_pull(const SolveInputs& in, const std::vector<int32_t>& free_vertices, SparseMatrix& matrix,
                         Eigen::VectorXd& rhs) {
  const auto nf = static_cast<Eigen::Index>(free_vertices.size());
  double diagonal = 0.0;
  for (Eigen::Index i = 0; i < 3 * nf; ++i) diagonal += matrix.coeff(i, i);
  const double pull = 1e-9 * diagonal / static_cast<double>(3 * nf);
  for (Eigen::Index i = 0; i < nf; ++i) {
    for (int d = 0; d < 3; ++d) {
      matrix.coeffRef(3 * i + d, 3 * i + d) += pull;
      rhs(3 * i + d) += pull * in.warm(free_vertices[static_cast<size_t>(i)], d);
    }
  }
}

// Moves the free vertices towards the system's solution `next`, damped, and returns the largest move (mm).
// Where tets are inverted the rotations flip from one iteration to the next and the plain iteration oscillates: a
// step larger than the last is taken in part (halved each time it happens).
double take_damped_step(const Eigen::VectorXd& next, int iteration, Eigen::Index nf, IterationState& state) {
  double step = 0.0;
  for (Eigen::Index i = 0; i < nf; ++i) {
    const Eigen::RowVector3d moved(next(3 * i), next(3 * i + 1), next(3 * i + 2));
    step = std::max(step, (moved - state.x.row(i)).norm());
  }
  if (iteration > 0 && step > state.last_full_step) state.damping = std::max(1.0 / 64.0, 0.5 * state.damping);
  state.last_full_step = step;
  for (Eigen::Index i = 0; i < nf; ++i) {
    const Eigen::RowVector3d moved(next(3 * i), next(3 * i + 1), next(3 * i + 2));
    state.x.row(i) += state.damping * (moved - state.x.row(i));
  }
  step *= state.damping;
  return step;
}

}  // namespace

Status validate(const CorotationalParams& params) {
  if (!(params.poisson_ratio >= 0.0 && params.poisson_ratio < 0.5)) {
    return invalid_argument_error("fem poisson_ratio must be in [0, 0.5), got " + std::to_string(params.poisson_ratio));
  }
  return internal::validate_iterations(params.max_iterations, params.tolerance_mm, params.margin_mm);
}

namespace {

// The co-rotational steady state of the free vertices (run_solve has checked the inputs and found them).
Result<Eigen::MatrixXd> corotational_steady_state(const SolveInputs& in, const CorotationalParams& params,
                                                  const std::vector<int32_t>& free_vertices, StageProgress& progress,
                                                  FemStats& st, const Stopwatch& start) {
  Eigen::MatrixXd posed = in.warm;
  const auto nf = static_cast<Eigen::Index>(free_vertices.size());

  // The tets touching a free vertex with their rest stiffness, and the pattern of the free-free matrix.
  const Elements el = gather_elements(in, free_vertices);
  st.tets = static_cast<int64_t>(el.corner.size());
  st.fixed_vertices = static_cast<int64_t>(el.solve_vertices.size()) - nf;
  const Lame lame = lame_parameters(params.poisson_ratio);
  BlockPattern bp = block_pattern(el);
  Eigen::CholmodSupernodalLLT<SparseMatrix, Eigen::Lower> llt;
  llt.analyzePattern(bp.matrix);
  st.factor_seconds = start.seconds();

  // Each iteration: the element rotations from the current positions (polar decomposition of F), then the linear
  // system sum_e R K_e (R^T x - X) = 0 for the free vertices, the bone and border vertices held where they are.
  const Stopwatch iterate_start;
  IterationState state = initial_state(in, el);
  for (int iteration = 0; iteration < params.max_iterations; ++iteration) {
    update_rotations(el, state);
    Eigen::VectorXd rhs = assemble_rotated_system(el, lame, state, bp);
    add_warm_start_pull(in, free_vertices, bp.matrix, rhs);
    llt.factorize(bp.matrix);
    if (llt.info() != Eigen::Success) {
      return internal_error("the co-rotational soft-tissue system (" + std::to_string(nf) +
                            " vertices) could not be factored");
    }
    const Eigen::VectorXd next = llt.solve(rhs);
    const double step = take_damped_step(next, iteration, nf, state);
    st.iterations = iteration + 1;
    st.last_step_mm = step;
    progress.update(static_cast<double>(iteration + 1) / params.max_iterations);
    POSEWARP_RETURN_IF_ERROR(progress.check_cancel());
    if (step <= params.tolerance_mm) break;
  }
  st.iterate_seconds = iterate_start.seconds();
  for (Eigen::Index i = 0; i < nf; ++i) posed.row(free_vertices[static_cast<size_t>(i)]) = state.x.row(i);
  progress.finish();
  return posed;
}

}  // namespace

Result<Eigen::MatrixXd> solve_corotational(const SolveInputs& in, const CorotationalParams& params,
                                           const ProgressHooks& hooks, FemStats* stats) {
  return internal::run_solve(in, params, hooks, stats, corotational_steady_state);
}

}  // namespace posewarp::fem
