// Robust sphere and cylinder fits to bone boundary points (joint centres and hinge axes).
#include "joint_fit.h"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>

namespace posewarp::rig::detail {
namespace {

using Eigen::Vector2d;
using Eigen::Vector3d;

constexpr double kRobustSigmas = 2.5;
constexpr double kMadToSigma = 1.4826;
constexpr double kMaxSphereRadiusMm = 80.0;
// An inlier set whose mean unit direction from the centre is longer than this is a nearly flat patch (a cap of
// less than about 35 degrees half-angle): its centre is not determined.
constexpr double kMaxMeanDirection = 0.9;

double median(std::vector<double> values) {
  if (values.empty()) return 0.0;
  const size_t mid = values.size() / 2;
  std::nth_element(values.begin(), values.begin() + static_cast<std::ptrdiff_t>(mid), values.end());
  return values[mid];
}

// Inlier band of residuals: 2.5 robust sigmas about the median, never narrower than the floor.
double inlier_band(const std::vector<double>& residuals, double floor_mm) {
  const double centre = median(residuals);
  std::vector<double> deviation(residuals.size());
  for (size_t i = 0; i < residuals.size(); ++i) deviation[i] = std::abs(residuals[i] - centre);
  return std::max(floor_mm, kRobustSigmas * kMadToSigma * median(deviation));
}

// |p - c|^2 = r^2 in the least-squares algebraic sense (Kasa), in any dimension.
template <int D>
bool algebraic_fit(const std::vector<Eigen::Matrix<double, D, 1>>& points, Eigen::Matrix<double, D, 1>& centre,
                   double& radius) {
  using Vec = Eigen::Matrix<double, D, 1>;
  if (points.size() < static_cast<size_t>(D + 2)) return false;
  Vec mean = Vec::Zero();
  for (const Vec& p : points) mean += p;
  mean /= static_cast<double>(points.size());
  Eigen::MatrixXd a(static_cast<Eigen::Index>(points.size()), D + 1);
  Eigen::VectorXd b(static_cast<Eigen::Index>(points.size()));
  for (size_t i = 0; i < points.size(); ++i) {
    const Vec q = points[i] - mean;
    a.row(static_cast<Eigen::Index>(i)).head<D>() = 2.0 * q.transpose();
    a(static_cast<Eigen::Index>(i), D) = 1.0;
    b(static_cast<Eigen::Index>(i)) = q.squaredNorm();
  }
  const Eigen::VectorXd x = a.colPivHouseholderQr().solve(b);
  const Vec c = x.head<D>();
  const double r2 = x(D) + c.squaredNorm();
  if (!(r2 > 0.0) || !c.allFinite()) return false;
  centre = c + mean;
  radius = std::sqrt(r2);
  return true;
}

// Gauss-Newton on sum (|p - c| - r)^2.
template <int D>
void geometric_refine(const std::vector<Eigen::Matrix<double, D, 1>>& points, Eigen::Matrix<double, D, 1>& centre,
                      double& radius, int iterations) {
  using Vec = Eigen::Matrix<double, D, 1>;
  for (int it = 0; it < iterations; ++it) {
    Eigen::Matrix<double, D + 1, D + 1> jtj = Eigen::Matrix<double, D + 1, D + 1>::Zero();
    Eigen::Matrix<double, D + 1, 1> jtr = Eigen::Matrix<double, D + 1, 1>::Zero();
    for (const Vec& p : points) {
      const Vec d = p - centre;
      const double n = d.norm();
      if (n < 1e-9) continue;
      Eigen::Matrix<double, D + 1, 1> j;
      j.template head<D>() = -d / n;
      j(D) = -1.0;
      const double residual = n - radius;
      jtj += j * j.transpose();
      jtr += j * residual;
    }
    const Eigen::Matrix<double, D + 1, 1> step = jtj.ldlt().solve(-jtr);
    if (!step.allFinite()) return;
    centre += step.template head<D>();
    radius += step(D);
    if (step.norm() < 1e-4) return;
  }
}

template <int D>
struct Trimmed {
  Eigen::Matrix<double, D, 1> centre;
  double radius = 0.0;
  double rms = 0.0;
  std::vector<int> inliers;
  double mean_direction = 1.0;  // length of the mean unit direction of the inliers from the centre
  double core_rms = 0.0;        // rms of the kCoreFraction of all points closest to the fit
  bool ok = false;
};

// A hinge's articular end is never alone near the joint (the shaft, a malleolus, the talus body): the fit is judged
// on the best-fitting part of the points, a least-trimmed-squares measure.
constexpr double kCoreFraction = 0.6;

// Alternates trimming (robust band of residuals) and geometric refinement, starting from an algebraic fit.
template <int D>
Trimmed<D> trimmed_fit(const std::vector<Eigen::Matrix<double, D, 1>>& points, double band_floor, int rounds) {
  using Vec = Eigen::Matrix<double, D, 1>;
  Trimmed<D> fit;
  if (!algebraic_fit<D>(points, fit.centre, fit.radius)) return fit;
  std::vector<Vec> kept;
  std::vector<double> residuals(points.size());
  for (int round = 0; round < rounds; ++round) {
    for (size_t i = 0; i < points.size(); ++i) residuals[i] = (points[i] - fit.centre).norm() - fit.radius;
    const double band = inlier_band(residuals, band_floor);
    kept.clear();
    fit.inliers.clear();
    for (size_t i = 0; i < points.size(); ++i) {
      if (std::abs(residuals[i]) < band) kept.push_back(points[i]), fit.inliers.push_back(static_cast<int>(i));
    }
    if (kept.size() < static_cast<size_t>(D + 2)) return fit;
    geometric_refine<D>(kept, fit.centre, fit.radius, 8);
  }
  double sum = 0.0;
  Vec direction = Vec::Zero();
  for (const Vec& p : kept) {
    const double e = (p - fit.centre).norm() - fit.radius;
    sum += e * e;
    direction += (p - fit.centre).normalized();
  }
  fit.rms = std::sqrt(sum / static_cast<double>(kept.size()));
  fit.mean_direction = direction.norm() / static_cast<double>(kept.size());
  std::vector<double> squared(points.size());
  for (size_t i = 0; i < points.size(); ++i) {
    const double e = (points[i] - fit.centre).norm() - fit.radius;
    squared[i] = e * e;
  }
  const size_t core = std::max<size_t>(1, static_cast<size_t>(kCoreFraction * static_cast<double>(points.size())));
  std::nth_element(squared.begin(), squared.begin() + static_cast<std::ptrdiff_t>(core - 1), squared.end());
  double core_sum = 0.0;
  for (size_t i = 0; i < core; ++i) core_sum += squared[i];
  fit.core_rms = std::sqrt(core_sum / static_cast<double>(core));
  fit.ok = fit.radius > 0.0 && fit.centre.allFinite();
  return fit;
}

void judge(SurfaceFit& fit, double mean_direction, double max_radius, const FitParams& params) {
  fit.accepted = false;
  if (fit.inliers < params.min_points) {
    fit.reason = std::to_string(fit.inliers) + " inlier points (" + std::to_string(params.min_points) + " needed)";
  } else if (!(fit.radius > 0.0) || fit.radius > max_radius) {
    fit.reason = "radius " + std::to_string(static_cast<int>(std::lround(fit.radius))) + " mm is not an articular surface";
  } else if (fit.rms > std::max(params.max_relative_rms * fit.radius, params.rms_floor_mm)) {
    fit.reason = "rms " + std::to_string(fit.rms) + " mm is too large for radius " + std::to_string(fit.radius) + " mm";
  } else if (mean_direction > kMaxMeanDirection) {
    fit.reason = "the surface is too flat to fix a centre";
  } else {
    fit.accepted = true;
  }
}

// Two unit vectors perpendicular to `axis` and to each other.
void perpendicular_basis(const Vector3d& axis, Vector3d& b1, Vector3d& b2) {
  const Vector3d helper = std::abs(axis.x()) < 0.9 ? Vector3d::UnitX() : Vector3d::UnitY();
  b1 = axis.cross(helper).normalized();
  b2 = axis.cross(b1).normalized();
}

struct AxisScore {
  double score = std::numeric_limits<double>::infinity();
  Trimmed<2> circle;
};

// A hinge's axis is close to mediolateral (the guess); on coarse slices a short cylinder's tilt is weakly determined,
// so each degree away from the guess costs a little: r (1 - cos tilt) mm, 0.75 mm at 18 degrees for a 15 mm radius.
AxisScore score_axis(const std::vector<Vector3d>& points, const Vector3d& axis, double band_floor,
                     const Vector3d& guess) {
  Vector3d b1, b2;
  perpendicular_basis(axis, b1, b2);
  std::vector<Vector2d> projected(points.size());
  for (size_t i = 0; i < points.size(); ++i) projected[i] = {points[i].dot(b1), points[i].dot(b2)};
  AxisScore result;
  result.circle = trimmed_fit<2>(projected, band_floor, 3);
  if (!result.circle.ok || result.circle.inliers.empty()) return result;
  result.score = result.circle.core_rms + result.circle.radius * (1.0 - std::abs(axis.dot(guess)));
  return result;
}

}  // namespace

SurfaceFit fit_sphere(const std::vector<Vector3d>& seed, const std::vector<Vector3d>& pool, const FitParams& params) {
  SurfaceFit fit;
  if (static_cast<int>(seed.size()) < params.min_points) {
    fit.reason = std::to_string(seed.size()) + " contact points (" + std::to_string(params.min_points) + " needed)";
    return fit;
  }
  Trimmed<3> current = trimmed_fit<3>(seed, params.band_floor_mm, 3);
  if (!current.ok) {
    fit.reason = "no sphere through the contact";
    return fit;
  }
  std::vector<Vector3d> gathered;
  for (int round = 0; round < 6; ++round) {
    if (current.radius > kMaxSphereRadiusMm) break;
    // Grow over the whole head: the bone's boundary within 1.35 radii of the centre.
    gathered.clear();
    const double reach = 1.35 * current.radius;
    for (const Vector3d& p : pool) {
      if ((p - current.centre).squaredNorm() < reach * reach) gathered.push_back(p);
    }
    if (static_cast<int>(gathered.size()) < params.min_points) break;
    Trimmed<3> next = trimmed_fit<3>(gathered, params.band_floor_mm, 4);
    if (!next.ok) break;
    const double moved = (next.centre - current.centre).norm() + std::abs(next.radius - current.radius);
    current = next;
    if (moved < 0.01) break;
  }
  fit.centre = current.centre;
  fit.radius = current.radius;
  fit.rms = current.rms;
  fit.inliers = static_cast<int>(current.inliers.size());
  judge(fit, current.mean_direction, kMaxSphereRadiusMm, params);
  return fit;
}

SurfaceFit fit_cylinder(const std::vector<Vector3d>& pool, const Vector3d& axis_guess, double max_tilt_deg,
                        double max_radius_mm, const FitParams& params) {
  SurfaceFit fit;
  if (static_cast<int>(pool.size()) < params.min_points || !(axis_guess.norm() > 0.0)) {
    fit.reason = std::to_string(pool.size()) + " points near the contact (" + std::to_string(params.min_points) +
                 " needed)";
    return fit;
  }
  Vector3d mean = Vector3d::Zero();
  for (const Vector3d& p : pool) mean += p;
  mean /= static_cast<double>(pool.size());
  // Every axis candidate refits the circle: a regular subsample of a large pool keeps that cheap.
  constexpr size_t kMaxPoints = 6000;
  const size_t stride = (pool.size() + kMaxPoints - 1) / kMaxPoints;
  std::vector<Vector3d> points;
  points.reserve(pool.size() / stride + 1);
  for (size_t i = 0; i < pool.size(); i += stride) points.push_back(pool[i] - mean);

  const Vector3d guess = axis_guess.normalized();
  // Best axis near `start` over `candidates`: coarse tilts in 5 degree steps (azimuths in 30), then two passes of
  // small steps about the best.
  auto search = [&](const std::vector<Vector3d>& candidates, const Vector3d& start, double tilt_deg, Vector3d& axis_out) {
    Vector3d g1, g2;
    perpendicular_basis(start, g1, g2);
    Vector3d best_axis = start;
    AxisScore best = score_axis(candidates, start, params.band_floor_mm, guess);
    for (double tilt = 5.0; tilt <= tilt_deg + 1e-9; tilt += 5.0) {
      for (double azimuth = 0.0; azimuth < 360.0; azimuth += 30.0) {
        const double t = tilt * M_PI / 180.0, a = azimuth * M_PI / 180.0;
        const Vector3d axis = (std::cos(t) * start + std::sin(t) * (std::cos(a) * g1 + std::sin(a) * g2)).normalized();
        AxisScore s = score_axis(candidates, axis, params.band_floor_mm, guess);
        if (s.score < best.score) best = std::move(s), best_axis = axis;
      }
    }
    for (const double step_deg : {1.0, 0.25}) {
      Vector3d f1, f2;
      perpendicular_basis(best_axis, f1, f2);
      const Vector3d centre_axis = best_axis;
      for (int u = -4; u <= 4; ++u) {
        for (int v = -4; v <= 4; ++v) {
          if (u == 0 && v == 0) continue;
          const double step = step_deg * M_PI / 180.0;
          const Vector3d axis = (centre_axis + std::tan(u * step) * f1 + std::tan(v * step) * f2).normalized();
          AxisScore s = score_axis(candidates, axis, params.band_floor_mm, guess);
          if (s.score < best.score) best = std::move(s), best_axis = axis;
        }
      }
    }
    axis_out = best_axis;
    return best;
  };
  Vector3d best_axis;
  AxisScore best = search(points, guess, max_tilt_deg, best_axis);
  // Then once more on the points near that cylinder only (the articular surface without the shaft and the rims).
  if (best.circle.ok) {
    Vector3d b1, b2;
    perpendicular_basis(best_axis, b1, b2);
    const double keep = std::max(params.band_floor_mm, 0.25 * best.circle.radius);
    std::vector<Vector3d> near;
    for (const Vector3d& p : points) {
      const Vector2d q(p.dot(b1), p.dot(b2));
      if (std::abs((q - best.circle.centre).norm() - best.circle.radius) < keep) near.push_back(p);
    }
    if (static_cast<int>(near.size()) >= params.min_points) {
      Vector3d refined_axis;
      AxisScore refined = search(near, best_axis, 5.0, refined_axis);
      if (refined.circle.ok) {
        points.swap(near);
        best = std::move(refined);
        best_axis = refined_axis;
      }
    }
  }
  if (!best.circle.ok) {
    fit.reason = "no circle across the contact";
    return fit;
  }
  Vector3d b1, b2;
  perpendicular_basis(best_axis, b1, b2);
  double along = 0.0;
  for (const int i : best.circle.inliers) along += points[static_cast<size_t>(i)].dot(best_axis);
  along /= static_cast<double>(std::max<size_t>(1, best.circle.inliers.size()));
  fit.axis = best_axis;
  fit.centre = mean + best.circle.centre.x() * b1 + best.circle.centre.y() * b2 + along * best_axis;
  fit.radius = best.circle.radius;
  fit.rms = best.circle.core_rms;
  fit.inliers = static_cast<int>(best.circle.inliers.size());
  judge(fit, best.circle.mean_direction, max_radius_mm, params);
  return fit;
}

double surface_support(const SurfaceFit& fit, const std::vector<Vector3d>& points, double band_mm) {
  if (points.empty()) return 0.0;
  const bool cylinder = fit.axis.norm() > 0.5;
  int64_t on = 0;
  for (const Vector3d& p : points) {
    Vector3d d = p - fit.centre;
    if (cylinder) d -= d.dot(fit.axis) * fit.axis;
    on += std::abs(d.norm() - fit.radius) < band_mm ? 1 : 0;
  }
  return static_cast<double>(on) / static_cast<double>(points.size());
}

}  // namespace posewarp::rig::detail
