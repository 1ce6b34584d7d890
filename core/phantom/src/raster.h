// Signed-distance primitives and their rasterization onto a label grid (phantom internals).
#pragma once

#include <limits>
#include <vector>

#include "posewarp/common/volume.h"

namespace posewarp::phantom::detail {

constexpr double kInf = std::numeric_limits<double>::infinity();

// A solid in physical space (mm). sdf() is negative inside; exact for spheres, capsules, cylinders, round cones and
// (oriented) boxes, a close approximation for elliptic shapes and cups (good enough to place a fat layer).
struct Shape {
  enum class Kind {
    kSphere,
    kCapsule,
    kCylinder,
    kEllipticCylinderZ,
    kEllipsoid,
    kBox,
    kRoundCone,
    kSphericalCup,
    kOrientedBox
  };
  Kind kind = Kind::kSphere;
  // sphere/ellipsoid/cup/oriented box centre; capsule/cylinder/round cone start; elliptic cylinder centre (z
  // ignored); box min
  Vec3 a{};
  // capsule/cylinder/round cone end; elliptic cylinder (z_min, z_max in b[0], b[1]); box max; cup pole (unit);
  // oriented box half extents along (axis_u, axis_v, axis_u x axis_v)
  Vec3 b{};
  double radius = 0.0;  // round cone radius at a; cup inner radius; oriented box edge rounding
  // ellipsoid and elliptic cylinder radii (x, y, -); round cone (radius at b, -, -); cup (outer radius,
  // half-angle in radians, -)
  Vec3 radii{};
  Vec3 axis_u{1.0, 0.0, 0.0};  // oriented box axes (orthonormal)
  Vec3 axis_v{0.0, 1.0, 0.0};
  // Only points inside this box belong to the shape (for hemispheres and the like).
  Vec3 clip_min{-kInf, -kInf, -kInf};
  Vec3 clip_max{kInf, kInf, kInf};

  double sdf(const Vec3& p) const;
  bool contains(const Vec3& p) const;
  void bounds(Vec3& lo, Vec3& hi) const;
};

Shape sphere(const Vec3& centre, double radius);
Shape capsule(const Vec3& a, const Vec3& b, double radius);
Shape cylinder(const Vec3& a, const Vec3& b, double radius);
Shape elliptic_cylinder_z(double cx, double cy, double rx, double ry, double z_min, double z_max);
Shape ellipsoid(const Vec3& centre, const Vec3& radii);
Shape box(const Vec3& lo, const Vec3& hi);
// A capsule whose radius goes linearly from radius_a at a to radius_b at b (|radius_a - radius_b| < |b - a|).
Shape round_cone(const Vec3& a, const Vec3& b, double radius_a, double radius_b);
// The part of the spherical shell inner_radius..outer_radius around `centre` within half_angle (radians) of the
// unit direction `pole`: a socket whose opening faces -pole.
Shape spherical_cup(const Vec3& centre, const Vec3& pole, double inner_radius, double outer_radius,
                    double half_angle);
// A box centred at `centre` with half extents along the orthonormal axes u, v and u x v, edges rounded by
// `rounding` (0 = sharp).
Shape oriented_box(const Vec3& centre, const Vec3& u, const Vec3& v, const Vec3& half_extents, double rounding = 0.0);

// A grid with the given spacing and direction that holds [lo, hi] plus a margin on every side.
ImageGeometry fit_grid(const Vec3& lo, const Vec3& hi, double spacing, const std::array<double, 9>& direction,
                       double margin);
// The same with a spacing per index axis (i, j, k).
ImageGeometry fit_grid(const Vec3& lo, const Vec3& hi, const Vec3& spacing, const std::array<double, 9>& direction,
                       double margin);

// Sets every voxel whose centre lies inside `shape` to `label`.
void paint(LabelVolume& labels, const Shape& shape, Label label);

// Sets the voxels inside `shape` that hold `from` to `to` (hollows or carves one bone without touching others).
void repaint(LabelVolume& labels, const Shape& shape, Label from, Label to);

// Paints the union of `body`, grown outwards by `grow_mm`: voxels within `shell_mm` of its surface get `shell_label`,
// deeper ones `inner_label`.
void paint_body(LabelVolume& labels, const std::vector<Shape>& body, Label inner_label, Label shell_label,
                double shell_mm, double grow_mm = 0.0);

// A CT on the labels' grid: `hu_of(label)` plus deterministic noise of amplitude `noise_hu`.
IntensityVolume synthesize_ct(const LabelVolume& labels, const std::vector<std::pair<Label, float>>& hu_table,
                              float background_hu, double noise_hu, uint64_t seed);

}  // namespace posewarp::phantom::detail
