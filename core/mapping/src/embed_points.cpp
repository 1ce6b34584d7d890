// embed_points and deform_points: surface vertices carried from the rest tets to the posed tets by barycentrics.
#include "posewarp/common/exception_wall.h"
#include "posewarp/mapping/tet_locator.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <limits>
#include <new>
#include <string>

#include "posewarp/common/parallel.h"

namespace posewarp::mapping {
namespace {

// Point indices sorted by hash cell (points outside the grid last), by an LSD radix sort on 16-bit digits.
std::vector<int32_t> spatial_order(const TetLocator& locator, const Eigen::MatrixXd& points) {
  const int64_t n = points.rows();
  std::vector<uint64_t> key(static_cast<size_t>(n));
  parallel_for(0, n, 8192, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) {
      const int64_t cell = locator.cell_of(Eigen::Vector3d(points(i, 0), points(i, 1), points(i, 2)));
      key[static_cast<size_t>(i)] = cell < 0 ? std::numeric_limits<uint64_t>::max() : static_cast<uint64_t>(cell);
    }
  });
  uint64_t largest = 0;
  for (const uint64_t k : key) {
    if (k != std::numeric_limits<uint64_t>::max()) largest = std::max(largest, k);
  }
  std::vector<int32_t> order(static_cast<size_t>(n)), next(static_cast<size_t>(n));
  for (int64_t i = 0; i < n; ++i) order[static_cast<size_t>(i)] = static_cast<int32_t>(i);
  // Outside points carry the largest key: one more digit than the inside keys need sorts them last.
  int digits = 1;
  while (digits < 4 && (largest >> (16 * digits)) != 0) ++digits;
  ++digits;
  std::vector<int64_t> count(65537);
  for (int d = 0; d < digits && d < 4; ++d) {
    const int shift = 16 * d;
    std::fill(count.begin(), count.end(), 0);
    for (const int32_t i : order) ++count[((key[static_cast<size_t>(i)] >> shift) & 0xffff) + 1];
    for (size_t b = 1; b < count.size(); ++b) count[b] += count[b - 1];
    for (const int32_t i : order) next[static_cast<size_t>(count[(key[static_cast<size_t>(i)] >> shift) & 0xffff]++)] = i;
    order.swap(next);
  }
  return order;
}

}  // namespace

Result<Embedding> embed_points(const TetMesh& rest, const Eigen::MatrixXd& points, const ProgressHooks& hooks) {
  const int64_t n = points.rows();
  if (n > 0 && points.cols() != 3) {
    return invalid_argument_error("points to embed must be #P x 3 (LPS mm), got " + std::to_string(points.cols()) +
                                  " columns");
  }
  if (n > 0 && !points.allFinite()) {
    for (int64_t i = 0; i < n; ++i) {
      if (!points.row(i).allFinite()) {
        return invalid_argument_error("point " + std::to_string(i) + " to embed is not finite");
      }
    }
  }
  POSEWARP_ASSIGN_OR_RETURN(const TetLocator locator, TetLocator::build(rest));
  StageProgress progress(hooks, "embed");
  Embedding embedding;
  std::vector<double> distance;
  // Locate the points in the order of their hash cells, so that the tets of a cell are read once for all of its
  // points rather than once per point.
  std::vector<int32_t> order;
  const Status allocated = guarded("embedding " + std::to_string(n) + " points", [&]() -> Status {
    embedding.tet.resize(n);
    embedding.barycentric.resize(n, 4);
    embedding.inside.assign(static_cast<size_t>(n), 0);
    distance.assign(static_cast<size_t>(n), 0.0);
    order = spatial_order(locator, points);
    return ok_status();
  });
  if (!allocated.ok()) return allocated;
  std::atomic<bool> cancelled{false};
  parallel_for(0, n, 2048, [&](int64_t begin, int64_t end) {
    if (cancelled.load(std::memory_order_relaxed)) return;
    if (progress.cancel_requested()) {
      cancelled.store(true);
      return;
    }
    for (int64_t position = begin; position < end; ++position) {
      const int64_t i = order[static_cast<size_t>(position)];
      const TetLocator::Location location = locator.locate(Eigen::Vector3d(points(i, 0), points(i, 1), points(i, 2)));
      embedding.tet(i) = location.tet;
      embedding.barycentric.row(i) = location.barycentric.transpose();
      embedding.inside[static_cast<size_t>(i)] = location.inside ? 1 : 0;
      distance[static_cast<size_t>(i)] = location.distance_mm;
    }
    progress.advance(end - begin, n);
  });
  if (cancelled.load()) return cancelled_error("cancelled during stage 'embed' at the caller's request");
  for (int64_t i = 0; i < n; ++i) {
    if (embedding.inside[static_cast<size_t>(i)]) continue;
    ++embedding.outside_count;
    embedding.max_outside_distance_mm = std::max(embedding.max_outside_distance_mm, distance[static_cast<size_t>(i)]);
  }
  progress.finish();
  return embedding;
}

Eigen::MatrixXd deform_points(const Embedding& embedding, const TetMesh& rest, const Eigen::MatrixXd& posed_vertices) {
  const int64_t n = embedding.tet.size();
  Eigen::MatrixXd posed(n, 3);
  const bool shapes_ok = embedding.barycentric.rows() == n && embedding.barycentric.cols() == 4 &&
                         rest.tets.cols() == 4 && posed_vertices.cols() == 3;
  const int64_t tet_count = rest.tet_count();
  const int64_t vertex_count = posed_vertices.rows();
  parallel_for(0, n, 8192, [&](int64_t begin, int64_t end) {
    for (int64_t i = begin; i < end; ++i) {
      const int32_t t = embedding.tet(i);
      bool valid = shapes_ok && t >= 0 && t < tet_count;
      Eigen::RowVector3d p = Eigen::RowVector3d::Zero();
      for (int c = 0; valid && c < 4; ++c) {
        const int v = rest.tets(t, c);
        valid = v >= 0 && v < vertex_count;
        if (valid) p += embedding.barycentric(i, c) * posed_vertices.row(v);
      }
      posed.row(i) = valid ? p : Eigen::RowVector3d::Constant(std::numeric_limits<double>::quiet_NaN());
    }
  });
  return posed;
}

}  // namespace posewarp::mapping
