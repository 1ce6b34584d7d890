// Skin pressed against the skin facing it in the projective solve (see internal.h).
#include <Eigen/Dense>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <limits>
#include <optional>
#include <vector>

#include "internal.h"
#include "posewarp/common/parallel.h"
#include "posewarp/common/stopwatch.h"

namespace posewarp::fem::internal {
namespace {

// How far a contact vertex may come to tissue from elsewhere between the warm start and the solve's end: tets and
// faces farther than this from every contact vertex at the warm start are not looked at.
constexpr double kReachMm = 30.0;
// Where a pushed vertex is put: this far outside the plane of the face it is paired with.
constexpr double kOutsideMm = 0.2;
// The untangling's planes weigh this many times the vertex's tets' stiffness (the diagonal of the solve's matrix):
// at 1 the turned-back folds pushed skin back in, at 4 they leave it out.
constexpr double kPlaneWeight = 4.0;
// A vertex no longer inside tissue from elsewhere keeps its face while it is within this distance of the face's
// plane (on either side); farther, it has slid past the face or come out, and is let go.
constexpr double kReleaseMm = 2.0;
// The nearest face from elsewhere is looked for within these half-widths in turn.
constexpr std::array<double, 3> kSearchMm{10.0, 20.0, 40.0};

// The point of triangle abc nearest to p (Ericson, Real-Time Collision Detection 5.1.5).
Eigen::Vector3d closest_on_triangle(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                                    const Eigen::Vector3d& c) {
  const Eigen::Vector3d ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0.0 && d2 <= 0.0) return a;
  const Eigen::Vector3d bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0.0 && d4 <= d3) return b;
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0.0 && d1 >= 0.0 && d3 <= 0.0) return a + d1 / (d1 - d3) * ab;
  const Eigen::Vector3d cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0.0 && d5 <= d6) return c;
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0.0 && d2 >= 0.0 && d6 <= 0.0) return a + d2 / (d2 - d6) * ac;
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0.0 && (d4 - d3) >= 0.0 && (d5 - d6) >= 0.0) return b + (d4 - d3) / ((d4 - d3) + (d5 - d6)) * (c - b);
  const double denominator = 1.0 / (va + vb + vc);
  return a + ab * (vb * denominator) + ac * (vc * denominator);
}

// Which cells of a dense grid over a box hold a point, grown by a reach: whether a point may be near one of them.
class Occupancy {
 public:
  Occupancy(const std::vector<Eigen::Vector3d>& points, double reach_mm) {
    if (points.empty()) return;
    lo_ = hi_ = points.front();
    for (const Eigen::Vector3d& p : points) {
      if (!p.allFinite()) return;  // nothing is near a warm start that is not finite
      lo_ = lo_.cwiseMin(p);
      hi_ = hi_.cwiseMax(p);
    }
    lo_.array() -= reach_mm;
    hi_.array() += reach_mm;
    constexpr double kMostCellsPerAxis = 4096.0;  // 41 m: a warm start spread wider is not a body
    if ((((hi_ - lo_).array() / kCellMm) > kMostCellsPerAxis).any()) return;
    size_ = ((hi_ - lo_).array() / kCellMm).floor().cast<int>() + 1;
    cells_.assign(static_cast<size_t>(size_.prod()), 0);
    const int grow = static_cast<int>(std::ceil(reach_mm / kCellMm));
    for (const Eigen::Vector3d& p : points) {
      const Eigen::Array3i c = ((p - lo_).array() / kCellMm).floor().cast<int>();
      const Eigen::Array3i a = (c - grow).max(0), b = (c + grow).min(size_ - 1);
      for (int z = a.z(); z <= b.z(); ++z)
        for (int y = a.y(); y <= b.y(); ++y)
          for (int x = a.x(); x <= b.x(); ++x) cells_[index(Eigen::Array3i(x, y, z))] = 1;
    }
  }
  bool near(const Eigen::Vector3d& p) const {
    if (cells_.empty() || !p.allFinite() || (p.array() < lo_.array()).any() || (p.array() > hi_.array()).any()) {
      return false;
    }
    return cells_[index((((p - lo_).array() / kCellMm).floor().cast<int>()).min(size_ - 1))] != 0;
  }

 private:
  static constexpr double kCellMm = 10.0;
  size_t index(const Eigen::Array3i& c) const {
    return static_cast<size_t>((static_cast<int64_t>(c.z()) * size_.y() + c.y()) * size_.x() + c.x());
  }
  Eigen::Vector3d lo_ = Eigen::Vector3d::Zero(), hi_ = Eigen::Vector3d::Zero();
  Eigen::Array3i size_ = Eigen::Array3i::Zero();
  std::vector<uint8_t> cells_;
};

}  // namespace

Contacts::Contacts(const SolveInputs& in, const std::vector<int32_t>& solve_vertices,
                   const std::vector<int32_t>& contact, const std::vector<double>& weight)
    : in_(in),
      local_(static_cast<size_t>(in.rest.vertex_count()), -1),
      contact_(contact),
      weight_(weight),
      face_(contact.size(), -1) {
  const Stopwatch start;
  for (size_t i = 0; i < solve_vertices.size(); ++i)
    local_[static_cast<size_t>(solve_vertices[i])] = static_cast<int32_t>(i);
  for (const int32_t i : contact_) vertex_.push_back(solve_vertices[static_cast<size_t>(i)]);
  std::vector<Eigen::Vector3d> at_warm;
  at_warm.reserve(contact_.size());
  for (const int32_t v : vertex_) at_warm.emplace_back(in.warm.row(v).transpose());
  const Occupancy near(at_warm, kReachMm);
  const TetMesh& mesh = in.rest;
  for (int64_t t = 0; t < mesh.tet_count(); ++t) {
    for (int c = 0; c < 4; ++c) {
      if (near.near(in.warm.row(mesh.tets(t, c)).transpose())) {
        tets_.push_back(static_cast<int32_t>(t));
        break;
      }
    }
  }
  for (size_t f = 0; f < in.topology.skin_faces.size(); ++f) {
    for (const int32_t v : in.topology.skin_faces[f]) {
      if (near.near(in.warm.row(v).transpose())) {
        faces_.push_back(static_cast<int32_t>(f));
        break;
      }
    }
  }
  seconds_ = start.seconds();
}

Eigen::Vector3d Contacts::position(int32_t vertex, const Positions& x) const {
  const int32_t i = local_[static_cast<size_t>(vertex)];
  return i >= 0 ? Eigen::Vector3d(x.row(i).transpose()) : Eigen::Vector3d(in_.warm.row(vertex).transpose());
}

double Contacts::face_distance(size_t k, const Positions& x, Eigen::Vector3d& normal) const {
  const std::array<int32_t, 3>& face = in_.topology.skin_faces[static_cast<size_t>(face_[k])];
  const Eigen::Vector3d a = position(face[0], x);
  normal = (position(face[1], x) - a).cross(position(face[2], x) - a);
  const double length = normal.norm();
  if (!(length > 0.0)) return std::numeric_limits<double>::infinity();  // a collapsed face pushes nothing
  normal /= length;
  return (Eigen::Vector3d(x.row(contact_[k]).transpose()) - a).dot(normal);
}

int64_t Contacts::detect(const Positions& x) {
  const Stopwatch start;
  const TetMesh& mesh = in_.rest;
  const size_t n = contact_.size();
  const auto from_elsewhere = [&](size_t k, int32_t corner) {
    return (mesh.vertices.row(corner) - mesh.vertices.row(vertex_[k])).squaredNorm() >= kElsewhereMm * kElsewhereMm;
  };
  // 1. Which contact vertices lie inside a posed tet from elsewhere: the lowest such tet, so that the result does
  // not depend on the threads.
  CellGrid points(10.0);
  for (size_t k = 0; k < n; ++k) {
    const Eigen::Vector3d p = x.row(contact_[k]).transpose();
    points.insert(static_cast<int32_t>(k), p, p);
  }
  std::vector<std::atomic<int32_t>> inside(n);
  for (std::atomic<int32_t>& t : inside) t.store(std::numeric_limits<int32_t>::max(), std::memory_order_relaxed);
  parallel_for(0, static_cast<int64_t>(tets_.size()), 2048, [&](int64_t s0, int64_t s1) {
    for (int64_t s = s0; s < s1; ++s) {
      const int32_t t = tets_[static_cast<size_t>(s)];
      std::array<Eigen::Vector3d, 4> corner;
      for (int c = 0; c < 4; ++c) corner[static_cast<size_t>(c)] = position(mesh.tets(t, c), x);
      Eigen::Vector3d lo = corner[0], hi = corner[0];
      for (const Eigen::Vector3d& p : corner) {
        lo = lo.cwiseMin(p);
        hi = hi.cwiseMax(p);
      }
      points.in_box(lo, hi, [&](int32_t k) {
        std::atomic<int32_t>& found = inside[static_cast<size_t>(k)];
        int32_t seen = found.load(std::memory_order_relaxed);
        if (seen <= t) return;
        for (int c = 0; c < 4; ++c) {
          if (!from_elsewhere(static_cast<size_t>(k), mesh.tets(t, c))) return;
        }
        const std::optional<Eigen::Vector4d> b =
            barycentric(corner, x.row(contact_[static_cast<size_t>(k)]).transpose());
        constexpr double kInside = 1e-9;
        if (!b || b->minCoeff() <= kInside) return;
        while (seen > t && !found.compare_exchange_weak(seen, t)) {
        }
      });
    }
  });
  // 2. Each vertex inside: the nearest skin face from elsewhere (the lowest of equally near ones). A vertex no longer
  // inside keeps its face while it is within kReleaseMm of the face's plane, so that a push does not let go the
  // moment it works.
  CellGrid faces(10.0);
  for (size_t j = 0; j < faces_.size(); ++j) {
    const std::array<int32_t, 3>& face = in_.topology.skin_faces[static_cast<size_t>(faces_[j])];
    Eigen::Vector3d lo = position(face[0], x), hi = lo;
    for (int c = 1; c < 3; ++c) {
      lo = lo.cwiseMin(position(face[static_cast<size_t>(c)], x));
      hi = hi.cwiseMax(position(face[static_cast<size_t>(c)], x));
    }
    faces.insert(static_cast<int32_t>(j), lo, hi);
  }
  std::vector<int32_t> next(n, -1);
  parallel_for(0, static_cast<int64_t>(n), 64, [&](int64_t k0, int64_t k1) {
    for (auto k = static_cast<size_t>(k0); k < static_cast<size_t>(k1); ++k) {
      if (inside[k].load(std::memory_order_relaxed) == std::numeric_limits<int32_t>::max()) {
        Eigen::Vector3d normal;
        if (face_[k] >= 0 && face_distance(k, x, normal) < kReleaseMm) next[k] = face_[k];
        continue;
      }
      const Eigen::Vector3d p = x.row(contact_[k]).transpose();
      double best = std::numeric_limits<double>::infinity();
      int32_t best_face = -1;
      for (const double half : kSearchMm) {
        faces.in_box(Eigen::Vector3d(p.array() - half), Eigen::Vector3d(p.array() + half), [&](int32_t j) {
          const int32_t f = faces_[static_cast<size_t>(j)];
          const std::array<int32_t, 3>& face = in_.topology.skin_faces[static_cast<size_t>(f)];
          for (const int32_t v : face) {
            if (!from_elsewhere(k, v)) return;
          }
          const double d =
              (p - closest_on_triangle(p, position(face[0], x), position(face[1], x), position(face[2], x)))
                  .squaredNorm();
          if (d < best || (d == best && f < best_face)) {
            best = d;
            best_face = f;
          }
        });
        if (best_face >= 0 && best <= half * half) break;
      }
      next[k] = best_face;
    }
  });
  int64_t added = 0;
  for (size_t k = 0; k < n; ++k) added += next[k] >= 0 && face_[k] < 0;
  changed_ = next != face_;
  face_ = std::move(next);
  seconds_ += start.seconds();
  return added;
}

std::vector<ContactPlane> Contacts::planes(const Positions& x) const {
  std::vector<ContactPlane> result;
  for (size_t k = 0; k < contact_.size(); ++k) {
    Eigen::Vector3d normal;
    if (face_[k] < 0 || !std::isfinite(face_distance(k, x, normal))) continue;
    const Eigen::Vector3d point = position(in_.topology.skin_faces[static_cast<size_t>(face_[k])][0], x);
    result.push_back({contact_[k], point, normal, kOutsideMm, kPlaneWeight * weight_[k]});
  }
  return result;
}

void Contacts::project(Positions& x) const {
  for (size_t k = 0; k < contact_.size(); ++k) {
    if (face_[k] < 0) continue;
    Eigen::Vector3d normal;
    const double distance = face_distance(k, x, normal);
    if (distance < kOutsideMm) x.row(contact_[k]) += (kOutsideMm - distance) * normal.transpose();
  }
}

int64_t Contacts::pressed(const Positions& x) const {
  int64_t count = 0;
  for (size_t k = 0; k < contact_.size(); ++k) {
    Eigen::Vector3d normal;
    count += face_[k] >= 0 && face_distance(k, x, normal) < kOutsideMm + 1e-6;
  }
  return count;
}

}  // namespace posewarp::fem::internal
