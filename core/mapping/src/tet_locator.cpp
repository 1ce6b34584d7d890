// TetLocator: Teschner's spatial hash over tet bounding boxes, containment by barycentrics, ring search for the
// nearest tet of points outside the mesh.
#include "posewarp/common/exception_wall.h"
#include "posewarp/mapping/tet_locator.h"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <limits>
#include <new>
#include <string>

namespace posewarp::mapping {
namespace {

constexpr double kInsideTolerance = 1e-9;
// A tet whose |det| is below this fraction of its longest edge cubed has no usable barycentric frame.
constexpr double kDegenerateVolume = 1e-12;
// More (cell, tet) entries than this means cell_mm is far too small for the tets (and bucket offsets are int32).
constexpr int64_t kMaxEntries = std::numeric_limits<int32_t>::max();

// Distance from p to triangle abc (Ericson, Real-Time Collision Detection, section 5.1.5).
double point_triangle_distance(const Eigen::Vector3d& p, const Eigen::Vector3d& a, const Eigen::Vector3d& b,
                               const Eigen::Vector3d& c) {
  const Eigen::Vector3d ab = b - a, ac = c - a, ap = p - a;
  const double d1 = ab.dot(ap), d2 = ac.dot(ap);
  if (d1 <= 0 && d2 <= 0) return ap.norm();
  const Eigen::Vector3d bp = p - b;
  const double d3 = ab.dot(bp), d4 = ac.dot(bp);
  if (d3 >= 0 && d4 <= d3) return bp.norm();
  const double vc = d1 * d4 - d3 * d2;
  if (vc <= 0 && d1 >= 0 && d3 <= 0) return (p - (a + ab * (d1 / (d1 - d3)))).norm();
  const Eigen::Vector3d cp = p - c;
  const double d5 = ab.dot(cp), d6 = ac.dot(cp);
  if (d6 >= 0 && d5 <= d6) return cp.norm();
  const double vb = d5 * d2 - d1 * d6;
  if (vb <= 0 && d2 >= 0 && d6 <= 0) return (p - (a + ac * (d2 / (d2 - d6)))).norm();
  const double va = d3 * d6 - d5 * d4;
  if (va <= 0 && (d4 - d3) >= 0 && (d5 - d6) >= 0) {
    return (p - (b + (c - b) * ((d4 - d3) / ((d4 - d3) + (d5 - d6))))).norm();
  }
  const double denom = 1.0 / (va + vb + vc);
  return (p - (a + ab * (vb * denom) + ac * (vc * denom))).norm();
}

bool is_prime(uint64_t n) {
  if (n < 2) return false;
  if (n % 2 == 0) return n == 2;
  for (uint64_t d = 3; d * d <= n; d += 2) {
    if (n % d == 0) return false;
  }
  return true;
}

uint64_t next_prime(uint64_t n) {
  while (!is_prime(n)) ++n;
  return n;
}

float round_down(double x) {
  float f = static_cast<float>(x);
  if (static_cast<double>(f) > x) f = std::nextafter(f, -std::numeric_limits<float>::infinity());
  return f;
}

float round_up(double x) {
  float f = static_cast<float>(x);
  if (static_cast<double>(f) < x) f = std::nextafter(f, std::numeric_limits<float>::infinity());
  return f;
}

Status check_mesh(const TetMesh& mesh) {
  if (mesh.tet_count() == 0 || mesh.vertex_count() == 0) {
    return invalid_argument_error("cannot locate points in an empty tet mesh; build the rig's mesh first");
  }
  if (mesh.vertices.cols() != 3 || mesh.tets.cols() != 4) {
    return invalid_argument_error("a tet mesh needs #V x 3 vertices and #T x 4 tets, got " +
                                  std::to_string(mesh.vertices.cols()) + " and " + std::to_string(mesh.tets.cols()) +
                                  " columns");
  }
  if (mesh.tet_count() >= std::numeric_limits<int32_t>::max()) {
    return invalid_argument_error("the tet mesh has more tets than a 32-bit index can name");
  }
  if (mesh.tets.minCoeff() < 0 || mesh.tets.maxCoeff() >= mesh.vertex_count()) {
    return invalid_argument_error("the tet mesh refers to vertices it does not have");
  }
  if (!mesh.vertices.allFinite()) return invalid_argument_error("the tet mesh has non-finite vertices");
  return ok_status();
}

// Bounding box and edge lengths of one tet.
struct TetExtent {
  Eigen::Vector3d lo, hi;
  double longest_edge = 0.0;
  double edge_sum = 0.0;  // of its six edges
};

// The extent of the tet with corners v.
TetExtent tet_extent(const Eigen::Vector3d (&v)[4]) {
  TetExtent extent;
  extent.lo = v[0], extent.hi = v[0];
  for (int c = 1; c < 4; ++c) extent.lo = extent.lo.cwiseMin(v[c]), extent.hi = extent.hi.cwiseMax(v[c]);
  for (int i = 0; i < 4; ++i) {
    for (int j = i + 1; j < 4; ++j) {
      const double length = (v[j] - v[i]).norm();
      extent.longest_edge = std::max(extent.longest_edge, length);
      extent.edge_sum += length;
    }
  }
  return extent;
}

// Writes the barycentric frame of the tet with corners v; false, with a zero inverse, when it is too flat for one.
bool write_tet_frame(const Eigen::Vector3d (&v)[4], double longest_edge, double (&origin)[3], double (&inverse)[9]) {
  Eigen::Matrix3d edges;
  for (int c = 0; c < 3; ++c) edges.col(c) = v[c + 1] - v[0];
  const double det = edges.determinant();
  for (int a = 0; a < 3; ++a) origin[a] = v[0](a);
  if (!(std::abs(det) > kDegenerateVolume * longest_edge * longest_edge * longest_edge)) {
    std::fill(std::begin(inverse), std::end(inverse), 0.0);
    return false;
  }
  const Eigen::Matrix3d edges_inverse = edges.inverse();
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) inverse[3 * r + c] = edges_inverse(r, c);
  }
  return true;
}

// The uniform grid that tets are hashed into.
struct HashGrid {
  Eigen::Vector3d origin = Eigen::Vector3d::Zero();  // lower corner of cell (0, 0, 0), mm
  double cell_mm = 0.0;
  int64_t dims[3] = {1, 1, 1};  // cells per axis
};

// The grid of cell_mm cells from lo over hi; RESOURCE_EXHAUSTED when its cell keys would not fit in 64 bits.
Result<HashGrid> grid_over(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, double cell_mm) {
  double along[3], cells = 1.0;
  for (int a = 0; a < 3; ++a) {
    along[a] = std::floor((hi(a) - lo(a)) / cell_mm) + 1.0;
    cells *= along[a];
  }
  if (cells > 1e18) {  // cell keys must fit in 64 bits
    return resource_exhausted_error("a tet locator cell of " + std::to_string(cell_mm) +
                                    " mm is too small for a mesh this large; use a larger cell");
  }
  HashGrid grid;
  grid.origin = lo;
  grid.cell_mm = cell_mm;
  for (int a = 0; a < 3; ++a) grid.dims[a] = static_cast<int64_t>(along[a]);
  return grid;
}

// First and last cell per axis that the bounding box of tet t (in boxes, #T x 6) overlaps, clamped to the grid.
void cell_range(const HashGrid& grid, const std::vector<float>& boxes, int64_t t, int64_t first[3], int64_t last[3]) {
  for (int a = 0; a < 3; ++a) {
    const double box_lo = boxes[static_cast<size_t>(6 * t + a)];
    const double box_hi = boxes[static_cast<size_t>(6 * t + 3 + a)];
    first[a] = std::clamp<int64_t>(static_cast<int64_t>(std::floor((box_lo - grid.origin(a)) / grid.cell_mm)), 0,
                                   grid.dims[a] - 1);
    last[a] = std::clamp<int64_t>(static_cast<int64_t>(std::floor((box_hi - grid.origin(a)) / grid.cell_mm)), 0,
                                  grid.dims[a] - 1);
  }
}

// Calls visit(i, j, k) for every cell that the bounding box of tet t overlaps, x fastest.
template <typename Visit>
void for_each_cell(const HashGrid& grid, const std::vector<float>& boxes, int64_t t, Visit&& visit) {
  int64_t first[3], last[3];
  cell_range(grid, boxes, t, first, last);
  for (int64_t k = first[2]; k <= last[2]; ++k) {
    for (int64_t j = first[1]; j <= last[1]; ++j) {
      for (int64_t i = first[0]; i <= last[0]; ++i) visit(i, j, k);
    }
  }
}

// The number of (cell, tet) entries the tets marked in `hashed` make; RESOURCE_EXHAUSTED past kMaxEntries.
Result<int64_t> count_entries(const HashGrid& grid, const std::vector<float>& boxes,
                              const std::vector<uint8_t>& hashed) {
  const int64_t nt = static_cast<int64_t>(hashed.size());
  int64_t entries = 0;
  for (int64_t t = 0; t < nt; ++t) {
    if (!hashed[static_cast<size_t>(t)]) continue;
    int64_t first[3], last[3];
    cell_range(grid, boxes, t, first, last);
    entries += (last[0] - first[0] + 1) * (last[1] - first[1] + 1) * (last[2] - first[2] + 1);
    if (entries > kMaxEntries) {
      return resource_exhausted_error("a tet locator cell of " + std::to_string(grid.cell_mm) +
                                      " mm is too small for these tets; use a larger cell (or 0 for automatic)");
    }
  }
  return entries;
}

}  // namespace

Result<TetLocator> TetLocator::build(const TetMesh& mesh, double cell_mm) {
  POSEWARP_RETURN_IF_ERROR(check_mesh(mesh));
  if (!std::isfinite(cell_mm) || cell_mm < 0.0) {
    return invalid_argument_error(
        "the tet locator's cell size must be a finite number of mm >= 0 (0 = automatic), got " +
        std::to_string(cell_mm));
  }
  const int64_t nv = mesh.vertex_count();
  const int64_t nt = mesh.tet_count();
  return guarded("building the tet locator for " + std::to_string(nt) + " tets", [&]() -> Result<TetLocator> {
    TetLocator locator;
    locator.vertices_.resize(static_cast<size_t>(nv) * 3);
    for (int64_t v = 0; v < nv; ++v) {
      for (int a = 0; a < 3; ++a) locator.vertices_[static_cast<size_t>(3 * v + a)] = mesh.vertices(v, a);
    }
    locator.tets_.resize(static_cast<size_t>(nt) * 4);
    locator.frames_.resize(static_cast<size_t>(nt));
    locator.boxes_.resize(static_cast<size_t>(nt) * 6);
    // Only tets with volume are hashed; they alone set the grid's extent and the automatic cell size.
    std::vector<uint8_t> hashed(static_cast<size_t>(nt), 0);
    Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
    Eigen::Vector3d hi = -lo;
    double edge_sum = 0.0;
    int64_t hashed_count = 0;
    for (int64_t t = 0; t < nt; ++t) {
      Eigen::Vector3d v[4];
      for (int c = 0; c < 4; ++c) {
        locator.tets_[static_cast<size_t>(4 * t + c)] = mesh.tets(t, c);
        v[c] = mesh.vertices.row(mesh.tets(t, c)).transpose();
      }
      const TetExtent extent = tet_extent(v);
      for (int a = 0; a < 3; ++a) {
        locator.boxes_[static_cast<size_t>(6 * t + a)] = round_down(extent.lo(a));
        locator.boxes_[static_cast<size_t>(6 * t + 3 + a)] = round_up(extent.hi(a));
      }
      TetFrame& frame = locator.frames_[static_cast<size_t>(t)];
      if (!write_tet_frame(v, extent.longest_edge, frame.origin, frame.inverse)) {
        ++locator.degenerate_count_;
        continue;
      }
      hashed[static_cast<size_t>(t)] = 1;
      ++hashed_count;
      edge_sum += extent.edge_sum / 6.0;
      lo = lo.cwiseMin(extent.lo);
      hi = hi.cwiseMax(extent.hi);
    }
    if (hashed_count == 0) {
      return invalid_argument_error("every tet of the mesh (" + std::to_string(nt) +
                                    ") is flat; no point can be located in it");
    }
    if (cell_mm == 0.0) cell_mm = edge_sum / static_cast<double>(hashed_count);
    POSEWARP_ASSIGN_OR_RETURN(const HashGrid grid, grid_over(lo, hi, cell_mm));
    locator.cell_mm_ = grid.cell_mm;
    locator.grid_origin_ = grid.origin;
    for (int a = 0; a < 3; ++a) locator.dims_[a] = grid.dims[a];
    POSEWARP_ASSIGN_OR_RETURN(const int64_t entries, count_entries(grid, locator.boxes_, hashed));

    // Teschner et al. found a prime table size a little above the number of hashed items to work best.
    const uint64_t buckets = next_prime(static_cast<uint64_t>(std::max<int64_t>(entries, 1)));
    std::vector<int32_t>& start = locator.bucket_start_;
    start.assign(buckets + 1, 0);
    for (int64_t t = 0; t < nt; ++t) {
      if (!hashed[static_cast<size_t>(t)]) continue;
      for_each_cell(grid, locator.boxes_, t, [&](int64_t i, int64_t j, int64_t k) {
        ++start[static_cast<size_t>(locator.bucket_of(i, j, k)) + 1];
      });
    }
    for (uint64_t b = 0; b < buckets; ++b) start[b + 1] += start[b];
    locator.entry_cell_.resize(static_cast<size_t>(entries));
    locator.entry_tet_.resize(static_cast<size_t>(entries));
    std::vector<int32_t> fill(start.begin(), start.end() - 1);
    for (int64_t t = 0; t < nt; ++t) {
      if (!hashed[static_cast<size_t>(t)]) continue;
      for_each_cell(grid, locator.boxes_, t, [&](int64_t i, int64_t j, int64_t k) {
        const size_t slot = static_cast<size_t>(fill[static_cast<size_t>(locator.bucket_of(i, j, k))]++);
        locator.entry_cell_[slot] = locator.cell_key(i, j, k);
        locator.entry_tet_[slot] = static_cast<int32_t>(t);
      });
    }
    return locator;
  });
}

int64_t TetLocator::bucket_of(int64_t i, int64_t j, int64_t k) const {
  const uint64_t h = (static_cast<uint64_t>(i) * 73856093u) ^ (static_cast<uint64_t>(j) * 19349663u) ^
                     (static_cast<uint64_t>(k) * 83492791u);
  return static_cast<int64_t>(h % (bucket_start_.size() - 1));
}

Eigen::Vector4d TetLocator::barycentric(int32_t tet, const Eigen::Vector3d& p) const {
  const TetFrame& f = frames_[static_cast<size_t>(tet)];
  const double d0 = p(0) - f.origin[0], d1 = p(1) - f.origin[1], d2 = p(2) - f.origin[2];
  const double* m = f.inverse;
  const double b1 = m[0] * d0 + m[1] * d1 + m[2] * d2;
  const double b2 = m[3] * d0 + m[4] * d1 + m[5] * d2;
  const double b3 = m[6] * d0 + m[7] * d1 + m[8] * d2;
  return Eigen::Vector4d(1.0 - b1 - b2 - b3, b1, b2, b3);
}

double TetLocator::distance_to_tet(int32_t tet, const Eigen::Vector3d& p, const Eigen::Vector4d& barycentric) const {
  if (barycentric.minCoeff() >= -kInsideTolerance) return 0.0;
  Eigen::Vector3d v[4];
  for (int c = 0; c < 4; ++c) {
    const double* x =
        vertices_.data() + 3 * static_cast<size_t>(tets_[4 * static_cast<size_t>(tet) + static_cast<size_t>(c)]);
    v[c] = Eigen::Vector3d(x[0], x[1], x[2]);
  }
  // The nearest point of a convex tet to an outside point lies on a face that faces the point, i.e. a face whose
  // opposite vertex has a negative barycentric.
  constexpr int kFaces[4][3] = {{1, 2, 3}, {0, 2, 3}, {0, 1, 3}, {0, 1, 2}};
  double best = std::numeric_limits<double>::infinity();
  for (int i = 0; i < 4; ++i) {
    if (barycentric(i) < 0.0) {
      best = std::min(best, point_triangle_distance(p, v[kFaces[i][0]], v[kFaces[i][1]], v[kFaces[i][2]]));
    }
  }
  return best;
}

double TetLocator::squared_distance_to_box(int32_t tet, const Eigen::Vector3d& p) const {
  const float* box = boxes_.data() + 6 * static_cast<size_t>(tet);
  double sum = 0.0;
  for (int a = 0; a < 3; ++a) {
    const double d = std::max({0.0, static_cast<double>(box[a]) - p(a), p(a) - static_cast<double>(box[3 + a])});
    sum += d * d;
  }
  return sum;
}

int64_t TetLocator::cell_of(const Eigen::Vector3d& p) const {
  int64_t cell[3];
  for (int a = 0; a < 3; ++a) {
    const double index = std::floor((p(a) - grid_origin_(a)) / cell_mm_);
    if (!(index >= 0.0 && index < static_cast<double>(dims_[a]))) return -1;
    cell[a] = static_cast<int64_t>(index);
  }
  return cell_key(cell[0], cell[1], cell[2]);
}

TetLocator::Location TetLocator::locate(const Eigen::Vector3d& p) const {
  Location location;
  if (!p.allFinite()) {
    location.distance_mm = std::numeric_limits<double>::infinity();
    return location;
  }
  int64_t cell[3];
  bool in_grid = true;
  for (int a = 0; a < 3; ++a) {
    // Clamped in double first so that far-away points do not overflow the cast.
    const double index =
        std::clamp(std::floor((p(a) - grid_origin_(a)) / cell_mm_), -1.0, static_cast<double>(dims_[a]));
    cell[a] = static_cast<int64_t>(index);
    in_grid = in_grid && cell[a] >= 0 && cell[a] < dims_[a];
  }
  // Fast path: a point inside the mesh lies in the bounding box of its tet, so that tet is hashed in p's cell.
  if (in_grid) {
    const int64_t key = cell_key(cell[0], cell[1], cell[2]);
    const size_t bucket = static_cast<size_t>(bucket_of(cell[0], cell[1], cell[2]));
    for (int32_t e = bucket_start_[bucket]; e < bucket_start_[bucket + 1]; ++e) {
      if (entry_cell_[static_cast<size_t>(e)] != key) continue;
      const int32_t t = entry_tet_[static_cast<size_t>(e)];
      const Eigen::Vector4d b = barycentric(t, p);
      if (b.minCoeff() >= -kInsideTolerance) {
        location.tet = t;
        location.barycentric = b;
        location.inside = true;
        return location;
      }
    }
  }

  // Ring search around the (clamped) cell of p, ring r holding the cells at Chebyshev distance r from it.
  int64_t centre[3];
  double gap[3];  // per-axis distance from p to the grid's box
  double gap_squared = 0.0;
  for (int a = 0; a < 3; ++a) {
    centre[a] = std::clamp<int64_t>(cell[a], 0, dims_[a] - 1);
    const double grid_lo = grid_origin_(a), grid_hi = grid_origin_(a) + cell_mm_ * static_cast<double>(dims_[a]);
    gap[a] = std::max({0.0, grid_lo - p(a), p(a) - grid_hi});
    gap_squared += gap[a] * gap[a];
  }
  double best = std::numeric_limits<double>::infinity();
  int32_t best_tet = -1;
  Eigen::Vector4d best_barycentric = Eigen::Vector4d::Zero();
  auto visit_cell = [&](int64_t i, int64_t j, int64_t k) {
    if (best_tet >= 0) {  // a cell farther than the best tet so far cannot hold a nearer one
      const int64_t index[3] = {i, j, k};
      double squared = 0.0;
      for (int a = 0; a < 3; ++a) {
        const double cell_lo = grid_origin_(a) + cell_mm_ * static_cast<double>(index[a]);
        const double d = std::max({0.0, cell_lo - p(a), p(a) - (cell_lo + cell_mm_)});
        squared += d * d;
      }
      if (squared > best * best) return;
    }
    const int64_t key = cell_key(i, j, k);
    const size_t bucket = static_cast<size_t>(bucket_of(i, j, k));
    for (int32_t e = bucket_start_[bucket]; e < bucket_start_[bucket + 1]; ++e) {
      if (entry_cell_[static_cast<size_t>(e)] != key) continue;
      const int32_t t = entry_tet_[static_cast<size_t>(e)];
      if (best_tet >= 0 && squared_distance_to_box(t, p) > best * best) continue;
      const Eigen::Vector4d b = barycentric(t, p);
      const double d = distance_to_tet(t, p, b);
      if (d < best || (d == best && t < best_tet)) {
        best = d;
        best_tet = t;
        best_barycentric = b;
      }
    }
  };
  for (int64_t ring = 0;; ++ring) {
    const int64_t z0 = std::max<int64_t>(centre[2] - ring, 0), z1 = std::min(centre[2] + ring, dims_[2] - 1);
    const int64_t y0 = std::max<int64_t>(centre[1] - ring, 0), y1 = std::min(centre[1] + ring, dims_[1] - 1);
    const int64_t x0 = std::max<int64_t>(centre[0] - ring, 0), x1 = std::min(centre[0] + ring, dims_[0] - 1);
    for (int64_t k = z0; k <= z1; ++k) {
      for (int64_t j = y0; j <= y1; ++j) {
        if (std::abs(k - centre[2]) == ring || std::abs(j - centre[1]) == ring) {
          for (int64_t i = x0; i <= x1; ++i) visit_cell(i, j, k);
        } else {
          if (centre[0] - ring >= 0) visit_cell(centre[0] - ring, j, k);
          if (ring > 0 && centre[0] + ring < dims_[0]) visit_cell(centre[0] + ring, j, k);
        }
      }
    }
    // Every cell of a later ring lies beyond ring + 1 cells from the centre along some axis, within the grid;
    // the smallest distance from p to such a cell bounds every tet not yet visited.
    double bound = std::numeric_limits<double>::infinity();
    bool cells_left = false;
    for (int a = 0; a < 3; ++a) {
      const double others = gap_squared - gap[a] * gap[a];
      if (centre[a] + ring + 1 < dims_[a]) {
        cells_left = true;
        const double slab = grid_origin_(a) + cell_mm_ * static_cast<double>(centre[a] + ring + 1);
        const double d = std::max(gap[a], slab - p(a));
        bound = std::min(bound, std::sqrt(others + d * d));
      }
      if (centre[a] - ring - 1 >= 0) {
        cells_left = true;
        const double slab = grid_origin_(a) + cell_mm_ * static_cast<double>(centre[a] - ring);
        const double d = std::max(gap[a], p(a) - slab);
        bound = std::min(bound, std::sqrt(others + d * d));
      }
    }
    if (!cells_left || (best_tet >= 0 && best < bound)) break;
  }
  location.tet = best_tet;
  location.barycentric = best_barycentric;
  location.distance_mm = best;
  location.inside = best == 0.0;
  return location;
}

}  // namespace posewarp::mapping
