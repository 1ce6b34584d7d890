// Uniform-grid spatial hash over tet bounding boxes; ring search for the nearest tet of outside points.
#include "posewarp/mapping/tet_locator.h"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <limits>
#include <new>

#include "posewarp/common/parallel.h"

namespace posewarp::mapping {
namespace {

// Distance from p to triangle abc (Ericson, Real-Time Collision Detection, 5.1.5).
double point_triangle_distance(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                               const Eigen::Vector3d& c) {
  const Eigen::Vector3d ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return (p - a).norm();
  const Eigen::Vector3d bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return (p - b).norm();
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return (p - (a + ab * (d1 / (d1 - d3)))).norm();
  const Eigen::Vector3d cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return (p - c).norm();
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return (p - (a + ac * (d2 / (d2 - d6)))).norm();
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
    return (p - (b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6))))).norm();
  }
  const double denom = 1.0 / (va + vb + vc);
  return (p - (a + ab * (vb * denom) + ac * (vc * denom))).norm();
}

}  // namespace

Result<TetLocator> TetLocator::build(const TetMesh& mesh, double cell_mm) {
  if (mesh.tet_count() == 0) return invalid_argument_error("cannot locate points in an empty tet mesh");
  TetLocator locator;
  locator.mesh_ = &mesh;
  const int64_t nt = mesh.tet_count();
  try {
    Eigen::Vector3d lo = mesh.vertices.colwise().minCoeff().transpose();
    Eigen::Vector3d hi = mesh.vertices.colwise().maxCoeff().transpose();
    if (!(cell_mm > 0.0)) {
      double sum = 0.0;
      for (int64_t t = 0; t < nt; ++t) {
        Eigen::Vector3d tl = mesh.vertices.row(mesh.tets(t, 0)), th = tl;
        for (int c = 1; c < 4; ++c) {
          tl = tl.cwiseMin(mesh.vertices.row(mesh.tets(t, c)).transpose());
          th = th.cwiseMax(mesh.vertices.row(mesh.tets(t, c)).transpose());
        }
        sum += (th - tl).mean();
      }
      cell_mm = std::max(1e-6, sum / static_cast<double>(nt));
    }
    locator.cell_ = cell_mm;
    locator.origin_ = lo;
    for (int a = 0; a < 3; ++a) {
      locator.dims_[a] = std::max<int64_t>(1, static_cast<int64_t>(std::floor((hi(a) - lo(a)) / cell_mm)) + 1);
    }
    if (locator.dims_[0] * locator.dims_[1] * locator.dims_[2] > int64_t{1} << 28) {
      return resource_exhausted_error("the tet locator grid would be too large; use a larger cell");
    }
    const int64_t cells = locator.dims_[0] * locator.dims_[1] * locator.dims_[2];
    auto cell_range = [&](int64_t t, int64_t first[3], int64_t last[3]) {
      Eigen::Vector3d tl = mesh.vertices.row(mesh.tets(t, 0)), th = tl;
      for (int c = 1; c < 4; ++c) {
        tl = tl.cwiseMin(mesh.vertices.row(mesh.tets(t, c)).transpose());
        th = th.cwiseMax(mesh.vertices.row(mesh.tets(t, c)).transpose());
      }
      for (int a = 0; a < 3; ++a) {
        first[a] = std::clamp<int64_t>(static_cast<int64_t>(std::floor((tl(a) - lo(a)) / cell_mm)), 0, locator.dims_[a] - 1);
        last[a] = std::clamp<int64_t>(static_cast<int64_t>(std::floor((th(a) - lo(a)) / cell_mm)), 0, locator.dims_[a] - 1);
      }
    };
    std::vector<int64_t> count(static_cast<size_t>(cells) + 1, 0);
    for (int64_t t = 0; t < nt; ++t) {
      int64_t f[3], l[3];
      cell_range(t, f, l);
      for (int64_t z = f[2]; z <= l[2]; ++z)
        for (int64_t y = f[1]; y <= l[1]; ++y)
          for (int64_t x = f[0]; x <= l[0]; ++x) ++count[static_cast<size_t>(locator.cell_of(x, y, z)) + 1];
    }
    for (int64_t c = 0; c < cells; ++c) count[static_cast<size_t>(c) + 1] += count[static_cast<size_t>(c)];
    locator.start_ = count;
    locator.tets_.resize(static_cast<size_t>(count.back()));
    std::vector<int64_t> fill(count.begin(), count.end() - 1);
    for (int64_t t = 0; t < nt; ++t) {
      int64_t f[3], l[3];
      cell_range(t, f, l);
      for (int64_t z = f[2]; z <= l[2]; ++z)
        for (int64_t y = f[1]; y <= l[1]; ++y)
          for (int64_t x = f[0]; x <= l[0]; ++x)
            locator.tets_[static_cast<size_t>(fill[static_cast<size_t>(locator.cell_of(x, y, z))]++)] = static_cast<int32_t>(t);
    }
    locator.inverse_.assign(static_cast<size_t>(nt) * 9, 0.0);
    for (int64_t t = 0; t < nt; ++t) {
      Eigen::Matrix3d e;
      const Eigen::Vector3d v0 = mesh.vertices.row(mesh.tets(t, 0));
      for (int c = 0; c < 3; ++c) e.col(c) = mesh.vertices.row(mesh.tets(t, c + 1)).transpose() - v0;
      if (std::abs(e.determinant()) <= 0.0) continue;
      const Eigen::Matrix3d inv = e.inverse();
      for (int r = 0; r < 3; ++r)
        for (int c = 0; c < 3; ++c) locator.inverse_[static_cast<size_t>(9 * t + 3 * r + c)] = inv(r, c);
    }
  } catch (const std::bad_alloc&) {
    return resource_exhausted_error("out of memory building the tet locator");
  }
  return locator;
}

bool TetLocator::barycentric(int32_t tet, const Eigen::Vector3d& p, Eigen::Vector4d& b) const {
  const double* m = inverse_.data() + 9 * static_cast<size_t>(tet);
  const Eigen::Vector3d d = p - mesh_->vertices.row(mesh_->tets(tet, 0)).transpose();
  const double l1 = m[0] * d(0) + m[1] * d(1) + m[2] * d(2);
  const double l2 = m[3] * d(0) + m[4] * d(1) + m[5] * d(2);
  const double l3 = m[6] * d(0) + m[7] * d(1) + m[8] * d(2);
  b = Eigen::Vector4d(1.0 - l1 - l2 - l3, l1, l2, l3);
  return b.minCoeff() >= -1e-9;
}

double TetLocator::distance(int32_t tet, const Eigen::Vector3d& p) const {
  Eigen::Vector4d b;
  if (barycentric(tet, p, b)) return 0.0;
  Eigen::Vector3d v[4];
  for (int c = 0; c < 4; ++c) v[c] = mesh_->vertices.row(mesh_->tets(tet, c)).transpose();
  constexpr int kFaces[4][3] = {{1, 2, 3}, {0, 2, 3}, {0, 1, 3}, {0, 1, 2}};
  double best = std::numeric_limits<double>::infinity();
  for (const auto& f : kFaces) best = std::min(best, point_triangle_distance(p, v[f[0]], v[f[1]], v[f[2]]));
  return best;
}

TetLocator::Location TetLocator::locate(const Eigen::Vector3d& p) const {
  Location location;
  int64_t c[3];
  for (int a = 0; a < 3; ++a) c[a] = static_cast<int64_t>(std::floor((p(a) - origin_(a)) / cell_));
  auto in_grid = [&](int64_t x, int64_t y, int64_t z) {
    return x >= 0 && y >= 0 && z >= 0 && x < dims_[0] && y < dims_[1] && z < dims_[2];
  };
  if (in_grid(c[0], c[1], c[2])) {
    const int64_t cell = cell_of(c[0], c[1], c[2]);
    for (int64_t i = start_[static_cast<size_t>(cell)]; i < start_[static_cast<size_t>(cell) + 1]; ++i) {
      Eigen::Vector4d b;
      if (barycentric(tets_[static_cast<size_t>(i)], p, b)) {
        location.tet = tets_[static_cast<size_t>(i)];
        location.barycentric = b;
        location.inside = true;
        return location;
      }
    }
  }
  // Outside: search rings of cells around p (clamped into the grid) until no closer tet can exist.
  int64_t centre[3];
  double outside_gap = 0.0;  // distance from p to the grid box
  for (int a = 0; a < 3; ++a) {
    centre[a] = std::clamp<int64_t>(c[a], 0, dims_[a] - 1);
    const double lo = origin_(a), hi = origin_(a) + cell_ * static_cast<double>(dims_[a]);
    outside_gap = std::max({outside_gap, lo - p(a), p(a) - hi});
  }
  double best = std::numeric_limits<double>::infinity();
  int32_t best_tet = -1;
  const int64_t max_ring = std::max({dims_[0], dims_[1], dims_[2]});
  for (int64_t ring = 0; ring <= max_ring; ++ring) {
    for (int64_t z = centre[2] - ring; z <= centre[2] + ring; ++z) {
      for (int64_t y = centre[1] - ring; y <= centre[1] + ring; ++y) {
        for (int64_t x = centre[0] - ring; x <= centre[0] + ring; ++x) {
          if (std::max({std::abs(x - centre[0]), std::abs(y - centre[1]), std::abs(z - centre[2])}) != ring) continue;
          if (!in_grid(x, y, z)) continue;
          const int64_t cell = cell_of(x, y, z);
          for (int64_t i = start_[static_cast<size_t>(cell)]; i < start_[static_cast<size_t>(cell) + 1]; ++i) {
            const int32_t t = tets_[static_cast<size_t>(i)];
            const double d = distance(t, p);
            if (d < best || (d == best && t < best_tet)) best = d, best_tet = t;
          }
        }
      }
    }
    // Cells beyond this ring are at least `ring` cells away from the centre cell (plus the gap to the grid).
    if (best_tet >= 0 && best <= std::max(0.0, outside_gap) + static_cast<double>(ring) * cell_) break;
  }
  location.tet = best_tet;
  location.distance_mm = best;
  barycentric(best_tet, p, location.barycentric);
  location.inside = best == 0.0;
  return location;
}

Result<Embedding> embed_points(const TetMesh& rest, const Eigen::MatrixXd& points, const ProgressHooks& hooks) {
  if (points.cols() != 3) return invalid_argument_error("points must be #P x 3");
  POSEWARP_ASSIGN_OR_RETURN(const TetLocator locator, TetLocator::build(rest));
  StageProgress progress(hooks, "embed");
  Embedding e;
  const int64_t n = points.rows();
  e.tet.resize(n);
  e.barycentric.resize(n, 4);
  e.inside.assign(static_cast<size_t>(n), 0);
  std::vector<double> distance(static_cast<size_t>(n), 0.0);
  parallel_for(0, n, 4096, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) {
      const TetLocator::Location l = locator.locate(points.row(i).transpose());
      e.tet(i) = l.tet;
      e.barycentric.row(i) = l.barycentric.transpose();
      e.inside[static_cast<size_t>(i)] = l.inside ? 1 : 0;
      distance[static_cast<size_t>(i)] = l.distance_mm;
    }
    progress.advance(end - begin, n);
  });
  for (int64_t i = 0; i < n; ++i) {
    if (!e.inside[static_cast<size_t>(i)]) {
      ++e.outside_count;
      e.max_outside_distance_mm = std::max(e.max_outside_distance_mm, distance[static_cast<size_t>(i)]);
    }
  }
  progress.finish();
  return e;
}

Eigen::MatrixXd deform_points(const Embedding& embedding, const TetMesh& rest, const Eigen::MatrixXd& posed_vertices) {
  const int64_t n = embedding.tet.size();
  Eigen::MatrixXd out(n, 3);
  parallel_for(0, n, 8192, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) {
      const int32_t t = embedding.tet(i);
      Eigen::Vector3d p = Eigen::Vector3d::Zero();
      for (int c = 0; c < 4; ++c) p += embedding.barycentric(i, c) * posed_vertices.row(rest.tets(t, c)).transpose();
      out.row(i) = p.transpose();
    }
  });
  return out;
}

}  // namespace posewarp::mapping
