// Rasterizing signed-distance primitives onto label grids.
#include "raster.h"

#include <algorithm>
#include <cmath>
#include <unordered_map>

#include "posewarp/common/parallel.h"

namespace posewarp::phantom::detail {
namespace {

// The signed distance to a finite cylinder from the signed distances to its side and to its end caps: outside both,
// the distance to the rim.
double capped(double radial, double axial) {
  return radial > 0.0 && axial > 0.0 ? std::hypot(radial, axial) : std::max(radial, axial);
}

double dot(const Vec3& u, const Vec3& v) { return u[0] * v[0] + u[1] * v[1] + u[2] * v[2]; }
Vec3 sub(const Vec3& u, const Vec3& v) { return {u[0] - v[0], u[1] - v[1], u[2] - v[2]}; }
double norm(const Vec3& u) { return std::sqrt(dot(u, u)); }
Vec3 cross(const Vec3& u, const Vec3& v) {
  return {u[1] * v[2] - u[2] * v[1], u[2] * v[0] - u[0] * v[2], u[0] * v[1] - u[1] * v[0]};
}
double sign(double x) { return x > 0.0 ? 1.0 : x < 0.0 ? -1.0 : 0.0; }

// Distance from p to segment [a, b], and the segment parameter of the closest point (unclamped).
double segment_parameter(const Vec3& p, const Vec3& a, const Vec3& b) {
  const Vec3 ab = sub(b, a);
  const double length2 = dot(ab, ab);
  return length2 > 0.0 ? dot(sub(p, a), ab) / length2 : 0.0;
}

// A SplitMix64 step: a well-mixed 64-bit hash for deterministic noise.
uint64_t mix(uint64_t x) {
  x += 0x9e3779b97f4a7c15ULL;
  x = (x ^ (x >> 30)) * 0xbf58476d1ce4e5b9ULL;
  x = (x ^ (x >> 27)) * 0x94d049bb133111ebULL;
  return x ^ (x >> 31);
}

// Index box [lo, hi] (inclusive) of the voxels whose centres may lie in the physical box, clamped to the grid.
bool index_box(const ImageGeometry& g, const Vec3& lo, const Vec3& hi, Index3& first, Index3& last) {
  Vec3 imin{kInf, kInf, kInf};
  Vec3 imax{-kInf, -kInf, -kInf};
  for (int corner = 0; corner < 8; ++corner) {
    const Vec3 p{(corner & 1) ? hi[0] : lo[0], (corner & 2) ? hi[1] : lo[1], (corner & 4) ? hi[2] : lo[2]};
    const Vec3 index = g.physical_to_index(p);
    for (int a = 0; a < 3; ++a) {
      imin[a] = std::min(imin[a], index[a]);
      imax[a] = std::max(imax[a], index[a]);
    }
  }
  for (int a = 0; a < 3; ++a) {
    first[a] = std::max<int64_t>(0, static_cast<int64_t>(std::floor(imin[a])));
    last[a] = std::min<int64_t>(g.size[a] - 1, static_cast<int64_t>(std::ceil(imax[a])));
    if (first[a] > last[a]) return false;
  }
  return true;
}

// Calls visit(offset, physical point) for every voxel of the index box, slices in parallel.
template <typename Visit>
void for_each_voxel(const ImageGeometry& g, const Index3& first, const Index3& last, const Visit& visit) {
  parallel_for(first[2], last[2] + 1, 1, [&](int64_t k0, int64_t k1) {
    for (int64_t k = k0; k < k1; ++k) {
      for (int64_t j = first[1]; j <= last[1]; ++j) {
        for (int64_t i = first[0]; i <= last[0]; ++i) {
          const Vec3 p = g.index_to_physical({static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)});
          visit(g.offset(i, j, k), p);
        }
      }
    }
  });
}

}  // namespace

double Shape::sdf(const Vec3& p) const {
  double d = 0.0;
  switch (kind) {
    case Kind::kSphere: d = norm(sub(p, a)) - radius; break;
    case Kind::kCapsule: {
      const double t = std::clamp(segment_parameter(p, a, b), 0.0, 1.0);
      const Vec3 closest{a[0] + t * (b[0] - a[0]), a[1] + t * (b[1] - a[1]), a[2] + t * (b[2] - a[2])};
      d = norm(sub(p, closest)) - radius;
      break;
    }
    case Kind::kCylinder: {
      const Vec3 axis = sub(b, a);
      const double length = norm(axis);
      const double along = dot(sub(p, a), axis) / length;  // mm from a along the axis
      const Vec3 foot{a[0] + axis[0] * along / length, a[1] + axis[1] * along / length,
                      a[2] + axis[2] * along / length};
      const double radial = norm(sub(p, foot)) - radius;
      const double axial = std::max(-along, along - length);
      d = capped(radial, axial);
      break;
    }
    case Kind::kEllipticCylinderZ: {
      const double u = (p[0] - a[0]) / radii[0];
      const double v = (p[1] - a[1]) / radii[1];
      const double radial = (std::sqrt(u * u + v * v) - 1.0) * std::min(radii[0], radii[1]);
      const double axial = std::max(b[0] - p[2], p[2] - b[1]);
      d = capped(radial, axial);
      break;
    }
    case Kind::kEllipsoid: {
      const double u = (p[0] - a[0]) / radii[0];
      const double v = (p[1] - a[1]) / radii[1];
      const double w = (p[2] - a[2]) / radii[2];
      d = (std::sqrt(u * u + v * v + w * w) - 1.0) * std::min({radii[0], radii[1], radii[2]});
      break;
    }
    case Kind::kBox: {
      Vec3 outside{};
      double inside = -kInf;
      for (int axis = 0; axis < 3; ++axis) {
        const double q = std::max(a[axis] - p[axis], p[axis] - b[axis]);
        outside[axis] = std::max(q, 0.0);
        inside = std::max(inside, q);
      }
      d = norm(outside) + std::min(inside, 0.0);
      break;
    }
    case Kind::kRoundCone: {
      // Quilez's exact round-cone distance (one square root per branch).
      const double r1 = radius;
      const double r2 = radii[0];
      const Vec3 ba = sub(b, a);
      const Vec3 pa = sub(p, a);
      const double l2 = dot(ba, ba);
      const double rr = r1 - r2;
      const double a2 = l2 - rr * rr;
      const double il2 = 1.0 / l2;
      const double y = dot(pa, ba);
      const double z = y - l2;
      const Vec3 xv{pa[0] * l2 - ba[0] * y, pa[1] * l2 - ba[1] * y, pa[2] * l2 - ba[2] * y};
      const double x2 = dot(xv, xv);
      const double y2 = y * y * l2;
      const double z2 = z * z * l2;
      const double k = sign(rr) * rr * rr * x2;
      if (sign(z) * a2 * z2 > k) {
        d = std::sqrt(x2 + z2) * il2 - r2;
      } else if (sign(y) * a2 * y2 < k) {
        d = std::sqrt(x2 + y2) * il2 - r1;
      } else {
        d = (std::sqrt(x2 * a2 * il2) + y * rr) * il2 - r1;
      }
      break;
    }
    case Kind::kSphericalCup: {
      const Vec3 q = sub(p, a);
      const double r = norm(q);
      const double shell = std::max(radius - r, r - radii[0]);
      const double cos_angle = r > 0.0 ? std::clamp(dot(q, b) / r, -1.0, 1.0) : 1.0;
      const double beyond = std::acos(cos_angle) - radii[1];  // radians past the rim (negative inside)
      const double cone = r * std::sin(std::min(beyond, 0.5 * 3.14159265358979323846));
      d = std::max(shell, cone);
      break;
    }
    case Kind::kOrientedBox: {
      const Vec3 q = sub(p, a);
      const Vec3 w = cross(axis_u, axis_v);
      const Vec3 local{dot(q, axis_u), dot(q, axis_v), dot(q, w)};
      Vec3 outside{};
      double inside = -kInf;
      for (int axis = 0; axis < 3; ++axis) {
        const double e = std::abs(local[axis]) - (b[axis] - radius);
        outside[axis] = std::max(e, 0.0);
        inside = std::max(inside, e);
      }
      d = norm(outside) + std::min(inside, 0.0) - radius;
      break;
    }
  }
  for (int axis = 0; axis < 3; ++axis) {
    if (p[axis] < clip_min[axis] || p[axis] > clip_max[axis]) return std::max(d, 1e-9);
  }
  return d;
}

bool Shape::contains(const Vec3& p) const { return sdf(p) <= 0.0; }

void Shape::bounds(Vec3& lo, Vec3& hi) const {
  switch (kind) {
    case Kind::kSphere:
      for (int i = 0; i < 3; ++i) lo[i] = a[i] - radius, hi[i] = a[i] + radius;
      break;
    case Kind::kCapsule:
    case Kind::kCylinder:
      for (int i = 0; i < 3; ++i) lo[i] = std::min(a[i], b[i]) - radius, hi[i] = std::max(a[i], b[i]) + radius;
      break;
    case Kind::kEllipticCylinderZ:
      lo = {a[0] - radii[0], a[1] - radii[1], b[0]};
      hi = {a[0] + radii[0], a[1] + radii[1], b[1]};
      break;
    case Kind::kEllipsoid:
      for (int i = 0; i < 3; ++i) lo[i] = a[i] - radii[i], hi[i] = a[i] + radii[i];
      break;
    case Kind::kBox:
      lo = a;
      hi = b;
      break;
    case Kind::kRoundCone: {
      const double r = std::max(radius, radii[0]);
      for (int i = 0; i < 3; ++i) lo[i] = std::min(a[i], b[i]) - r, hi[i] = std::max(a[i], b[i]) + r;
      break;
    }
    case Kind::kSphericalCup:
      for (int i = 0; i < 3; ++i) lo[i] = a[i] - radii[0], hi[i] = a[i] + radii[0];
      break;
    case Kind::kOrientedBox: {
      const Vec3 w = cross(axis_u, axis_v);
      for (int i = 0; i < 3; ++i) {
        const double extent = std::abs(axis_u[i]) * b[0] + std::abs(axis_v[i]) * b[1] + std::abs(w[i]) * b[2];
        lo[i] = a[i] - extent;
        hi[i] = a[i] + extent;
      }
      break;
    }
  }
  for (int i = 0; i < 3; ++i) {
    lo[i] = std::max(lo[i], clip_min[i]);
    hi[i] = std::min(hi[i], clip_max[i]);
  }
}

namespace {

// A shape of `kind` from its fields (what each means for each kind: Shape's comments).
Shape shape(Shape::Kind kind, const Vec3& a, const Vec3& b = {}, double radius = 0.0, const Vec3& radii = {}) {
  Shape s;
  s.kind = kind;
  s.a = a;
  s.b = b;
  s.radius = radius;
  s.radii = radii;
  return s;
}

}  // namespace

Shape sphere(const Vec3& centre, double radius) { return shape(Shape::Kind::kSphere, centre, {}, radius); }

Shape capsule(const Vec3& a, const Vec3& b, double radius) { return shape(Shape::Kind::kCapsule, a, b, radius); }

Shape cylinder(const Vec3& a, const Vec3& b, double radius) { return shape(Shape::Kind::kCylinder, a, b, radius); }

Shape elliptic_cylinder_z(double cx, double cy, double rx, double ry, double z_min, double z_max) {
  return shape(Shape::Kind::kEllipticCylinderZ, {cx, cy, 0.0}, {z_min, z_max, 0.0}, 0.0, {rx, ry, 0.0});
}

Shape ellipsoid(const Vec3& centre, const Vec3& radii) {
  return shape(Shape::Kind::kEllipsoid, centre, {}, 0.0, radii);
}

Shape box(const Vec3& lo, const Vec3& hi) { return shape(Shape::Kind::kBox, lo, hi); }

Shape round_cone(const Vec3& a, const Vec3& b, double radius_a, double radius_b) {
  return shape(Shape::Kind::kRoundCone, a, b, radius_a, {radius_b, 0.0, 0.0});
}

Shape spherical_cup(const Vec3& centre, const Vec3& pole, double inner_radius, double outer_radius,
                    double half_angle) {
  const double length = norm(pole);
  return shape(Shape::Kind::kSphericalCup, centre, {pole[0] / length, pole[1] / length, pole[2] / length},
               inner_radius, {outer_radius, half_angle, 0.0});
}

Shape oriented_box(const Vec3& centre, const Vec3& u, const Vec3& v, const Vec3& half_extents, double rounding) {
  Shape s = shape(Shape::Kind::kOrientedBox, centre, half_extents, rounding);
  s.axis_u = u;
  s.axis_v = v;
  return s;
}

ImageGeometry fit_grid(const Vec3& lo, const Vec3& hi, double spacing, const std::array<double, 9>& direction,
                       double margin) {
  return fit_grid(lo, hi, Vec3{spacing, spacing, spacing}, direction, margin);
}

ImageGeometry fit_grid(const Vec3& lo, const Vec3& hi, const Vec3& spacing, const std::array<double, 9>& direction,
                       double margin) {
  ImageGeometry g;
  g.spacing = spacing;
  g.direction = direction;
  // Extent of the box along each grid axis (columns of the direction matrix).
  Vec3 origin{0.0, 0.0, 0.0};
  for (int axis = 0; axis < 3; ++axis) {
    const Vec3 column{direction[axis], direction[3 + axis], direction[6 + axis]};
    double min_proj = kInf;
    double max_proj = -kInf;
    for (int corner = 0; corner < 8; ++corner) {
      const Vec3 p{(corner & 1) ? hi[0] : lo[0], (corner & 2) ? hi[1] : lo[1], (corner & 4) ? hi[2] : lo[2]};
      const double proj = dot(p, column);
      min_proj = std::min(min_proj, proj);
      max_proj = std::max(max_proj, proj);
    }
    min_proj -= margin;
    max_proj += margin;
    g.size[axis] = static_cast<int64_t>(std::ceil((max_proj - min_proj) / spacing[axis])) + 1;
    for (int r = 0; r < 3; ++r) origin[r] += column[r] * min_proj;
  }
  g.origin = origin;
  return g;
}

namespace {

// Sets every voxel inside `shape` whose value `wanted` accepts (checked first: it is cheaper) to `label`.
template <typename Wanted>
void set_inside(LabelVolume& labels, const Shape& shape, Label label, const Wanted& wanted) {
  Vec3 lo{};
  Vec3 hi{};
  shape.bounds(lo, hi);
  Index3 first{};
  Index3 last{};
  if (!index_box(labels.geometry(), lo, hi, first, last)) return;
  Label* out = labels.data();
  for_each_voxel(labels.geometry(), first, last, [&](int64_t offset, const Vec3& p) {
    if (wanted(out[offset]) && shape.contains(p)) out[offset] = label;
  });
}

}  // namespace

void paint(LabelVolume& labels, const Shape& shape, Label label) {
  set_inside(labels, shape, label, [](Label) { return true; });
}

void repaint(LabelVolume& labels, const Shape& shape, Label from, Label to) {
  set_inside(labels, shape, to, [from](Label value) { return value == from; });
}

void paint_body(LabelVolume& labels, const std::vector<Shape>& body, Label inner_label, Label shell_label,
                double shell_mm, double grow_mm) {
  Vec3 lo{kInf, kInf, kInf};
  Vec3 hi{-kInf, -kInf, -kInf};
  std::vector<std::pair<Vec3, Vec3>> shape_bounds(body.size());
  for (size_t s = 0; s < body.size(); ++s) {
    Vec3& slo = shape_bounds[s].first;
    Vec3& shi = shape_bounds[s].second;
    body[s].bounds(slo, shi);
    for (int a = 0; a < 3; ++a) {
      slo[a] -= grow_mm, shi[a] += grow_mm;
      lo[a] = std::min(lo[a], slo[a]), hi[a] = std::max(hi[a], shi[a]);
    }
  }
  Index3 first{};
  Index3 last{};
  if (!index_box(labels.geometry(), lo, hi, first, last)) return;
  Label* out = labels.data();
  for_each_voxel(labels.geometry(), first, last, [&](int64_t offset, const Vec3& p) {
    // A shape whose bounds miss p has a positive distance there, so it cannot change a depth d <= 0: skipping it
    // gives the same labels, faster.
    double d = kInf;
    for (size_t s = 0; s < body.size(); ++s) {
      const Vec3& slo = shape_bounds[s].first;
      const Vec3& shi = shape_bounds[s].second;
      if (p[0] < slo[0] || p[1] < slo[1] || p[2] < slo[2] || p[0] > shi[0] || p[1] > shi[1] || p[2] > shi[2]) {
        continue;
      }
      d = std::min(d, body[s].sdf(p) - grow_mm);
    }
    if (d <= 0.0) out[offset] = d > -shell_mm ? shell_label : inner_label;
  });
}

IntensityVolume synthesize_ct(const LabelVolume& labels, const std::vector<std::pair<Label, float>>& hu_table,
                              float background_hu, double noise_hu, uint64_t seed) {
  IntensityVolume ct(labels.geometry(), background_hu);
  ct.set_source_type(PixelType::kInt16);
  std::unordered_map<Label, float> hu(hu_table.begin(), hu_table.end());
  const Label* in = labels.data();
  float* out = ct.data();
  const uint64_t salt = mix(seed);
  parallel_for(0, labels.voxel_count(), 1 << 16, [&](int64_t begin, int64_t end) {
    for (int64_t v = begin; v < end; ++v) {
      auto it = hu.find(in[v]);
      const float base = it == hu.end() ? background_hu : it->second;
      // Uniform noise in [-noise, noise], rounded to whole HU like a real scanner's integers.
      const double unit = static_cast<double>(mix(salt ^ static_cast<uint64_t>(v)) >> 11) * 0x1.0p-53;
      out[v] = static_cast<float>(std::round(base + noise_hu * (2.0 * unit - 1.0)));
    }
  });
  return ct;
}

}  // namespace posewarp::phantom::detail
