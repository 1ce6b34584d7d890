// The nonlinear steady state by projected Newton (see soft_tissue.h's solve_nonlinear): the reference the projective
// solve is measured against, and the refinement after it that a pose asks for (api::FemOptions::refine_iterations).
#include <Eigen/CholmodSupport>
#include <Eigen/Dense>
#include <Eigen/Sparse>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "internal.h"
#include "posewarp/common/parallel.h"
#include "posewarp/common/stopwatch.h"
#include "posewarp/fem/soft_tissue.h"

namespace posewarp::fem {
namespace {

using internal::Elements;
using internal::Positions;
using internal::SparseMatrix;
using Matrix9 = Eigen::Matrix<double, 9, 9>;
using Vector9 = Eigen::Matrix<double, 9, 1>;

// det F's gradient in F: its cofactor matrix, column by column f1 x f2, f2 x f0, f0 x f1.
Eigen::Matrix3d cofactor(const Eigen::Matrix3d& f) {
  Eigen::Matrix3d c;
  c.col(0) = f.col(1).cross(f.col(2));
  c.col(1) = f.col(2).cross(f.col(0));
  c.col(2) = f.col(0).cross(f.col(1));
  return c;
}

// Slot s's deformation gradient at positions x.
Eigen::Matrix3d deformation(const Elements& el, const Positions& x, size_t s) {
  Eigen::Matrix3d f = Eigen::Matrix3d::Zero();
  for (int c = 0; c < 4; ++c) {
    f += x.row(el.corner[s][static_cast<size_t>(c)]).transpose() * el.gradients[s].col(c).transpose();
  }
  return f;
}

// One tet's barrier (NonlinearParams::barrier_weight and barrier_from; kappa 0 for a tet it does not guard).
struct Barrier {
  double kappa = 0.0, from = 0.0;
};

// The barrier's value and first two derivatives in J: kappa (J - J0)^2 (-log(J / J0)) below J0, 0 above.
std::array<double, 3> barrier(double j, const Barrier& b) {
  if (b.kappa <= 0.0 || j >= b.from) return {0.0, 0.0, 0.0};
  if (j <= 0.0) return {std::numeric_limits<double>::infinity(), 0.0, 0.0};
  const double d = j - b.from, l = std::log(j / b.from);
  return {-b.kappa * d * d * l, -b.kappa * (2.0 * d * l + d * d / j),
          -b.kappa * (2.0 * l + 4.0 * d / j - d * d / (j * j))};
}

// A tet's energy per rest volume, |F - R|^2 + w (det F - 1)^2 (signed singular values: R is a rotation) and the
// barrier.
double tet_energy(const Eigen::Matrix3d& f, double w, const Barrier& b) {
  Eigen::Matrix3d u, v;
  Eigen::Vector3d sigma;
  internal::signed_svd(f, u, sigma, v);
  const double j = f.determinant();
  return (sigma.array() - 1.0).square().sum() + w * (j - 1.0) * (j - 1.0) + barrier(j, b)[0];
}

// One tet's gradient and definite Hessian in its 4 corners' positions, rest volume included.
struct TetDerivatives {
  Eigen::Matrix<double, 12, 1> gradient;
  Eigen::Matrix<double, 12, 12> hessian;
  double det = 0.0;          // det F, for the stars
  Eigen::Matrix3d cofactor;  // its gradient in F
};

void tet_derivatives(const Eigen::Matrix3d& f, const Eigen::Matrix<double, 3, 4>& g, double volume, double w,
                     const Barrier& guarded_by, TetDerivatives& out) {
  Eigen::Matrix3d u, v;
  Eigen::Vector3d sigma;
  internal::signed_svd(f, u, sigma, v);
  const double j = f.determinant();
  const Eigen::Matrix3d cof = cofactor(f);
  out.det = j;
  out.cofactor = cof;
  const std::array<double, 3> guard = barrier(j, guarded_by);
  const double first = 2.0 * w * (j - 1.0) + guard[1], second = 2.0 * w + guard[2];  // the J terms' derivatives in J
  const Eigen::Matrix3d p = 2.0 * (f - u * v.transpose()) + first * cof;
  // In vec(F) (columns stacked): |F - R|^2's Hessian is 2 I but along the three twists U T V^T / sqrt(2), where it
  // is 2 - 4 / (sigma_a + sigma_b), clamped at 0 (Smith et al. 2019's eigensystem, projected).
  Matrix9 h = 2.0 * Matrix9::Identity();
  constexpr int kPairs[3][2] = {{1, 2}, {0, 2}, {0, 1}};
  for (const auto& pair : kPairs) {
    Eigen::Matrix3d twist = Eigen::Matrix3d::Zero();
    twist(pair[0], pair[1]) = M_SQRT1_2;
    twist(pair[1], pair[0]) = -M_SQRT1_2;
    const Eigen::Matrix3d q = u * twist * v.transpose();
    const Vector9 qv = Eigen::Map<const Vector9>(q.data());
    const double s = sigma(pair[0]) + sigma(pair[1]);
    const double lambda = s > 0.0 ? std::max(0.0, 2.0 - 4.0 / s) : 2.0;
    h += (lambda - 2.0) * qv * qv.transpose();
  }
  // The J terms: second c c^T + first H_det, c = vec(cof F), projected onto its non-negative eigenvalues. In F's
  // singular frame (Smith et al. 2019) H_det is first sigma_c along the twist U T_ab V^T of the pair (a, b) with c
  // the third, -first sigma_c along its flip (T_ab symmetric), and on the scalings U diag(e) V^T the 3 x 3 matrix
  // second g g^T + first (sigma_c off the diagonal), g = (s1 s2, s0 s2, s0 s1); c c^T lies on the scalings alone.
  // The same as the 9 x 9 eigensystem's projection within 1e-11 (a throwaway check on 20000 random F, a third
  // inverted), in a fraction of the time.
  if (w > 0.0 || guard[1] != 0.0) {
    const auto add = [&](const Eigen::Matrix3d& a, double lambda) {
      if (lambda <= 0.0) return;
      const Eigen::Matrix3d q = u * a * v.transpose();
      const Vector9 qv = Eigen::Map<const Vector9>(q.data());
      h.noalias() += lambda * qv * qv.transpose();
    };
    for (const auto& pair : kPairs) {
      const int third = 3 - pair[0] - pair[1];
      Eigen::Matrix3d twist = Eigen::Matrix3d::Zero(), flip = Eigen::Matrix3d::Zero();
      twist(pair[0], pair[1]) = flip(pair[0], pair[1]) = flip(pair[1], pair[0]) = M_SQRT1_2;
      twist(pair[1], pair[0]) = -M_SQRT1_2;
      add(twist, first * sigma(third));
      add(flip, -first * sigma(third));
    }
    const Eigen::Vector3d minors(sigma(1) * sigma(2), sigma(0) * sigma(2), sigma(0) * sigma(1));
    Eigen::Matrix3d scaling = second * minors * minors.transpose();
    for (const auto& pair : kPairs) {
      scaling(pair[0], pair[1]) += first * sigma(3 - pair[0] - pair[1]);
      scaling(pair[1], pair[0]) += first * sigma(3 - pair[0] - pair[1]);
    }
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen;
    eigen.computeDirect(scaling);
    for (int k = 0; k < 3; ++k) add(eigen.eigenvectors().col(k).asDiagonal(), eigen.eigenvalues()(k));
  }
  // F = sum_c x_c g_c^T: corner c's gradient P g_c, the (a, b) block sum_jk g_a(j) g_b(k) H_jk.
  for (int a = 0; a < 4; ++a) {
    out.gradient.segment<3>(3 * a) = volume * p * g.col(a);
    for (int b = 0; b < 4; ++b) {
      Eigen::Matrix3d k = Eigen::Matrix3d::Zero();
      for (int ja = 0; ja < 3; ++ja)
        for (int jb = 0; jb < 3; ++jb) k += g(ja, a) * g(jb, b) * h.block<3, 3>(3 * ja, 3 * jb);
      out.hessian.block<3, 3>(3 * a, 3 * b) = volume * k;
    }
  }
}

// Each free vertex's star: its tets and their rest volume. A star of no volume (tets flat at rest) has no term: it
// keeps nothing, and its J would be 0 / 0.
struct Stars {
  std::vector<std::vector<int32_t>> slots;
  std::vector<double> volume;
};

Stars stars_of(const Elements& el) {
  Stars stars;
  stars.slots.resize(static_cast<size_t>(el.free_count));
  stars.volume.assign(static_cast<size_t>(el.free_count), 0.0);
  for (size_t s = 0; s < el.corner.size(); ++s) {
    for (const int32_t v : el.corner[s]) {
      if (v >= el.free_count) continue;
      stars.slots[static_cast<size_t>(v)].push_back(static_cast<int32_t>(s));
      stars.volume[static_cast<size_t>(v)] += el.volume[s];
    }
  }
  for (size_t v = 0; v < stars.slots.size(); ++v) {
    if (stars.volume[v] <= 1e-9) {  // mm^3
      stars.slots[v].clear();
      stars.volume[v] = 0.0;
    }
  }
  return stars;
}

// Each star's posed over rest volume at positions x (1 for a star of no rest volume).
std::vector<double> star_ratios(const Elements& el, const Stars& stars, const Positions& x) {
  std::vector<double> ratio(stars.slots.size(), 1.0);
  parallel_for(0, static_cast<int64_t>(stars.slots.size()), 1024, [&](int64_t v0, int64_t v1) {
    for (int64_t v = v0; v < v1; ++v) {
      const auto star = static_cast<size_t>(v);
      if (stars.volume[star] <= 0.0) continue;
      double posed = 0.0;
      for (const int32_t s : stars.slots[star]) {
        posed += el.volume[static_cast<size_t>(s)] * deformation(el, x, static_cast<size_t>(s)).determinant();
      }
      ratio[star] = posed / stars.volume[star];
    }
  });
  return ratio;
}

// The whole energy at positions x.
double energy_at(const Elements& el, const Stars& stars, const NonlinearParams& params, const Positions& x,
                 const std::vector<uint8_t>& guarded) {
  std::vector<double> energy(el.corner.size()), det(el.corner.size());
  parallel_for(0, static_cast<int64_t>(el.corner.size()), 2048, [&](int64_t s0, int64_t s1) {
    for (int64_t s = s0; s < s1; ++s) {
      const Eigen::Matrix3d f = deformation(el, x, static_cast<size_t>(s));
      const Barrier b{guarded[static_cast<size_t>(s)] ? params.barrier_weight : 0.0, params.barrier_from};
      energy[static_cast<size_t>(s)] = el.volume[static_cast<size_t>(s)] * tet_energy(f, params.tet_volume_weight, b);
      det[static_cast<size_t>(s)] = f.determinant();
    }
  });
  double total = 0.0;
  for (const double e : energy) total += e;
  if (params.star_volume_weight > 0.0) {
    for (size_t v = 0; v < stars.slots.size(); ++v) {
      if (stars.volume[v] <= 0.0) continue;
      double posed = 0.0;
      for (const int32_t s : stars.slots[v]) posed += el.volume[static_cast<size_t>(s)] * det[static_cast<size_t>(s)];
      const double j = posed / stars.volume[v];
      total += params.star_volume_weight * stars.volume[v] * (j - 1.0) * (j - 1.0);
    }
  }
  return total;
}

// The Newton matrix's lower triangle, its pattern fixed for a solve: the tets' blocks between free vertices and, with
// a star volume, every pair of free vertices in one star (two edges apart); where each entry goes among its values.
struct NewtonPattern {
  SparseMatrix matrix;
  // Per tet, per corner pair (a, b) and entry (r, c) of their 3 x 3 block (144 in all): its value slot, -1 above the
  // diagonal or on a fixed corner.
  std::vector<int32_t> tet_slot;
  // Per star: its distinct free vertices; per (tet, free corner) of the star in Stars order, that vertex's place
  // among them; and per pair (p, q <= p) of the star's coordinates (3 per vertex, ascending), the value slot.
  std::vector<int64_t> vertex_start, corner_start, pair_start;
  std::vector<int32_t> vertices, corner_place, pair_slot;
  std::vector<int32_t> diagonal;  // per coordinate
};

// The lower triangle's layout by 3 x 3 blocks: per free vertex j (a block column), the vertices i >= j of its blocks,
// ascending from j itself. Column 3 j + c holds the diagonal block's rows 3 j + r (r >= c), then 3 rows per block
// below it, so an entry's slot follows from its block's place in the column without a search of the rows.
class BlockLayout {
 public:
  explicit BlockLayout(Eigen::Index vertices) : rows_(static_cast<size_t>(vertices)) {
    for (Eigen::Index j = 0; j < vertices; ++j) rows_[static_cast<size_t>(j)].push_back(static_cast<int32_t>(j));
  }
  void add(int32_t i, int32_t j) {  // the block of vertices i and j (either order)
    if (i < j) std::swap(i, j);
    if (i != j) rows_[static_cast<size_t>(j)].push_back(i);
  }
  // The matrix's pattern (values 0); the layout's blocks are fixed from here on.
  SparseMatrix pattern() {
    const auto n = static_cast<Eigen::Index>(rows_.size());
    start_.assign(3 * rows_.size() + 1, 0);
    for (size_t j = 0; j < rows_.size(); ++j) {
      std::vector<int32_t>& rows = rows_[j];
      std::sort(rows.begin() + 1, rows.end());
      rows.erase(std::unique(rows.begin() + 1, rows.end()), rows.end());
      for (int c = 0; c < 3; ++c) {
        start_[3 * j + static_cast<size_t>(c) + 1] =
            start_[3 * j + static_cast<size_t>(c)] + (3 - c) + 3 * static_cast<int64_t>(rows.size() - 1);
      }
    }
    SparseMatrix m(3 * n, 3 * n);
    m.resizeNonZeros(static_cast<Eigen::Index>(start_.back()));
    for (size_t k = 0; k < start_.size(); ++k) m.outerIndexPtr()[k] = static_cast<int>(start_[k]);
    int* inner = m.innerIndexPtr();
    for (size_t j = 0; j < rows_.size(); ++j)
      for (int c = 0; c < 3; ++c) {
        int64_t at = start_[3 * j + static_cast<size_t>(c)];
        for (int r = c; r < 3; ++r) inner[at++] = static_cast<int>(3 * j) + r;
        for (size_t k = 1; k < rows_[j].size(); ++k)
          for (int r = 0; r < 3; ++r) inner[at++] = 3 * rows_[j][k] + r;
      }
    std::fill(m.valuePtr(), m.valuePtr() + m.nonZeros(), 0.0);
    return m;
  }
  // Vertex i's place among block column j's rows (i >= j, a block the layout holds).
  int32_t place(int32_t i, int32_t j) const {
    const std::vector<int32_t>& rows = rows_[static_cast<size_t>(j)];
    return i == j ? 0 : static_cast<int32_t>(std::lower_bound(rows.begin() + 1, rows.end(), i) - rows.begin());
  }
  // The slot of entry (r, c) of block (i, j) at `place` in its column (rows of the diagonal block: r >= c).
  int32_t slot(int32_t j, int32_t place, int r, int c) const {
    const int64_t column = start_[3 * static_cast<size_t>(j) + static_cast<size_t>(c)];
    return static_cast<int32_t>(place == 0 ? column + (r - c) : column + (3 - c) + 3 * (place - 1) + r);
  }

 private:
  std::vector<std::vector<int32_t>> rows_;
  std::vector<int64_t> start_;  // per column, its first slot
};

NewtonPattern newton_pattern(const Elements& el, const Stars& stars, bool with_stars) {
  const Eigen::Index nf = el.free_count;
  NewtonPattern np;
  BlockLayout layout(nf);
  for (const std::array<int32_t, 4>& corner : el.corner)
    for (const int32_t a : corner)
      for (const int32_t b : corner)
        if (a < nf && b < nf) layout.add(a, b);
  np.vertex_start.assign(1, 0);
  np.corner_start.assign(1, 0);
  for (size_t v = 0; with_stars && v < stars.slots.size(); ++v) {
    std::vector<int32_t> mine;
    for (const int32_t s : stars.slots[v])
      for (const int32_t k : el.corner[static_cast<size_t>(s)])
        if (k < nf) mine.push_back(k);
    std::sort(mine.begin(), mine.end());
    mine.erase(std::unique(mine.begin(), mine.end()), mine.end());
    for (const int32_t s : stars.slots[v])
      for (const int32_t k : el.corner[static_cast<size_t>(s)])
        if (k < nf) {
          np.corner_place.push_back(static_cast<int32_t>(std::lower_bound(mine.begin(), mine.end(), k) - mine.begin()));
        }
    for (size_t p = 0; p < mine.size(); ++p)
      for (size_t q = 0; q < p; ++q) layout.add(mine[p], mine[q]);
    np.vertices.insert(np.vertices.end(), mine.begin(), mine.end());
    np.vertex_start.push_back(static_cast<int64_t>(np.vertices.size()));
    np.corner_start.push_back(static_cast<int64_t>(np.corner_place.size()));
  }
  np.matrix = layout.pattern();
  np.tet_slot.assign(144 * el.corner.size(), -1);
  parallel_for(0, static_cast<int64_t>(el.corner.size()), 1024, [&](int64_t s0, int64_t s1) {
    for (int64_t s = s0; s < s1; ++s) {
      int32_t* to = np.tet_slot.data() + 144 * s;
      const std::array<int32_t, 4>& corner = el.corner[static_cast<size_t>(s)];
      for (int a = 0; a < 4; ++a)
        for (int b = 0; b < 4; ++b) {
          const int32_t ia = corner[static_cast<size_t>(a)], ib = corner[static_cast<size_t>(b)];
          if (ia >= nf || ib >= nf || ia < ib) continue;
          const int32_t place = layout.place(ia, ib);
          for (int r = 0; r < 3; ++r)
            for (int c = 0; c < 3; ++c)
              if (ia > ib || r >= c) to[36 * a + 9 * b + 3 * r + c] = layout.slot(ib, place, r, c);
        }
    }
  });
  np.pair_start.assign(1, 0);
  for (size_t v = 0; v + 1 < np.vertex_start.size(); ++v) {
    const int32_t* mine = np.vertices.data() + np.vertex_start[v];
    const auto count = static_cast<size_t>(np.vertex_start[v + 1] - np.vertex_start[v]);
    std::vector<int32_t> places(count * count);  // mine[p]'s place in mine[q]'s block column, q <= p
    for (size_t p = 0; p < count; ++p)
      for (size_t q = 0; q <= p; ++q) places[p * count + q] = layout.place(mine[p], mine[q]);
    for (size_t p = 0; p < 3 * count; ++p)
      for (size_t q = 0; q <= p; ++q) {
        np.pair_slot.push_back(layout.slot(mine[q / 3], places[(p / 3) * count + q / 3], static_cast<int>(p % 3),
                                           static_cast<int>(q % 3)));
      }
    np.pair_start.push_back(static_cast<int64_t>(np.pair_slot.size()));
  }
  np.diagonal.resize(static_cast<size_t>(3 * nf));
  for (Eigen::Index i = 0; i < 3 * nf; ++i) {
    np.diagonal[static_cast<size_t>(i)] = layout.slot(static_cast<int32_t>(i / 3), 0, static_cast<int>(i % 3),
                                                      static_cast<int>(i % 3));
  }
  return np;
}

// The Newton system at x into the pattern's values: the tets' definite Hessians and the stars' Gauss-Newton terms
// 2 w_n V_s dJ_s dJ_s^T, dJ_s in corner c of tet t being V_t / V_s cof(F_t) g_c; returns the gradient.
Eigen::VectorXd assemble(const Elements& el, const Stars& stars, const NonlinearParams& params, const Positions& x,
                         const std::vector<uint8_t>& guarded, NewtonPattern& np,
                         std::vector<TetDerivatives>& derivatives) {
  const Eigen::Index nf = el.free_count;
  derivatives.resize(el.corner.size());
  parallel_for(0, static_cast<int64_t>(el.corner.size()), 512, [&](int64_t s0, int64_t s1) {
    for (int64_t s = s0; s < s1; ++s) {
      const auto slot = static_cast<size_t>(s);
      const Barrier b{guarded[slot] ? params.barrier_weight : 0.0, params.barrier_from};
      tet_derivatives(deformation(el, x, slot), el.gradients[slot], el.volume[slot], params.tet_volume_weight, b,
                      derivatives[slot]);
    }
  });
  double* values = np.matrix.valuePtr();
  std::fill(values, values + np.matrix.nonZeros(), 0.0);
  Eigen::VectorXd gradient = Eigen::VectorXd::Zero(3 * nf);
  for (size_t s = 0; s < el.corner.size(); ++s) {
    const int32_t* to = np.tet_slot.data() + 144 * s;
    for (int a = 0; a < 4; ++a) {
      const int32_t ia = el.corner[s][static_cast<size_t>(a)];
      if (ia >= nf) continue;
      gradient.segment<3>(3 * ia) += derivatives[s].gradient.segment<3>(3 * a);
      for (int b = 0; b < 4; ++b)
        for (int r = 0; r < 3; ++r)
          for (int c = 0; c < 3; ++c) {
            const int32_t slot = to[36 * a + 9 * b + 3 * r + c];
            if (slot >= 0) values[slot] += derivatives[s].hessian(3 * a + r, 3 * b + c);
          }
    }
  }
  if (params.star_volume_weight <= 0.0) return gradient;
  // Each star's dJ_s over its distinct free vertices (3 per vertex) and its J_s, on every thread; then added in.
  const auto star_count = static_cast<int64_t>(np.vertex_start.size()) - 1;
  std::vector<double> dj(3 * np.vertices.size(), 0.0), j(static_cast<size_t>(star_count), 0.0);
  parallel_for(0, star_count, 256, [&](int64_t v0, int64_t v1) {
    for (int64_t v = v0; v < v1; ++v) {
      const auto star = static_cast<size_t>(v);
      double* d = dj.data() + 3 * np.vertex_start[star];
      int64_t place = np.corner_start[star];
      double posed = 0.0;
      if (stars.volume[star] <= 0.0) continue;
      for (const int32_t s : stars.slots[star]) {
        const auto slot = static_cast<size_t>(s);
        posed += el.volume[slot] * derivatives[slot].det;
        for (int c = 0; c < 4; ++c) {
          if (el.corner[slot][static_cast<size_t>(c)] >= nf) continue;
          const Eigen::Vector3d g =
              el.volume[slot] / stars.volume[star] * (derivatives[slot].cofactor * el.gradients[slot].col(c));
          double* to = d + 3 * np.corner_place[static_cast<size_t>(place++)];
          for (int r = 0; r < 3; ++r) to[r] += g(r);
        }
      }
      j[star] = posed / stars.volume[star];
    }
  });
  for (size_t star = 0; star < static_cast<size_t>(star_count); ++star) {
    if (stars.volume[star] <= 0.0) continue;
    const double scale = 2.0 * params.star_volume_weight * stars.volume[star];
    const double* d = dj.data() + 3 * np.vertex_start[star];
    const int32_t* mine = np.vertices.data() + np.vertex_start[star];
    const auto coordinates = static_cast<size_t>(3 * (np.vertex_start[star + 1] - np.vertex_start[star]));
    for (size_t p = 0; p < coordinates; ++p)
      gradient(3 * mine[p / 3] + static_cast<Eigen::Index>(p % 3)) += scale * (j[star] - 1.0) * d[p];
    const int32_t* to = np.pair_slot.data() + np.pair_start[star];
    for (size_t p = 0; p < coordinates; ++p)
      for (size_t q = 0; q <= p; ++q) values[*to++] += scale * d[p] * d[q];
  }
  return gradient;
}

// The free vertices within `rings` edges of a vertex whose star is compressed below `below` of its rest volume at the
// warm start (NonlinearParams::region_below), ascending as given.
std::vector<int32_t> compressed_region(const SolveInputs& in, const std::vector<int32_t>& free_vertices, double below,
                                       int rings) {
  const Elements el = internal::gather_elements(in, free_vertices);
  const Stars stars = stars_of(el);
  Positions x(static_cast<Eigen::Index>(el.solve_vertices.size()), 3);
  for (size_t i = 0; i < el.solve_vertices.size(); ++i)
    x.row(static_cast<Eigen::Index>(i)) = in.warm.row(el.solve_vertices[i]);
  std::vector<uint8_t> in_region(free_vertices.size(), 0);
  std::vector<int32_t> frontier;
  const std::vector<double> ratio = star_ratios(el, stars, x);
  for (size_t v = 0; v < stars.slots.size(); ++v) {
    if (stars.volume[v] > 0.0 && ratio[v] < below) {
      in_region[v] = 1;
      frontier.push_back(static_cast<int32_t>(v));
    }
  }
  for (int ring = 0; ring < rings; ++ring) {
    std::vector<int32_t> next;
    for (const int32_t v : frontier)
      for (const int32_t s : stars.slots[static_cast<size_t>(v)])
        for (const int32_t k : el.corner[static_cast<size_t>(s)])
          if (k < el.free_count && !std::exchange(in_region[static_cast<size_t>(k)], uint8_t{1})) next.push_back(k);
    frontier = std::move(next);
  }
  std::vector<int32_t> region;
  for (size_t i = 0; i < free_vertices.size(); ++i)
    if (in_region[i]) region.push_back(free_vertices[i]);
  return region;
}

Result<Eigen::MatrixXd> nonlinear_steady_state(const SolveInputs& in, const NonlinearParams& params,
                                               std::vector<int32_t> free_vertices, StageProgress& progress,
                                               FemStats& st, const Stopwatch& start) {
  if (params.region_below > 0.0) {
    free_vertices = compressed_region(in, free_vertices, params.region_below, params.region_rings);
    st.free_vertices = static_cast<int64_t>(free_vertices.size());
    if (free_vertices.empty()) return in.warm;
  }
  const auto nf = static_cast<Eigen::Index>(free_vertices.size());
  const Elements el = internal::gather_elements(in, free_vertices);
  st.tets = static_cast<int64_t>(el.corner.size());
  st.fixed_vertices = static_cast<int64_t>(el.solve_vertices.size()) - nf;
  Stars stars = stars_of(el);
  Positions x(static_cast<Eigen::Index>(el.solve_vertices.size()), 3);
  for (size_t i = 0; i < el.solve_vertices.size(); ++i)
    x.row(static_cast<Eigen::Index>(i)) = in.warm.row(el.solve_vertices[i]);
  if (params.star_below > 0.0) {  // only the stars the warm start left compressed keep their volume
    const std::vector<double> ratio = star_ratios(el, stars, x);
    for (size_t v = 0; v < stars.slots.size(); ++v) {
      if (ratio[v] >= params.star_below) {
        stars.slots[v].clear();
        stars.volume[v] = 0.0;
      }
    }
  }
  // The barrier guards the tets the warm start has unfolded.
  std::vector<uint8_t> guarded(el.corner.size(), 0);
  for (size_t slot = 0; slot < el.corner.size(); ++slot) guarded[slot] = deformation(el, x, slot).determinant() > 0.0;
  // The matrix's pattern and its ordering, once.
  NewtonPattern np = newton_pattern(el, stars, params.star_volume_weight > 0.0);
  Eigen::CholmodSupernodalLLT<SparseMatrix, Eigen::Lower> llt;
  llt.analyzePattern(np.matrix);
  st.factor_seconds = start.seconds();

  const Stopwatch iterate_start;
  double energy = energy_at(el, stars, params, x, guarded);
  std::vector<TetDerivatives> derivatives;
  for (int iteration = 0; iteration < params.max_iterations; ++iteration) {
    const Eigen::VectorXd gradient = assemble(el, stars, params, x, guarded, np, derivatives);
    if (!std::isfinite(energy) || !gradient.allFinite()) {
      return internal_error("the nonlinear soft-tissue energy is not finite at its start (" + std::to_string(nf) +
                            " vertices; a tet flat at rest?): rebuild the rig");
    }
    // A faint shift keeps the system definite where a vertex's tets give it no stiffness in some direction.
    double trace = 0.0;
    for (const int32_t d : np.diagonal) trace += np.matrix.valuePtr()[d];
    const double shift = 1e-8 * trace / static_cast<double>(3 * nf);
    for (const int32_t d : np.diagonal) np.matrix.valuePtr()[d] += shift;
    llt.factorize(np.matrix);
    if (llt.info() != Eigen::Success) {
      return internal_error("the nonlinear soft-tissue system (" + std::to_string(nf) +
                            " vertices) could not be factored");
    }
    const Eigen::VectorXd step = llt.solve(-gradient);
    // Converged once the Newton step itself moves no vertex more than the tolerance: where the barrier holds a tet,
    // the line search takes a part of the step only, which says nothing of how far the minimum still is.
    double newton_step = 0.0;
    for (Eigen::Index i = 0; i < nf; ++i) newton_step = std::max(newton_step, step.segment<3>(3 * i).norm());
    st.iterations = iteration + 1;
    st.last_step_mm = newton_step;
    if (newton_step <= params.tolerance_mm) break;
    // Backtracking (Armijo): the longest of 1, 1/2, 1/4, ... that lowers the energy by its share of the slope.
    const double slope = gradient.dot(step);
    if (!std::isfinite(slope)) {
      return internal_error("the nonlinear soft-tissue solve's step is not finite (" + std::to_string(nf) +
                            " vertices)");
    }
    Positions trial = x;
    double alpha = 1.0, trial_energy = energy;
    bool lowered = false;
    for (int k = 0; k < 30; ++k) {
      for (Eigen::Index i = 0; i < nf; ++i) trial.row(i) = x.row(i) + alpha * step.segment<3>(3 * i).transpose();
      trial_energy = energy_at(el, stars, params, trial, guarded);
      lowered = trial_energy <= energy + 1e-4 * alpha * slope;
      if (lowered) break;
      alpha *= 0.5;
    }
    if (!lowered)
      break;  // a descent direction along which no step lowers the energy: a minimum, as far as doubles tell
    x = trial;
    energy = trial_energy;
    progress.update(static_cast<double>(iteration + 1) / params.max_iterations);
    POSEWARP_RETURN_IF_ERROR(progress.check_cancel());
  }
  st.iterate_seconds = iterate_start.seconds();
  if (params.untangle) {  // as the projective solve ends: the tets left inverted turned back
    std::vector<int64_t> vertex_start(static_cast<size_t>(nf) + 1, 0);
    std::vector<std::pair<int32_t, int32_t>> vertex_tets;
    for (Eigen::Index i = 0; i < nf; ++i) {
      for (const int32_t s : stars.slots[static_cast<size_t>(i)]) {
        int c = 0;
        while (el.corner[static_cast<size_t>(s)][static_cast<size_t>(c)] != i) ++c;
        vertex_tets.emplace_back(s, c);
      }
      vertex_start[static_cast<size_t>(i) + 1] = static_cast<int64_t>(vertex_tets.size());
    }
    const std::vector<int32_t> bone_segment = internal::bone_segments(in, el.solve_vertices, static_cast<size_t>(nf));
    const internal::PackedTets packed{el.corner, el.gradients, el.volume, vertex_start, vertex_tets, bone_segment};
    internal::UntangleParams untangle_params;
    untangle_params.piece_volume_weight = FemParams{}.untangle_volume_weight;
    POSEWARP_ASSIGN_OR_RETURN(const internal::UntangleStats untangled,
                              internal::untangle(packed, nf, x, untangle_params, internal::ContactLookUp{},
                                                 [&] { return progress.check_cancel(); }));
    internal::record(untangled, st);
  }
  Eigen::MatrixXd posed = in.warm;
  for (Eigen::Index i = 0; i < nf; ++i) posed.row(free_vertices[static_cast<size_t>(i)]) = x.row(i);
  progress.finish();
  return posed;
}

}  // namespace

Status validate(const NonlinearParams& params) {
  if (!(params.tet_volume_weight >= 0.0 && params.tet_volume_weight <= 1e6)) {
    return invalid_argument_error("fem tet_volume_weight must be in [0, 1e6], got " +
                                  std::to_string(params.tet_volume_weight));
  }
  if (!(params.star_volume_weight >= 0.0 && params.star_volume_weight <= 1e6)) {
    return invalid_argument_error("fem star_volume_weight must be in [0, 1e6], got " +
                                  std::to_string(params.star_volume_weight));
  }
  if (!(params.region_below >= 0.0 && params.region_below <= 1.0)) {
    return invalid_argument_error("fem region_below must be in [0, 1], got " + std::to_string(params.region_below));
  }
  if (params.region_rings < 0 || params.region_rings > 100) {
    return invalid_argument_error("fem region_rings must be in [0, 100], got " + std::to_string(params.region_rings));
  }
  if (!(params.star_below >= 0.0 && params.star_below <= 10.0)) {
    return invalid_argument_error("fem star_below must be in [0, 10], got " + std::to_string(params.star_below));
  }
  if (!(params.barrier_from > 0.0 && params.barrier_from <= 1.0)) {
    return invalid_argument_error("fem barrier_from must be in (0, 1], got " + std::to_string(params.barrier_from));
  }
  if (!(params.barrier_weight >= 0.0 && params.barrier_weight <= 1e6)) {
    return invalid_argument_error("fem barrier_weight must be in [0, 1e6], got " +
                                  std::to_string(params.barrier_weight));
  }
  return internal::validate_iterations(params.max_iterations, params.tolerance_mm, params.margin_mm);
}

Result<Eigen::MatrixXd> solve_nonlinear(const SolveInputs& in, const NonlinearParams& params,
                                        const ProgressHooks& hooks, FemStats* stats) {
  return internal::run_solve(in, params, hooks, stats, nonlinear_steady_state, "fem-refine");
}

}  // namespace posewarp::fem
