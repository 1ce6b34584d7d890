// Skin that a pose drove into tissue or bone: the mesh's skin vertices and the posed tets each lies in (see
// soft_tissue.h).
#include <Eigen/Dense>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <functional>
#include <limits>
#include <memory>
#include <mutex>
#include <optional>
#include <unordered_map>
#include <vector>

#include "internal.h"
#include "posewarp/common/parallel.h"
#include "posewarp/fem/soft_tissue.h"

namespace posewarp::fem {
namespace internal {

std::optional<Eigen::Vector4d> barycentric(const std::array<Eigen::Vector3d, 4>& x, const Eigen::Vector3d& p) {
  Eigen::Matrix3d edges;
  for (int c = 1; c < 4; ++c) edges.col(c - 1) = x[static_cast<size_t>(c)] - x[0];
  if (std::abs(edges.determinant()) < 1e-12) return std::nullopt;
  const Eigen::Vector3d b = edges.inverse() * (p - x[0]);
  return Eigen::Vector4d(1.0 - b.sum(), b.x(), b.y(), b.z());
}

DenseCells::DenseCells(const std::vector<Eigen::Vector3d>& points, double cell_mm) : cells_of_{cell_mm} {
  Eigen::Array3i lo = Eigen::Array3i::Constant(std::numeric_limits<int>::max()), hi = -lo;
  for (const Eigen::Vector3d& p : points) {
    if (!cells_of_.hold(p)) continue;
    lo = lo.min(cells_of_.of(p));
    hi = hi.max(cells_of_.of(p));
  }
  if ((lo > hi).any()) return;
  size_ = hi - lo + 1;
  if ((size_.cast<double>().prod()) > double{kMostDenseCells}) return;
  first_ = lo;
  start_.assign(static_cast<size_t>(size_.prod()) + 1, 0);
  for (const Eigen::Vector3d& p : points) {
    if (cells_of_.hold(p)) ++start_[index(cells_of_.of(p)) + 1];
  }
  for (size_t c = 1; c < start_.size(); ++c) start_[c] += start_[c - 1];
  items_.resize(static_cast<size_t>(start_.back()));
  std::vector<int32_t> next(start_.begin(), start_.end() - 1);
  for (size_t i = 0; i < points.size(); ++i) {
    if (cells_of_.hold(points[i])) {
      items_[static_cast<size_t>(next[index(cells_of_.of(points[i]))]++)] = static_cast<int32_t>(i);
    }
  }
}

}  // namespace internal

namespace {

// The solid angle at corner a of a tet whose other corners are b, c, d (Van Oosterom and Strackee 1983).
double solid_angle(const Eigen::Vector3d& a, const Eigen::Vector3d& b, const Eigen::Vector3d& c, const Eigen::Vector3d& d) {
  const Eigen::Vector3d u = b - a, v = c - a, w = d - a;
  const double lu = u.norm(), lv = v.norm(), lw = w.norm();
  const double numerator = std::abs(u.dot(v.cross(w)));
  const double denominator = lu * lv * lw + u.dot(v) * lw + u.dot(w) * lv + v.dot(w) * lu;
  return 2.0 * std::atan2(numerator, denominator);
}

}  // namespace

std::vector<uint8_t> skin_vertices(const TetMesh& rest) {
  const int64_t n = rest.vertex_count();
  // A vertex inside the mesh is surrounded by its tets (their solid angles add up to 4 pi); one on the boundary is
  // not. Summed per thread over its share of the tets, then added up.
  const int threads = std::max(1, static_cast<int>(std::min<int64_t>(thread_count(), rest.tet_count() / 65536 + 1)));
  std::vector<std::vector<double>> angle(static_cast<size_t>(threads), std::vector<double>(static_cast<size_t>(n), 0.0));
  parallel_for(0, threads, 1, [&](int64_t k0, int64_t k1) {
    for (int64_t k = k0; k < k1; ++k) {
      std::vector<double>& sum = angle[static_cast<size_t>(k)];
      for (int64_t t = k; t < rest.tet_count(); t += threads) {
        Eigen::Vector3d x[4];
        for (int c = 0; c < 4; ++c) x[c] = rest.vertices.row(rest.tets(t, c)).transpose();
        for (int c = 0; c < 4; ++c) {
          sum[static_cast<size_t>(rest.tets(t, c))] += solid_angle(x[c], x[(c + 1) % 4], x[(c + 2) % 4], x[(c + 3) % 4]);
        }
      }
    }
  });
  std::vector<uint8_t> bone(static_cast<size_t>(n), 0);
  if (rest.tet_class.size() == rest.tet_count()) {
    for (int64_t t = 0; t < rest.tet_count(); ++t) {
      if (rest.tet_class(t) >= kFirstBoneClass) {
        for (int c = 0; c < 4; ++c) bone[static_cast<size_t>(rest.tets(t, c))] = 1;
      }
    }
  }
  constexpr double kFullSphere = 4.0 * M_PI;
  std::vector<double> total(static_cast<size_t>(n), 0.0);
  for (int64_t v = 0; v < n; ++v) {
    for (const std::vector<double>& sum : angle) total[static_cast<size_t>(v)] += sum[static_cast<size_t>(v)];
  }
  // The vertices a joint's gap cut (cut_joint_gaps) lie at one rest position: together their tets surround it.
  struct PositionHash {
    size_t operator()(const std::array<double, 3>& p) const {
      return std::hash<double>()(p[0]) ^ (std::hash<double>()(p[1]) * 31) ^ (std::hash<double>()(p[2]) * 131);
    }
  };
  std::unordered_map<std::array<double, 3>, double, PositionHash> at_position;
  auto position = [&](int64_t v) {
    return std::array<double, 3>{rest.vertices(v, 0), rest.vertices(v, 1), rest.vertices(v, 2)};
  };
  auto open = [&](double angle_sum) { return angle_sum > 0.0 && angle_sum < kFullSphere - 1e-6; };
  for (int64_t v = 0; v < n; ++v) {
    if (open(total[static_cast<size_t>(v)])) at_position[position(v)] += total[static_cast<size_t>(v)];
  }
  std::vector<uint8_t> skin(static_cast<size_t>(n), 0);
  for (int64_t v = 0; v < n; ++v) {
    skin[static_cast<size_t>(v)] =
        open(total[static_cast<size_t>(v)]) && open(at_position[position(v)]) && !bone[static_cast<size_t>(v)];
  }
  return skin;
}

namespace {

constexpr double kCellMm = 10.0;  // the skin points' cells

// One centre's skin points (within the largest radius at rest), posed, in cells, with what each was found inside.
struct NearCentre {
  std::vector<int32_t> points;
  std::vector<Eigen::Vector3d> posed;
  std::optional<internal::DenseCells> dense;
  internal::CellGrid grid{kCellMm};              // only where the points spread too far for the dense cells
  Eigen::Vector3d lo, hi;                        // the posed points' box
  std::unique_ptr<std::atomic<uint8_t>[]> what;  // 0 nothing, 1 tissue, 2 bone
};

// Which centres (those with points) each rest vertex is within `reach` of, a bit per centre, 8 to a byte, `groups`
// bytes a vertex: one pass down the vertices, so that the tets' pass reads a byte or two per tet instead of its first
// vertex's three scattered columns, and skips a tet near no centre at once.
std::vector<uint8_t> centres_within_reach(const TetMesh& rest, const std::vector<Eigen::Vector3d>& centres,
                                          const std::vector<NearCentre>& near, double reach, size_t groups) {
  std::vector<uint8_t> within(static_cast<size_t>(rest.vertex_count()) * groups, 0);
  parallel_for(0, rest.vertex_count(), 16384, [&](int64_t v0, int64_t v1) {
    for (int64_t v = v0; v < v1; ++v) {
      const Eigen::Vector3d x = rest.vertices.row(v).transpose();
      for (size_t j = 0; j < centres.size(); ++j) {
        if (!near[j].points.empty() && (x - centres[j]).squaredNorm() <= reach * reach)
          within[static_cast<size_t>(v) * groups + j / 8] |= static_cast<uint8_t>(1u << (j % 8));
      }
    }
  });
  return within;
}

// The posed vertices a row each (the matrix keeps x, y and z apart: three scattered lines per corner otherwise).
std::vector<Eigen::Vector3d> rows_of(const Eigen::MatrixXd& posed) {
  std::vector<Eigen::Vector3d> rows(static_cast<size_t>(posed.rows()));
  parallel_for(0, posed.rows(), 16384, [&](int64_t v0, int64_t v1) {
    for (int64_t v = v0; v < v1; ++v) rows[static_cast<size_t>(v)] = posed.row(v).transpose();
  });
  return rows;
}

}  // namespace

std::vector<std::vector<Penetration>> penetration(const TetMesh& rest, const Eigen::MatrixXd& posed,
                                                  const std::vector<uint8_t>& skin,
                                                  const std::vector<Eigen::Vector3d>& centres,
                                                  const std::vector<double>& radii_mm, double rest_distance_mm) {
  std::vector<std::vector<Penetration>> result(centres.size(), std::vector<Penetration>(radii_mm.size()));
  if (radii_mm.empty() || posed.rows() != rest.vertex_count() || posed.cols() != 3 ||
      static_cast<int64_t>(skin.size()) != rest.vertex_count() || rest.tet_class.size() != rest.tet_count()) {
    return result;
  }
  const double radius = *std::max_element(radii_mm.begin(), radii_mm.end());
  std::vector<NearCentre> near(centres.size());
  bool any = false;
  for (size_t j = 0; j < centres.size(); ++j) {
    NearCentre& n = near[j];
    for (int64_t v = 0; v < rest.vertex_count(); ++v) {
      if (skin[static_cast<size_t>(v)] &&
          (rest.vertices.row(v).transpose() - centres[j]).squaredNorm() <= radius * radius) {
        n.points.push_back(static_cast<int32_t>(v));
      }
    }
    if (n.points.empty()) continue;
    any = true;
    for (const int32_t v : n.points) n.posed.push_back(posed.row(v).transpose());
    n.dense.emplace(n.posed, kCellMm);
    if (n.dense->empty()) {
      for (size_t i = 0; i < n.posed.size(); ++i) n.grid.insert(static_cast<int32_t>(i), n.posed[i], n.posed[i]);
    }
    n.lo = n.hi = n.posed[0];
    for (const Eigen::Vector3d& x : n.posed) n.lo = n.lo.cwiseMin(x), n.hi = n.hi.cwiseMax(x);
    n.what.reset(new std::atomic<uint8_t>[n.points.size()]);
    for (size_t i = 0; i < n.points.size(); ++i) n.what[i].store(0, std::memory_order_relaxed);
  }
  if (!any) return result;
  // Every tet that could be "elsewhere" for a centre's points and near them posed: within the radius, the contact
  // distance and a tet's length (kTetReach) of the centre at rest; each posed tet's box looks up the points it may
  // hold. One pass over the tets for every centre: a tet's box and corners are worked out once.
  constexpr double kTetReach = 100.0;
  const double reach = radius + rest_distance_mm + kTetReach;
  const size_t groups = (centres.size() + 7) / 8;
  const std::vector<uint8_t> within = centres_within_reach(rest, centres, near, reach, groups);
  const std::vector<Eigen::Vector3d> posed_rows = rows_of(posed);
  parallel_for(0, rest.tet_count(), 4096, [&](int64_t t0, int64_t t1) {
    for (int64_t t = t0; t < t1; ++t) {
      const uint8_t* first_within = within.data() + static_cast<size_t>(rest.tets(t, 0)) * groups;
      bool boxed = false;
      Eigen::Vector3d lo, hi;
      std::array<Eigen::Vector3d, 4> corners;
      for (size_t j = 0; j < near.size(); ++j) {
        if (j % 8 == 0 && first_within[j / 8] == 0) {  // near none of these eight
          j += 7;
          continue;
        }
        if (!(first_within[j / 8] >> (j % 8) & 1)) continue;
        NearCentre& n = near[j];
        if (!boxed) {
          for (int c = 0; c < 4; ++c)
            corners[static_cast<size_t>(c)] = posed_rows[static_cast<size_t>(rest.tets(t, c))];
          lo = hi = corners[0];
          for (int c = 1; c < 4; ++c) {
            lo = lo.cwiseMin(corners[static_cast<size_t>(c)]);
            hi = hi.cwiseMax(corners[static_cast<size_t>(c)]);
          }
          boxed = true;
        }
        if ((hi.array() < n.lo.array()).any() || (lo.array() > n.hi.array()).any()) continue;
        const uint8_t kind = rest.tet_class(t) >= kFirstBoneClass ? 2 : 1;
        auto visit = [&](int32_t i) {
          std::atomic<uint8_t>& what = n.what[static_cast<size_t>(i)];
          if (what.load(std::memory_order_relaxed) >= kind) return;
          // Outside the posed tet's box, a point is outside the tet by more than barycentric's rounding: not inside.
          const Eigen::Vector3d& at = n.posed[static_cast<size_t>(i)];
          if ((at.array() < lo.array()).any() || (at.array() > hi.array()).any()) return;
          const Eigen::Vector3d x = rest.vertices.row(n.points[static_cast<size_t>(i)]).transpose();
          for (int c = 0; c < 4; ++c) {
            if ((rest.vertices.row(rest.tets(t, c)).transpose() - x).squaredNorm() <
                rest_distance_mm * rest_distance_mm) {
              return;
            }
          }
          const std::optional<Eigen::Vector4d> b = internal::barycentric(corners, at);
          constexpr double kInside = 1e-9;
          if (!b || b->minCoeff() <= kInside) return;
          uint8_t seen = what.load(std::memory_order_relaxed);
          while (seen < kind && !what.compare_exchange_weak(seen, kind)) {
          }
        };
        if (n.dense->empty()) {
          n.grid.in_box(lo, hi, visit);
        } else {
          n.dense->in_box(lo, hi, visit);
        }
      }
    }
  });
  for (size_t j = 0; j < near.size(); ++j) {
    const NearCentre& n = near[j];
    for (size_t i = 0; i < n.points.size(); ++i) {
      const double d = (rest.vertices.row(n.points[i]).transpose() - centres[j]).norm();
      const uint8_t w = n.what[i].load(std::memory_order_relaxed);
      for (size_t r = 0; r < radii_mm.size(); ++r) {
        if (d > radii_mm[r]) continue;
        ++result[j][r].skin_vertices;
        result[j][r].inside_tissue += w == 1;
        result[j][r].inside_bone += w == 2;
      }
    }
  }
  return result;
}

std::vector<Penetration> penetration(const TetMesh& rest, const Eigen::MatrixXd& posed,
                                     const std::vector<uint8_t>& skin, const Eigen::Vector3d& centre,
                                     const std::vector<double>& radii_mm, double rest_distance_mm) {
  return penetration(rest, posed, skin, std::vector<Eigen::Vector3d>{centre}, radii_mm, rest_distance_mm).front();
}

}  // namespace posewarp::fem
