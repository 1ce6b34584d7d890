// Signed-distance primitives and their rasterization onto a label grid (phantom internals).
#pragma once

#include <limits>
#include <vector>

#include "posewarp/common/volume.h"

namespace posewarp::phantom::detail {

constexpr double kInf = std::numeric_limits<double>::infinity();

// A solid in physical space (mm). sdf() is negative inside; exact for spheres, capsules, cylinders and boxes,
// a close approximation for elliptic shapes (good enough to place a fat layer).
struct Shape {
  enum class Kind { kSphere, kCapsule, kCylinder, kEllipticCylinderZ, kEllipsoid, kBox };
  Kind kind = Kind::kSphere;
  Vec3 a{};       // sphere/ellipsoid centre; capsule/cylinder start; elliptic cylinder centre (z ignored); box min
  Vec3 b{};       // capsule/cylinder end; elliptic cylinder (z_min, z_max in b[0], b[1]); box max
  double radius = 0.0;
  Vec3 radii{};   // ellipsoid and elliptic cylinder radii (x, y, -)
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

// A grid with the given spacing and direction that holds [lo, hi] plus a margin on every side.
ImageGeometry fit_grid(const Vec3& lo, const Vec3& hi, double spacing, const std::array<double, 9>& direction,
                       double margin);

// Sets every voxel whose centre lies inside `shape` to `label`.
void paint(LabelVolume& labels, const Shape& shape, Label label);

// Paints the union of `body`: voxels within `shell_mm` of its surface get `shell_label`, deeper ones `inner_label`.
void paint_body(LabelVolume& labels, const std::vector<Shape>& body, Label inner_label, Label shell_label,
                double shell_mm);

// A CT on the labels' grid: `hu_of(label)` plus deterministic noise of amplitude `noise_hu`.
IntensityVolume synthesize_ct(const LabelVolume& labels, const std::vector<std::pair<Label, float>>& hu_table,
                              float background_hu, double noise_hu, uint64_t seed);

}  // namespace posewarp::phantom::detail
