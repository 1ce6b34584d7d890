// Articular surface fits for joint centres: a robust sphere (ball joints) and a robust cylinder (hinges), fitted to
// bone boundary points (voxel face centres, so thick slices do not bias the fit toward the bone's interior).
#pragma once

#include <Eigen/Core>

#include <string>
#include <vector>

namespace posewarp::rig::detail {

struct SurfaceFit {
  bool accepted = false;
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();  // sphere centre, or the axis point at the inliers' middle
  Eigen::Vector3d axis = Eigen::Vector3d::Zero();    // unit cylinder axis (zero for a sphere)
  double radius = 0.0;                               // mm
  double rms = 0.0;                                  // mm, over the inliers
  int inliers = 0;
  std::string reason;                                // why a fit was refused, for the skeleton's notes
};

struct FitParams {
  double max_relative_rms = 0.15;  // accept when rms / radius is below this
  int min_points = 20;             // inliers needed
  double band_floor_mm = 1.0;      // the inlier band is never narrower than this (about half a voxel)
  double rms_floor_mm = 0.0;       // rms accepted whatever the radius (the staircase of thick slices)
};

// Sphere through `seed` (the bone's points at the contact: an algebraic start), then grown over `pool` (the same
// bone's boundary points near the contact: the whole head, not only the part in the socket) and refined by
// geometric least squares with outliers trimmed at 2.5 robust sigmas (the neck and the shaft fall inside the sphere
// and are dropped). Refused when too few inliers remain, the rms is too large, or the inliers are a nearly flat patch.
SurfaceFit fit_sphere(const std::vector<Eigen::Vector3d>& seed, const std::vector<Eigen::Vector3d>& pool,
                      const FitParams& params);

// Cylinder (a hinge's condyles, trochlea or talar dome) through `pool`: the axis is searched within `max_tilt_deg`
// of `axis_guess`, each candidate scored by a trimmed circle fit of the points projected across it; the centre is
// the axis point in the middle of the inliers. Refused as fit_sphere is, or when the circle is larger than
// `max_radius_mm` (a flat plateau fits a huge circle).
SurfaceFit fit_cylinder(const std::vector<Eigen::Vector3d>& pool, const Eigen::Vector3d& axis_guess,
                        double max_tilt_deg, double max_radius_mm, const FitParams& params);

// The fraction of `points` (a bone's articular surface: where it nearly touches the other bone) that lie within
// `band_mm` of the fitted sphere or cylinder. A convex articular surface is on its fit; a fit to the shaft is not.
double surface_support(const SurfaceFit& fit, const std::vector<Eigen::Vector3d>& points, double band_mm);

}  // namespace posewarp::rig::detail
