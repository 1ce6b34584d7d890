// PointKdTree: nearest-neighbour queries on a fixed 3D point set (a balanced k-d tree in one array).
#pragma once

#include <Eigen/Core>

#include <algorithm>
#include <cstdint>
#include <limits>
#include <utility>
#include <vector>

namespace posewarp::weights {

class PointKdTree {
 public:
  struct Point {
    Eigen::Vector3d position;  // mm
    int64_t id = -1;           // what queries return
  };
  struct Hit {
    int64_t id = -1;
    double distance_sq = std::numeric_limits<double>::infinity();  // mm^2
  };

  explicit PointKdTree(std::vector<Point> points) : points_(std::move(points)), axis_(points_.size(), 0) {
    build(0, static_cast<int64_t>(points_.size()));
  }

  // Improves *best with the nearest point to q: strictly closer, or as close with a lower id. Starting from a hit
  // of an earlier query prunes the search (nearest point to a set of queries).
  void nearest(const Eigen::Vector3d& q, Hit* best) const { search(0, static_cast<int64_t>(points_.size()), q, best); }

 private:
  static constexpr int64_t kLeafSize = 8;

  void build(int64_t lo, int64_t hi) {
    if (hi - lo <= kLeafSize) return;
    Eigen::Vector3d low = points_[lo].position, high = low;
    for (int64_t i = lo + 1; i < hi; ++i) {
      low = low.cwiseMin(points_[i].position);
      high = high.cwiseMax(points_[i].position);
    }
    Eigen::Index axis = 0;
    (high - low).maxCoeff(&axis);
    const int64_t mid = lo + (hi - lo) / 2;
    std::nth_element(points_.begin() + lo, points_.begin() + mid, points_.begin() + hi,
                     [axis](const Point& a, const Point& b) { return a.position[axis] < b.position[axis]; });
    axis_[mid] = static_cast<int8_t>(axis);
    build(lo, mid);
    build(mid + 1, hi);
  }

  static void consider(const Point& p, const Eigen::Vector3d& q, Hit* best) {
    const double d = (p.position - q).squaredNorm();
    if (d < best->distance_sq || (d == best->distance_sq && p.id < best->id)) *best = {p.id, d};
  }

  void search(int64_t lo, int64_t hi, const Eigen::Vector3d& q, Hit* best) const {
    if (hi - lo <= kLeafSize) {
      for (int64_t i = lo; i < hi; ++i) consider(points_[i], q, best);
      return;
    }
    const int64_t mid = lo + (hi - lo) / 2;
    const Point& split = points_[mid];
    consider(split, q, best);
    const double diff = q[axis_[mid]] - split.position[axis_[mid]];
    const bool left_first = diff < 0.0;
    if (left_first) {
      search(lo, mid, q, best);
    } else {
      search(mid + 1, hi, q, best);
    }
    if (diff * diff <= best->distance_sq) {
      if (left_first) {
        search(mid + 1, hi, q, best);
      } else {
        search(lo, mid, q, best);
      }
    }
  }

  std::vector<Point> points_;
  std::vector<int8_t> axis_;  // split axis of the node stored at each median position
};

}  // namespace posewarp::weights
