// Turning back the soft tets a solve left inverted (see internal.h): a foldover-free energy after Garanzha et al.
// 2021 on the free vertices around them, minimised by L-BFGS while its regulariser shrinks.
#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <deque>
#include <functional>
#include <limits>
#include <vector>

#include "internal.h"
#include "posewarp/common/disjoint_sets.h"
#include "posewarp/common/parallel.h"
#include "posewarp/common/stopwatch.h"

namespace posewarp::fem::internal {
namespace {

// The regularised determinant: (D + sqrt(eps^2 + D^2)) / 2, positive for every D, D itself as eps goes to 0 where D
// is positive; written without cancellation where D is negative.
double chi_of(double d, double eps, double root) {
  return d >= 0.0 ? 0.5 * (d + root) : 0.5 * eps * eps / (root - d);
}
double chi(double d, double eps) {
  return chi_of(d, eps, std::sqrt(eps * eps + d * d));
}

// The cube root of a positive normal double, within 1e-15 of std::cbrt in under half its time (the untangling takes
// one per tet per evaluation): an exponent-thirding first guess, then three Halley steps.
double cube_root(double x) {
  uint64_t bits = 0;
  std::memcpy(&bits, &x, sizeof bits);
  bits = bits / 3 + 0x2A9F7893782DA1CEull;
  double y = 0.0;
  std::memcpy(&y, &bits, sizeof y);
  for (int k = 0; k < 3; ++k) {
    const double y3 = y * y * y;
    y *= (y3 + 2.0 * x) / (2.0 * y3 + x);
  }
  return y;
}

// The untangled region: its vertices (free solve vertices, numbered 0..n-1 here), its tets with each corner's
// region number or -1 - (solve vertex) for a held corner, and each region vertex's (tet, corner) pairs.
struct Region {
  std::vector<int32_t> vertices;                // region vertex -> solve vertex
  std::vector<int32_t> slots;                   // region tet -> packed tet
  std::vector<std::array<int32_t, 4>> corners;  // region tet -> region vertex, or -1 - solve vertex when held
  // Region tet -> the least eps of its regulariser: above 0 for a tet with three or more corners held (kHeldEps,
  // kGapEps in a joint's gap), 0 for the others.
  std::vector<double> floor;
  std::vector<int64_t> vertex_start;            // n + 1
  std::vector<std::pair<int32_t, int32_t>> vertex_tets;
  // Connected pieces (vertices sharing a region tet): region tet -> its piece (-1 when every corner is held) and the
  // rest volume its piece counts from it (a quarter of the tet per corner in the region).
  std::vector<int32_t> tet_piece;
  std::vector<double> piece_volume;
  int32_t pieces = 0;
};

// Finds the region's connected pieces (Region::tet_piece, piece_volume, pieces).
void find_pieces(const PackedTets& tets, Region& r) {
  DisjointSets sets(static_cast<int64_t>(r.vertices.size()));
  for (const std::array<int32_t, 4>& corner : r.corners) {
    int32_t first = -1;
    for (const int32_t k : corner) {
      if (k < 0) continue;
      if (first < 0) {
        first = k;
      } else {
        sets.unite(first, k);
      }
    }
  }
  std::vector<int32_t> number(r.vertices.size(), -1);
  r.tet_piece.assign(r.corners.size(), -1);
  r.piece_volume.assign(r.corners.size(), 0.0);
  for (size_t t = 0; t < r.corners.size(); ++t) {
    int32_t first = -1, count = 0;
    for (const int32_t k : r.corners[t]) {
      if (k < 0) continue;
      if (first < 0) first = k;
      ++count;
    }
    if (first < 0) continue;
    int32_t& n = number[static_cast<size_t>(sets.find(first))];
    if (n < 0) n = r.pieces++;
    r.tet_piece[t] = n;
    r.piece_volume[t] = 0.25 * count * tets.volume[static_cast<size_t>(r.slots[t])];
  }
}

// A tet with three corners held leaves its fourth one side of a fixed triangle, which the tets around it may
// forbid: such a tet keeps a floor under its regulariser, a soft push rather than a wall, and its det does not set
// the others' eps. Where its free corner also touches another bone's tets it sits in a joint's gap, which a bent
// joint shears past any position of that corner (the two bone surfaces slide; the rig build's cut, cut_joint_gaps,
// lets them, but a rig built before it or with --weld-joint-gaps keeps such tets, and so does a gap's rim): there the
// floor is 1, elsewhere 0.1. posewarp_fem_probe on eight scripts/body_check rigs at 90 degrees,
// tissue within 50 mm, 1 everywhere -> 0.1 off the gaps: knee -1.0 to -5.9% -> -0.4 to -4.6% (better on all eight),
// elbow -1.0 to -5.1% -> -0.5 to -3.8%, shoulder -2.2 to -5.2% -> -2.0 to -4.9%, hip -14.6 to -20.4% -> -15.4 to
// -20.3% (worse by up to 1.5 points on six); folded 0.8-6.5% -> 0.8-6.9%. A floor of 0.1 for every such tet (stop 41,
// a --joint-size 5 rig) folded more at the hip and undid the shoulder's untangling: the gaps' tets pulled the rest.
constexpr int kMostHeld = 3;
constexpr double kHeldEps = 0.1;
constexpr double kGapEps = 1.0;
// The regulariser's schedule: the worst tet's regularised det starts at kFirstMu and falls by at least kLeastCut a
// round of kInner L-BFGS steps; kPureBarrier once every tet is positive (the energy then keeps them so). 0.5 and 25
// (were 0.3 and 40), posewarp_fem_probe on out/bc9 and bc10: at the hips 90 (fem:100:20:cor) the untangling took
// 0.28 / 0.65 s instead of 0.76 / 1.08, the share folded within 50 mm 0.9 / 0.5% (was 0.9 / 0.6%), the volume
// there -7.9 / -6.8% (was -7.2 / -5.5%); at bc9's knee, elbow and shoulder 90 (pose:0:2, no refinement) the whole solve
// 0.26-0.40 s instead of 0.35-1.05 (the shoulder), folded 0.7 -> 0.4%, 0.6 -> 0.6%, 0.5 -> 0.3%, the volume 0.2-0.5
// point further from rest. The refinement after it gives that volume back (api::FemOptions::refine_iterations).
constexpr double kFirstMu = 0.1;
constexpr double kLeastCut = 0.5;
constexpr double kPureBarrier = 1e-10;
constexpr double kFlatEps = 1e-3;
constexpr int kInner = 25;
// Rounds in which the worst det gains less than kProgress before the minimisation stops.
constexpr double kProgress = 1e-3;
constexpr int kStalledRounds = 5;

Region grow_region(const PackedTets& tets, Eigen::Index free_count, const std::vector<int32_t>& seeds, int rings) {
  Region r;
  std::vector<int32_t> local(static_cast<size_t>(free_count), -1);
  std::vector<int32_t> frontier;
  for (const int32_t v : seeds) {
    if (local[static_cast<size_t>(v)] < 0) {
      local[static_cast<size_t>(v)] = static_cast<int32_t>(r.vertices.size());
      r.vertices.push_back(v);
      frontier.push_back(v);
    }
  }
  for (int ring = 0; ring < rings; ++ring) {
    std::vector<int32_t> next;
    for (const int32_t v : frontier) {
      for (int64_t e = tets.vertex_start[static_cast<size_t>(v)]; e < tets.vertex_start[static_cast<size_t>(v) + 1];
           ++e) {
        for (const int32_t w : tets.corners[static_cast<size_t>(tets.vertex_tets[static_cast<size_t>(e)].first)]) {
          if (w < free_count && local[static_cast<size_t>(w)] < 0) {
            local[static_cast<size_t>(w)] = static_cast<int32_t>(r.vertices.size());
            r.vertices.push_back(w);
            next.push_back(w);
          }
        }
      }
    }
    frontier = std::move(next);
  }
  std::vector<int32_t> slot_index(tets.corners.size(), -1);
  r.vertex_start.assign(r.vertices.size() + 1, 0);
  for (size_t i = 0; i < r.vertices.size(); ++i) {
    const int32_t v = r.vertices[i];
    for (int64_t e = tets.vertex_start[static_cast<size_t>(v)]; e < tets.vertex_start[static_cast<size_t>(v) + 1];
         ++e) {
      const auto [slot, c] = tets.vertex_tets[static_cast<size_t>(e)];
      if (slot_index[static_cast<size_t>(slot)] < 0) {
        slot_index[static_cast<size_t>(slot)] = static_cast<int32_t>(r.slots.size());
        r.slots.push_back(slot);
        std::array<int32_t, 4> corner{};
        for (int k = 0; k < 4; ++k) {
          const int32_t w = tets.corners[static_cast<size_t>(slot)][static_cast<size_t>(k)];
          corner[static_cast<size_t>(k)] =
              w < free_count && local[static_cast<size_t>(w)] >= 0 ? local[static_cast<size_t>(w)] : -1 - w;
        }
        r.corners.push_back(corner);
        int held = 0;
        for (const int32_t k : corner) held += k < 0;
        r.floor.push_back(held >= kMostHeld ? kHeldEps : 0.0);
      }
      r.vertex_tets.emplace_back(slot_index[static_cast<size_t>(slot)], c);
    }
    r.vertex_start[i + 1] = static_cast<int64_t>(r.vertex_tets.size());
  }
  // Each region vertex whose tets have held corners on two bones (it lies in a joint's gap); a mostly held tet with
  // such a corner gets the gap's floor.
  std::vector<uint8_t> in_gap(r.vertices.size(), 0);
  for (size_t i = 0; i < r.vertices.size(); ++i) {
    int32_t first = -1;
    for (int64_t e = r.vertex_start[i]; e < r.vertex_start[i + 1] && !in_gap[i]; ++e) {
      for (const int32_t k : r.corners[static_cast<size_t>(r.vertex_tets[static_cast<size_t>(e)].first)]) {
        const int32_t segment = k < 0 ? tets.bone_segment[static_cast<size_t>(-1 - k)] : -1;
        if (segment < 0) continue;
        if (first < 0) first = segment;
        if (segment != first) in_gap[i] = 1;
      }
    }
  }
  for (size_t t = 0; t < r.corners.size(); ++t) {
    if (r.floor[t] == 0.0) continue;
    for (const int32_t k : r.corners[t]) {
      if (k >= 0 && in_gap[static_cast<size_t>(k)]) r.floor[t] = kGapEps;
    }
  }
  find_pieces(tets, r);
  return r;
}

// The energy of the region's tets at positions z (3 per region vertex), its gradient, and each tet's det F. With
// cofactor C = dD/dF and chi' = chi / sqrt(eps^2 + D^2):
//   d/dF |F|^2 / chi^(2/3) = 2 F / chi^(2/3) - 2/3 |F|^2 chi' / chi^(5/3) C
//   d/dF ((D - 1)^2 + (D^2 + 1) / chi) = (2 (D - 1) + 2 D / chi - (D^2 + 1) chi' / chi^2) C
// and the pieces' term, which reaches each tet through its det: d/dF w W_p (J_p - 1)^2 = 2 w (J_p - 1) V s C, with V s
// the rest volume its piece counts from the tet. The held corners' positions are read from x once, here: they do
// not move while the region does.
class Energy {
 public:
  Energy(const PackedTets& tets, const Region& region, const Positions& x, double volume_share, double piece_weight)
      : tets_(tets),
        region_(region),
        theta_(volume_share),
        piece_weight_(piece_weight),
        energy_(region.slots.size()),
        det_(region.slots.size()),
        corner_gradient_(region.slots.size()),
        det_gradient_(piece_weight > 0.0 ? region.slots.size() : 0),
        local_(static_cast<size_t>(x.rows()), -1),
        piece_rest_(static_cast<size_t>(region.pieces), 0.0),
        piece_posed_(static_cast<size_t>(region.pieces), 0.0),
        piece_pull_(static_cast<size_t>(region.pieces), 0.0) {
    for (size_t i = 0; i < region.vertices.size(); ++i)
      local_[static_cast<size_t>(region.vertices[i])] = static_cast<int32_t>(i);
    for (size_t t = 0; t < region.slots.size(); ++t) {
      if (region.tet_piece[t] >= 0) piece_rest_[static_cast<size_t>(region.tet_piece[t])] += region.piece_volume[t];
    }
    // Each tet's data side by side, with what its held corners add to F (they do not move while the region does).
    packed_.resize(region.slots.size());
    for (size_t t = 0; t < region.slots.size(); ++t) {
      const auto slot = static_cast<size_t>(region.slots[t]);
      PackedTet& p = packed_[t];
      p.volume = tets.volume[slot];
      p.floor = region.floor[t];
      Eigen::Matrix3d held = Eigen::Matrix3d::Zero();
      for (int c = 0; c < 4; ++c) {
        const int32_t k = region.corners[t][static_cast<size_t>(c)];
        p.corner[static_cast<size_t>(c)] = k;
        for (int j = 0; j < 3; ++j) p.gradient[c][j] = tets.gradients[slot](j, c);
        if (k < 0) held.noalias() += x.row(-1 - k).transpose() * tets.gradients[slot].col(c).transpose();
      }
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) p.held[i][j] = held(i, j);
    }
  }

  // The contact planes whose energy is added from now on: those of the region's vertices.
  void set_planes(const std::vector<ContactPlane>& planes) {
    planes_.clear();
    for (const ContactPlane& plane : planes) {
      const int32_t i = local_[static_cast<size_t>(plane.vertex)];
      if (i < 0) continue;
      planes_.push_back(plane);
      planes_.back().vertex = i;
    }
  }

  double operator()(const Eigen::VectorXd& z, double eps, Eigen::VectorXd* gradient) {
    const auto count = static_cast<int64_t>(region_.slots.size());
    parallel_for(0, count, 1024, [&](int64_t t0, int64_t t1) {
      for (int64_t t = t0; t < t1; ++t) evaluate(z, eps, t, gradient != nullptr);
    });
    double total = 0.0;
    for (const double e : energy_) total += e;
    if (piece_weight_ > 0.0) total += piece_energy();
    if (gradient) {
      // Each vertex's tets' corner gradients, with their pieces' pull on their dets.
      gradient->resize(z.size());
      const bool pieces = piece_weight_ > 0.0;
      parallel_for(0, static_cast<int64_t>(region_.vertices.size()), 2048, [&](int64_t i0, int64_t i1) {
        for (int64_t i = i0; i < i1; ++i) {
          Eigen::Vector3d g = Eigen::Vector3d::Zero();
          for (int64_t e = region_.vertex_start[static_cast<size_t>(i)];
               e < region_.vertex_start[static_cast<size_t>(i) + 1]; ++e) {
            const auto [t, c] = region_.vertex_tets[static_cast<size_t>(e)];
            g += corner_gradient_[static_cast<size_t>(t)].col(c);
            if (pieces && region_.tet_piece[static_cast<size_t>(t)] >= 0) {
              g += piece_pull_[static_cast<size_t>(region_.tet_piece[static_cast<size_t>(t)])] *
                   region_.piece_volume[static_cast<size_t>(t)] * det_gradient_[static_cast<size_t>(t)].col(c);
            }
          }
          gradient->segment<3>(3 * i) = g;
        }
      });
    }
    for (const ContactPlane& plane : planes_) {
      const double depth = plane.offset - (z.segment<3>(3 * plane.vertex) - plane.point).dot(plane.normal);
      if (depth <= 0.0) continue;
      total += plane.weight * depth * depth;
      if (gradient) gradient->segment<3>(3 * plane.vertex) -= 2.0 * plane.weight * depth * plane.normal;
    }
    return total;
  }

  // The smallest det F at the positions last evaluated of a tet with two or more free corners (infinite when every
  // tet has three held; 1 for an empty region).
  double min_det() const {
    if (det_.empty()) return 1.0;
    double least = std::numeric_limits<double>::infinity();
    for (size_t t = 0; t < det_.size(); ++t) {
      if (region_.floor[t] == 0.0) least = std::min(least, det_[t]);
    }
    return least;
  }

  // The rest volume of the region's tets folded (det F <= 0) at the positions last evaluated.
  double folded_volume() const {
    double folded = 0.0;
    for (size_t t = 0; t < det_.size(); ++t) {
      if (det_[t] <= 0.0) folded += tets_.volume[static_cast<size_t>(region_.slots[t])];
    }
    return folded;
  }

 private:
  // Written on plain arrays: Eigen's fixed-size temporaries here went through the stack, half again slower.
  void evaluate(const Eigen::VectorXd& z, double eps, int64_t t, bool with_gradient) {
    const PackedTet& p = packed_[static_cast<size_t>(t)];
    double f[3][3];  // f[i][j] = F(i, j) = sum_c x_c(i) g_c(j)
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) f[i][j] = p.held[i][j];
    for (int c = 0; c < 4; ++c) {
      const int32_t k = p.corner[static_cast<size_t>(c)];
      if (k < 0) continue;
      const double* x = z.data() + 3 * static_cast<Eigen::Index>(k);
      for (int i = 0; i < 3; ++i)
        for (int j = 0; j < 3; ++j) f[i][j] += x[i] * p.gradient[c][j];
    }
    // The cofactor dD/dF: column j is the cross product of F's other two columns.
    double m[3][3];
    for (int j = 0; j < 3; ++j) {
      const int a = (j + 1) % 3, b = (j + 2) % 3;
      m[0][j] = f[1][a] * f[2][b] - f[2][a] * f[1][b];
      m[1][j] = f[2][a] * f[0][b] - f[0][a] * f[2][b];
      m[2][j] = f[0][a] * f[1][b] - f[1][a] * f[0][b];
    }
    const double d = f[0][0] * m[0][0] + f[1][0] * m[1][0] + f[2][0] * m[2][0];
    const double e = std::max(eps, p.floor);
    const double root = std::sqrt(e * e + d * d);
    const double c = chi_of(d, e, root);
    const double c_prime = c / root;  // d chi / d D
    double trace = 0.0;
    for (int i = 0; i < 3; ++i)
      for (int j = 0; j < 3; ++j) trace += f[i][j] * f[i][j];
    const double c23 = cube_root(c * c);
    const double volume = p.volume;
    det_[static_cast<size_t>(t)] = d;
    energy_[static_cast<size_t>(t)] =
        volume * ((1.0 - theta_) * trace / c23 + theta_ * ((d - 1.0) * (d - 1.0) + (d * d + 1.0) / c));
    if (!with_gradient) return;
    // dE/dF = a F + b cofactor; corner c's gradient is dE/dF g_c.
    const double a = volume * (1.0 - theta_) * 2.0 / c23;
    const double b = volume * (-(1.0 - theta_) * (2.0 / 3.0) * trace / (c23 * c) * c_prime +
                               theta_ * (2.0 * (d - 1.0) + 2.0 * d / c - (d * d + 1.0) * c_prime / (c * c)));
    Eigen::Matrix<double, 3, 4>& out = corner_gradient_[static_cast<size_t>(t)];
    for (int k = 0; k < 4; ++k) {
      const double* g = p.gradient[k];
      for (int i = 0; i < 3; ++i) {
        const double fg = f[i][0] * g[0] + f[i][1] * g[1] + f[i][2] * g[2];
        const double mg = m[i][0] * g[0] + m[i][1] * g[1] + m[i][2] * g[2];
        out(i, k) = a * fg + b * mg;
        if (piece_weight_ > 0.0) det_gradient_[static_cast<size_t>(t)](i, k) = mg;
      }
    }
  }

  // The pieces' term, piece_weight sum_p W_p (J_p - 1)^2, from the dets last evaluated; each piece's pull on a det,
  // 2 w (J_p - 1) (times the rest volume its piece counts from the tet, V s, in the gradient's gather).
  double piece_energy() {
    std::fill(piece_posed_.begin(), piece_posed_.end(), 0.0);
    for (size_t t = 0; t < region_.slots.size(); ++t) {
      if (region_.tet_piece[t] >= 0) {
        piece_posed_[static_cast<size_t>(region_.tet_piece[t])] += region_.piece_volume[t] * det_[t];
      }
    }
    double total = 0.0;
    for (size_t p = 0; p < piece_rest_.size(); ++p) {
      const double change = piece_rest_[p] > 0.0 ? piece_posed_[p] / piece_rest_[p] - 1.0 : 0.0;
      total += piece_weight_ * piece_rest_[p] * change * change;
      piece_pull_[p] = 2.0 * piece_weight_ * change;
    }
    return total;
  }

  // A region tet's gradient rows, rest volume, corners (region vertex, or < 0 when held), its held corners' part of F
  // and the floor under its regulariser.
  struct PackedTet {
    double gradient[4][3];  // per corner c, g_c
    double held[3][3];      // F(i, j) from the held corners
    double volume = 0.0;
    std::array<int32_t, 4> corner{};
    double floor = 0.0;
  };

  const PackedTets& tets_;
  const Region& region_;
  std::vector<PackedTet> packed_;
  double theta_, piece_weight_;
  std::vector<double> energy_, det_;
  std::vector<Eigen::Matrix<double, 3, 4>> corner_gradient_;
  std::vector<Eigen::Matrix<double, 3, 4>> det_gradient_;  // per region tet, with the pieces' term: dD/dx per corner
  std::vector<int32_t> local_;        // solve vertex -> region vertex, -1 when held
  std::vector<double> piece_rest_, piece_posed_, piece_pull_;  // per piece: W_p, its posed volume, 2 w (J_p - 1)
  std::vector<ContactPlane> planes_;  // vertex: region number
};

// L-BFGS (Nocedal and Wright, algorithm 7.4) with a backtracking Armijo line search, at most `iterations` steps at
// this eps: the energy where it started and where it ended, and the steps taken.
struct Minimised {
  double first = 0.0, last = 0.0;
  int steps = 0;
};

Minimised minimise(Energy& energy, Eigen::VectorXd& z, double eps, int iterations) {
  constexpr int kMemory = 8;
  std::deque<Eigen::VectorXd> s_list, y_list;
  std::deque<double> rho_list;
  Eigen::VectorXd g;
  double value = energy(z, eps, &g);
  const double first = value;
  int steps = 0;
  for (; steps < iterations; ++steps) {
    Eigen::VectorXd q = -g;
    std::vector<double> alpha(s_list.size());
    for (int i = static_cast<int>(s_list.size()) - 1; i >= 0; --i) {
      alpha[static_cast<size_t>(i)] = rho_list[static_cast<size_t>(i)] * s_list[static_cast<size_t>(i)].dot(q);
      q -= alpha[static_cast<size_t>(i)] * y_list[static_cast<size_t>(i)];
    }
    if (!s_list.empty()) {
      q *= s_list.back().dot(y_list.back()) / y_list.back().squaredNorm();
    } else {
      q *= 1.0 / std::max(1.0, g.lpNorm<Eigen::Infinity>());  // a first step of at most 1 mm
    }
    for (size_t i = 0; i < s_list.size(); ++i) {
      const double beta = rho_list[i] * y_list[i].dot(q);
      q += (alpha[i] - beta) * s_list[i];
    }
    double slope = g.dot(q);
    if (slope >= 0.0) {  // not a descent direction: forget the history and go down the gradient
      s_list.clear(), y_list.clear(), rho_list.clear();
      q = -g / std::max(1.0, g.lpNorm<Eigen::Infinity>());
      slope = g.dot(q);
    }
    double step = 1.0;
    Eigen::VectorXd trial, trial_g;
    double trial_value = value;
    bool accepted = false;
    for (int k = 0; k < 30; ++k, step *= 0.5) {
      trial = z + step * q;
      trial_value = energy(trial, eps, &trial_g);
      if (std::isfinite(trial_value) && trial_value <= value + 1e-4 * step * slope) {
        accepted = true;
        break;
      }
    }
    if (!accepted) break;
    Eigen::VectorXd s = trial - z, y = trial_g - g;
    const double sy = s.dot(y);
    if (sy > 1e-12 * s.norm() * y.norm()) {
      s_list.push_back(std::move(s)), y_list.push_back(std::move(y)), rho_list.push_back(1.0 / sy);
      if (static_cast<int>(s_list.size()) > kMemory) s_list.pop_front(), y_list.pop_front(), rho_list.pop_front();
    }
    const double change = value - trial_value;
    z = std::move(trial), g = std::move(trial_g), value = trial_value;
    if (change <= 1e-9 * std::abs(value)) {
      ++steps;
      break;
    }
  }
  return {first, value, steps};
}

double det_of(const PackedTets& tets, const Positions& x, size_t slot) {
  Eigen::Matrix<double, 3, 4> corner;
  for (int c = 0; c < 4; ++c) corner.col(c) = x.row(tets.corners[slot][static_cast<size_t>(c)]).transpose();
  return (corner * tets.gradients[slot].transpose()).determinant();
}

// The solve's inverted tets with a free corner: how many, their rest volume, and their free corners.
struct Folds {
  int64_t inverted = 0;
  double volume = 0.0;
  std::vector<int32_t> free_corners;
};

Folds folds(const PackedTets& tets, Eigen::Index free_count, const Positions& x) {
  Folds f;
  for (size_t s = 0; s < tets.corners.size(); ++s) {
    if (det_of(tets, x, s) > 0.0) continue;
    const size_t before = f.free_corners.size();
    for (const int32_t v : tets.corners[s]) {
      if (v < free_count) f.free_corners.push_back(v);
    }
    if (f.free_corners.size() == before) continue;
    ++f.inverted;
    f.volume += tets.volume[s];
  }
  return f;
}

}  // namespace

Result<UntangleStats> untangle(const PackedTets& tets, Eigen::Index free_count, Positions& x,
                               const UntangleParams& params, const ContactLookUp& contact_planes,
                               const std::function<Status()>& cancel) {
  const Stopwatch clock;
  UntangleStats st;
  const Folds start = folds(tets, free_count, x);
  st.inverted_before = st.inverted_after = start.inverted;
  if (start.inverted == 0) {
    st.seconds = clock.seconds();
    return st;
  }
  const Region region = grow_region(tets, free_count, start.free_corners, params.rings);
  st.vertices = static_cast<int64_t>(region.vertices.size());
  Eigen::VectorXd z(3 * static_cast<Eigen::Index>(region.vertices.size()));
  for (size_t i = 0; i < region.vertices.size(); ++i) {
    z.segment<3>(3 * static_cast<Eigen::Index>(i)) = x.row(region.vertices[i]).transpose();
  }

  Energy energy(tets, region, x, params.volume_share, params.piece_volume_weight);
  energy(z, 1.0, nullptr);
  double min_det = energy.min_det();
  // The positions that folded the least tissue so far (the start's, to begin with): a round may fold more than it
  // turns back while eps is large, and the last round is not always the best.
  Eigen::VectorXd best = z;
  double best_folded = energy.folded_volume();
  const double start_folded = best_folded;
  // eps such that the worst tet's regularised det is mu; each round lowers mu by how much the last round's
  // minimisation lowered the energy (at least kLeastCut), so eps shrinks as fast as the tets follow.
  auto eps_for = [](double mu, double d) { return d < mu ? 2.0 * std::sqrt(mu * (mu - d)) : kPureBarrier; };
  double eps = eps_for(kFirstMu, min_det);
  double best_det = min_det;
  int stalled = 0;
  while (st.iterations < params.max_iterations) {
    if (contact_planes) {  // the skin the region's moves have brought into tissue from elsewhere, looked up again
      for (size_t i = 0; i < region.vertices.size(); ++i) {
        x.row(region.vertices[i]) = z.segment<3>(3 * static_cast<Eigen::Index>(i)).transpose();
      }
      energy.set_planes(contact_planes(x));
    }
    const Minimised round = minimise(energy, z, eps, std::min(kInner, params.max_iterations - st.iterations));
    st.iterations += round.steps;
    energy(z, eps, nullptr);  // the figures of z itself (the line search's last trial may have been refused)
    min_det = energy.min_det();
    if (const double folded = energy.folded_volume(); folded <= best_folded) best = z, best_folded = folded;
    POSEWARP_RETURN_IF_ERROR(cancel());
    const double cut = 1.0 - round.last / round.first;
    if (min_det > 0.0 && eps <= kPureBarrier && cut < 1e-4) break;  // foldover-free and settled
    // A tet the others pin flat approaches det 0 from below without crossing; one pinned inverted stops improving.
    // Either way what is left inverted stays, and further rounds only cost time.
    if (eps < kFlatEps) break;
    stalled = min_det > best_det + kProgress ? 0 : stalled + 1;
    best_det = std::max(best_det, min_det);
    if (stalled >= kStalledRounds) break;
    eps = eps_for((1.0 - std::max(cut, kLeastCut)) * chi(min_det, eps), min_det);
  }
  st.undone = best_folded >= start_folded;
  for (size_t i = 0; i < region.vertices.size(); ++i) {
    x.row(region.vertices[i]) = best.segment<3>(3 * static_cast<Eigen::Index>(i)).transpose();
  }
  st.inverted_after = folds(tets, free_count, x).inverted;
  st.seconds = clock.seconds();
  return st;
}

}  // namespace posewarp::fem::internal
