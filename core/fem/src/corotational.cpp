// The straightforward co-rotational linear FEM (Mueller and Gross 2004), the model of the paper's section 5: what the
// projective solve (soft_tissue.cpp) is measured against.
#include <Eigen/CholmodSupport>
#include <Eigen/Dense>
#include <Eigen/Sparse>

#include <algorithm>
#include <array>
#include <string>
#include <vector>

#include "internal.h"
#include "posewarp/common/parallel.h"
#include "posewarp/fem/soft_tissue.h"
#include "posewarp/common/stopwatch.h"

namespace posewarp::fem {
namespace {

}  // namespace

Status validate(const CorotationalParams& params) {
  if (!(params.poisson_ratio >= 0.0 && params.poisson_ratio < 0.5)) {
    return invalid_argument_error("fem poisson_ratio must be in [0, 0.5), got " + std::to_string(params.poisson_ratio));
  }
  return internal::validate_iterations(params.max_iterations, params.tolerance_mm, params.margin_mm);
}

Result<Eigen::MatrixXd> solve_corotational(const SolveInputs& in, const CorotationalParams& params,
                                           const ProgressHooks& hooks, FemStats* stats) {
  POSEWARP_RETURN_IF_ERROR(validate(params));
  POSEWARP_RETURN_IF_ERROR(internal::check_inputs(in));
  StageProgress progress(hooks, "fem");
  FemStats local_stats;
  FemStats& st = stats ? *stats : local_stats;
  st = FemStats{};
  const Stopwatch start;
  const TetMesh& mesh = in.rest;
  const std::vector<int32_t> free_vertices = internal::free_vertices(in, params.margin_mm);
  Eigen::MatrixXd posed = in.warm;
  const auto nf = static_cast<Eigen::Index>(free_vertices.size());
  st.free_vertices = nf;
  if (nf == 0) return posed;

  // The tets touching a free vertex, their corners as solve vertices (free ones first) and their rest stiffness
  // blocks K_ab = V (lambda g_a g_b^T + mu g_b g_a^T + mu (g_a . g_b) I), with mu = 1 (a steady state under
  // prescribed positions does not depend on Young's modulus).
  std::vector<int32_t> local(static_cast<size_t>(mesh.vertex_count()), -1);
  std::vector<int32_t> solve_vertices(free_vertices);
  for (Eigen::Index i = 0; i < nf; ++i) local[static_cast<size_t>(free_vertices[static_cast<size_t>(i)])] = static_cast<int32_t>(i);
  std::vector<int32_t> solve_tets;
  std::vector<uint8_t> taken(static_cast<size_t>(mesh.tet_count()), 0);
  for (const int32_t v : free_vertices) {
    for (int64_t e = in.topology.tet_start[static_cast<size_t>(v)]; e < in.topology.tet_start[static_cast<size_t>(v) + 1]; ++e) {
      const int32_t t = in.topology.tets[static_cast<size_t>(e)];
      if (!std::exchange(taken[static_cast<size_t>(t)], uint8_t{1})) solve_tets.push_back(t);
    }
  }
  const size_t slots = solve_tets.size();
  st.tets = static_cast<int64_t>(slots);
  std::vector<std::array<int32_t, 4>> corner(slots);
  std::vector<Eigen::Matrix<double, 3, 4>> gradients(slots);
  std::vector<double> volume(slots);
  for (size_t s = 0; s < slots; ++s) {
    for (int c = 0; c < 4; ++c) {
      const int32_t v = mesh.tets(solve_tets[s], c);
      if (local[static_cast<size_t>(v)] < 0) {
        local[static_cast<size_t>(v)] = static_cast<int32_t>(solve_vertices.size());
        solve_vertices.push_back(v);
      }
      corner[s][static_cast<size_t>(c)] = local[static_cast<size_t>(v)];
      gradients[s].col(c) = internal::gradient(in.frames, solve_tets[s], c);
    }
    volume[s] = in.frames.rest_volume(solve_tets[s]);
  }
  st.fixed_vertices = static_cast<int64_t>(solve_vertices.size()) - nf;
  const double mu = 1.0, lambda = 2.0 * params.poisson_ratio / (1.0 - 2.0 * params.poisson_ratio) * mu;
  auto block = [&](size_t s, int a, int b) -> Eigen::Matrix3d {
    const Eigen::Vector3d ga = gradients[s].col(a), gb = gradients[s].col(b);
    return volume[s] * (lambda * ga * gb.transpose() + mu * gb * ga.transpose() + mu * ga.dot(gb) * Eigen::Matrix3d::Identity());
  };

  // The matrix's pattern (3 x 3 blocks between free vertices sharing a tet), once; each iteration writes its values
  // through `where`: per tet, per free (a, b) pair, the 9 value slots of R K_ab R^T.
  using SparseMatrix = Eigen::SparseMatrix<double>;
  SparseMatrix matrix(3 * nf, 3 * nf);
  {
    std::vector<Eigen::Triplet<double>> pattern;
    pattern.reserve(slots * 144);
    for (size_t s = 0; s < slots; ++s)
      for (int a = 0; a < 4; ++a)
        for (int b = 0; b < 4; ++b) {
          const int32_t ia = corner[s][static_cast<size_t>(a)], ib = corner[s][static_cast<size_t>(b)];
          if (ia >= nf || ib >= nf) continue;
          for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c) pattern.emplace_back(3 * ia + r, 3 * ib + c, 1.0);
        }
    matrix.setFromTriplets(pattern.begin(), pattern.end());
    matrix.makeCompressed();
  }
  auto value_slot = [&](Eigen::Index row, Eigen::Index col) {
    const auto* begin = matrix.innerIndexPtr() + matrix.outerIndexPtr()[col];
    const auto* end = matrix.innerIndexPtr() + matrix.outerIndexPtr()[col + 1];
    return static_cast<int64_t>(std::lower_bound(begin, end, static_cast<int>(row)) - matrix.innerIndexPtr());
  };
  std::vector<int64_t> where;  // per tet, per (a, b) with both free, 9 slots (row-major in the 3 x 3 block)
  std::vector<int64_t> where_start(slots + 1, 0);
  for (size_t s = 0; s < slots; ++s) {
    for (int a = 0; a < 4; ++a)
      for (int b = 0; b < 4; ++b) {
        const int32_t ia = corner[s][static_cast<size_t>(a)], ib = corner[s][static_cast<size_t>(b)];
        if (ia >= nf || ib >= nf) continue;
        for (int r = 0; r < 3; ++r)
          for (int c = 0; c < 3; ++c) where.push_back(value_slot(3 * ia + r, 3 * ib + c));
      }
    where_start[s + 1] = static_cast<int64_t>(where.size());
  }
  Eigen::CholmodSupernodalLLT<SparseMatrix, Eigen::Lower> llt;
  llt.analyzePattern(matrix);
  st.factor_seconds = start.seconds();

  // Each iteration: the element rotations from the current positions (polar decomposition of F), then the linear
  // system sum_e R K_e (R^T x - X) = 0 for the free vertices, the bone and border vertices held where they are.
  const Stopwatch iterate_start;
  Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> x(static_cast<Eigen::Index>(solve_vertices.size()), 3);
  Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> rest(static_cast<Eigen::Index>(solve_vertices.size()), 3);
  for (size_t i = 0; i < solve_vertices.size(); ++i) {
    x.row(static_cast<Eigen::Index>(i)) = in.warm.row(solve_vertices[i]);
    rest.row(static_cast<Eigen::Index>(i)) = mesh.vertices.row(solve_vertices[i]);
  }
  std::vector<Eigen::Matrix3d> rotation(slots);
  double damping = 1.0, last_full_step = 0.0;
  for (int iteration = 0; iteration < params.max_iterations; ++iteration) {
    parallel_for(0, static_cast<int64_t>(slots), 2048, [&](int64_t s0, int64_t s1) {
      for (int64_t s = s0; s < s1; ++s) {
        Eigen::Matrix3d f = Eigen::Matrix3d::Zero();
        for (int c = 0; c < 4; ++c) {
          f += x.row(corner[static_cast<size_t>(s)][static_cast<size_t>(c)]).transpose() *
               gradients[static_cast<size_t>(s)].col(c).transpose();
        }
        Eigen::Matrix3d u, v;
        Eigen::Vector3d sigma;
        internal::signed_svd(f, u, sigma, v);
        rotation[static_cast<size_t>(s)] = u * v.transpose();
      }
    });
    std::fill(matrix.valuePtr(), matrix.valuePtr() + matrix.nonZeros(), 0.0);
    Eigen::VectorXd rhs = Eigen::VectorXd::Zero(3 * nf);
    for (size_t s = 0; s < slots; ++s) {
      const Eigen::Matrix3d& r = rotation[s];
      int64_t w = where_start[s];
      for (int a = 0; a < 4; ++a) {
        const int32_t ia = corner[s][static_cast<size_t>(a)];
        if (ia >= nf) continue;
        for (int b = 0; b < 4; ++b) {
          const int32_t ib = corner[s][static_cast<size_t>(b)];
          const Eigen::Matrix3d k = block(s, a, b);
          // f_a = sum_b R K_ab (R^T x_b - X_b): R K_ab R^T x_b on the left, R K_ab X_b on the right.
          rhs.segment<3>(3 * ia) += r * (k * rest.row(ib).transpose());
          const Eigen::Matrix3d rkr = r * k * r.transpose();
          if (ib < nf) {
            for (int p = 0; p < 3; ++p)
              for (int q = 0; q < 3; ++q) matrix.valuePtr()[where[static_cast<size_t>(w++)]] += rkr(p, q);
          } else {
            rhs.segment<3>(3 * ia) -= rkr * x.row(ib).transpose();
          }
        }
      }
    }
    // A faint pull towards the warm start keeps the system definite where a free piece touches nothing fixed.
    double diagonal = 0.0;
    for (Eigen::Index i = 0; i < 3 * nf; ++i) diagonal += matrix.coeff(i, i);
    const double pull = 1e-9 * diagonal / static_cast<double>(3 * nf);
    for (Eigen::Index i = 0; i < nf; ++i) {
      for (int d = 0; d < 3; ++d) {
        matrix.coeffRef(3 * i + d, 3 * i + d) += pull;
        rhs(3 * i + d) += pull * in.warm(free_vertices[static_cast<size_t>(i)], d);
      }
    }
    llt.factorize(matrix);
    if (llt.info() != Eigen::Success) {
      return internal_error("the co-rotational soft-tissue system (" + std::to_string(nf) + " vertices) could not be factored");
    }
    const Eigen::VectorXd next = llt.solve(rhs);
    double step = 0.0;
    for (Eigen::Index i = 0; i < nf; ++i) {
      const Eigen::RowVector3d moved(next(3 * i), next(3 * i + 1), next(3 * i + 2));
      step = std::max(step, (moved - x.row(i)).norm());
    }
    // Where tets are inverted the rotations flip from one iteration to the next and the plain iteration
    // oscillates: a step larger than the last is taken in part (halved each time it happens).
    if (iteration > 0 && step > last_full_step) damping = std::max(1.0 / 64.0, 0.5 * damping);
    last_full_step = step;
    for (Eigen::Index i = 0; i < nf; ++i) {
      const Eigen::RowVector3d moved(next(3 * i), next(3 * i + 1), next(3 * i + 2));
      x.row(i) += damping * (moved - x.row(i));
    }
    step *= damping;
    st.iterations = iteration + 1;
    st.last_step_mm = step;
    progress.update(static_cast<double>(iteration + 1) / params.max_iterations);
    POSEWARP_RETURN_IF_ERROR(progress.check_cancel());
    if (step <= params.tolerance_mm) break;
  }
  st.iterate_seconds = iterate_start.seconds();
  for (Eigen::Index i = 0; i < nf; ++i) posed.row(free_vertices[static_cast<size_t>(i)]) = x.row(i);
  progress.finish();
  return posed;
}

}  // namespace posewarp::fem
