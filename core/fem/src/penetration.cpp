// Skin that a pose drove into tissue or bone: the mesh's skin vertices and the posed tets each lies in (see
// soft_tissue.h).
#include <Eigen/Dense>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <functional>
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

std::vector<Penetration> penetration(const TetMesh& rest, const Eigen::MatrixXd& posed, const std::vector<uint8_t>& skin,
                                     const Eigen::Vector3d& centre, const std::vector<double>& radii_mm,
                                     double rest_distance_mm) {
  std::vector<Penetration> result(radii_mm.size());
  if (radii_mm.empty() || posed.rows() != rest.vertex_count() || posed.cols() != 3 ||
      static_cast<int64_t>(skin.size()) != rest.vertex_count() || rest.tet_class.size() != rest.tet_count()) {
    return result;
  }
  const double radius = *std::max_element(radii_mm.begin(), radii_mm.end());
  std::vector<int32_t> points;  // skin vertices within the radius at rest
  for (int64_t v = 0; v < rest.vertex_count(); ++v) {
    if (skin[static_cast<size_t>(v)] && (rest.vertices.row(v).transpose() - centre).squaredNorm() <= radius * radius) {
      points.push_back(static_cast<int32_t>(v));
    }
  }
  if (points.empty()) return result;
  // Every tet that could be "elsewhere" for them and near them posed: within the radius, the contact distance and
  // a tet's length (kTetReach) of the centre at rest; each posed tet's box looks up the points it may hold.
  constexpr double kTetReach = 100.0;
  const double reach = radius + rest_distance_mm + kTetReach;
  internal::CellGrid grid(10.0);
  for (size_t i = 0; i < points.size(); ++i) {
    const Eigen::Vector3d p = posed.row(points[i]).transpose();
    grid.insert(static_cast<int32_t>(i), p, p);
  }
  Eigen::Vector3d points_lo = posed.row(points[0]).transpose(), points_hi = points_lo;
  for (const int32_t v : points) {
    points_lo = points_lo.cwiseMin(posed.row(v).transpose());
    points_hi = points_hi.cwiseMax(posed.row(v).transpose());
  }
  std::vector<std::atomic<uint8_t>> what(points.size());
  for (std::atomic<uint8_t>& w : what) w.store(0, std::memory_order_relaxed);
  parallel_for(0, rest.tet_count(), 4096, [&](int64_t t0, int64_t t1) {
    for (int64_t t = t0; t < t1; ++t) {
      if ((rest.vertices.row(rest.tets(t, 0)).transpose() - centre).squaredNorm() > reach * reach) continue;
      Eigen::Vector3d lo = posed.row(rest.tets(t, 0)).transpose(), hi = lo;
      for (int c = 1; c < 4; ++c) {
        lo = lo.cwiseMin(posed.row(rest.tets(t, c)).transpose());
        hi = hi.cwiseMax(posed.row(rest.tets(t, c)).transpose());
      }
      if ((hi.array() < points_lo.array()).any() || (lo.array() > points_hi.array()).any()) continue;
      const uint8_t kind = rest.tet_class(t) >= kFirstBoneClass ? 2 : 1;
      std::array<Eigen::Vector3d, 4> corners;
      for (int c = 0; c < 4; ++c) corners[static_cast<size_t>(c)] = posed.row(rest.tets(t, c)).transpose();
      grid.in_box(lo, hi, [&](int32_t i) {
        const int32_t v = points[static_cast<size_t>(i)];
        if (what[static_cast<size_t>(i)].load(std::memory_order_relaxed) >= kind) return;
        const Eigen::Vector3d x = rest.vertices.row(v).transpose();
        for (int c = 0; c < 4; ++c) {
          if ((rest.vertices.row(rest.tets(t, c)).transpose() - x).squaredNorm() < rest_distance_mm * rest_distance_mm) return;
        }
        const std::optional<Eigen::Vector4d> b = internal::barycentric(corners, posed.row(v).transpose());
        constexpr double kInside = 1e-9;
        if (!b || b->minCoeff() <= kInside) return;
        uint8_t seen = what[static_cast<size_t>(i)].load(std::memory_order_relaxed);
        while (seen < kind && !what[static_cast<size_t>(i)].compare_exchange_weak(seen, kind)) {
        }
      });
    }
  });
  for (size_t i = 0; i < points.size(); ++i) {
    const double d = (rest.vertices.row(points[i]).transpose() - centre).norm();
    const uint8_t w = what[i].load(std::memory_order_relaxed);
    for (size_t r = 0; r < radii_mm.size(); ++r) {
      if (d > radii_mm[r]) continue;
      ++result[r].skin_vertices;
      result[r].inside_tissue += w == 1;
      result[r].inside_bone += w == 2;
    }
  }
  return result;
}

}  // namespace posewarp::fem
