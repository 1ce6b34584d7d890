// ImageGeometry: index <-> physical conversion and validation.
#include "posewarp/common/image_geometry.h"

#include <cmath>
#include <sstream>

namespace posewarp {
namespace {

// Inverse of a 3x3 row-major matrix; the caller guarantees it is invertible.
std::array<double, 9> inverse3(const std::array<double, 9>& m) {
  const double c00 = m[4] * m[8] - m[5] * m[7];
  const double c01 = m[5] * m[6] - m[3] * m[8];
  const double c02 = m[3] * m[7] - m[4] * m[6];
  const double det = m[0] * c00 + m[1] * c01 + m[2] * c02;
  const double s = 1.0 / det;
  return {c00 * s,
          (m[2] * m[7] - m[1] * m[8]) * s,
          (m[1] * m[5] - m[2] * m[4]) * s,
          c01 * s,
          (m[0] * m[8] - m[2] * m[6]) * s,
          (m[2] * m[3] - m[0] * m[5]) * s,
          c02 * s,
          (m[1] * m[6] - m[0] * m[7]) * s,
          (m[0] * m[4] - m[1] * m[3]) * s};
}

}  // namespace

Vec3 ImageGeometry::index_to_physical(const Vec3& index) const {
  const Vec3 scaled{index[0] * spacing[0], index[1] * spacing[1], index[2] * spacing[2]};
  Vec3 point{};
  for (int r = 0; r < 3; ++r) {
    point[r] = origin[r] + direction[3 * r] * scaled[0] + direction[3 * r + 1] * scaled[1] +
               direction[3 * r + 2] * scaled[2];
  }
  return point;
}

Vec3 ImageGeometry::physical_to_index(const Vec3& point) const {
  return PhysicalToIndex(*this)(point);
}

PhysicalToIndex::PhysicalToIndex(const ImageGeometry& geometry)
    : inverse_(inverse3(geometry.direction)), origin_(geometry.origin), spacing_(geometry.spacing) {}

bool ImageGeometry::same_grid(const ImageGeometry& other, double tolerance) const {
  if (size != other.size) return false;
  for (int a = 0; a < 3; ++a) {
    if (std::abs(spacing[a] - other.spacing[a]) > tolerance) return false;
    if (std::abs(origin[a] - other.origin[a]) > tolerance) return false;
  }
  for (int e = 0; e < 9; ++e) {
    if (std::abs(direction[e] - other.direction[e]) > tolerance) return false;
  }
  return true;
}

Status ImageGeometry::validate() const {
  for (int a = 0; a < 3; ++a) {
    if (size[a] <= 0) {
      return invalid_argument_error("image size " + std::to_string(size[0]) + " x " + std::to_string(size[1]) +
                                    " x " + std::to_string(size[2]) + " has a non-positive dimension");
    }
    if (!(spacing[a] > 0.0) || !std::isfinite(spacing[a])) {
      std::ostringstream out;
      out << "voxel spacing along axis " << a << " is " << spacing[a]
          << " mm; spacing must be positive and finite (fix the image header)";
      return invalid_argument_error(out.str());
    }
    if (!std::isfinite(origin[a])) return invalid_argument_error("image origin is not finite (fix the image header)");
  }
  // voxel_count() multiplies the sizes, and callers multiply it by up to 8 bytes: a crafted size overflowed it
  // (found by fuzzing the rig reader). Below 2^60 voxels every product fits; real limits (a voxel budget, RESOURCE_
  // EXHAUSTED) are the callers'.
  constexpr int64_t kMaxVoxels = int64_t{1} << 60;
  if (size[0] > kMaxVoxels / size[1] || size[0] * size[1] > kMaxVoxels / size[2]) {
    return invalid_argument_error("image size " + std::to_string(size[0]) + " x " + std::to_string(size[1]) + " x " +
                                  std::to_string(size[2]) + " is beyond any image (over 2^60 voxels)");
  }
  // Columns must be orthonormal: D^T D = I.
  for (int c1 = 0; c1 < 3; ++c1) {
    for (int c2 = 0; c2 < 3; ++c2) {
      double dot = 0.0;
      for (int r = 0; r < 3; ++r) dot += direction[3 * r + c1] * direction[3 * r + c2];
      const double expected = c1 == c2 ? 1.0 : 0.0;
      if (!std::isfinite(dot) || std::abs(dot - expected) > 1e-3) {
        return invalid_argument_error(
            "image direction matrix is not orthonormal (sheared or degenerate orientation in the header); "
            "re-save the image with a proper orientation");
      }
    }
  }
  return ok_status();
}

std::string ImageGeometry::describe() const {
  std::ostringstream out;
  out << size[0] << " x " << size[1] << " x " << size[2] << " voxels, " << spacing[0] << " x " << spacing[1]
      << " x " << spacing[2] << " mm";
  return out.str();
}

std::array<double, 9> rotation_direction(Vec3 axis, double degrees) {
  const double length = std::sqrt(axis[0] * axis[0] + axis[1] * axis[1] + axis[2] * axis[2]);
  const Vec3 n{axis[0] / length, axis[1] / length, axis[2] / length};
  const double a = degrees * M_PI / 180.0;
  const double c = std::cos(a);
  const double s = std::sin(a);
  const double t = 1.0 - c;
  return {t * n[0] * n[0] + c,        t * n[0] * n[1] - s * n[2], t * n[0] * n[2] + s * n[1],
          t * n[0] * n[1] + s * n[2], t * n[1] * n[1] + c,        t * n[1] * n[2] - s * n[0],
          t * n[0] * n[2] - s * n[1], t * n[1] * n[2] + s * n[0], t * n[2] * n[2] + c};
}

}  // namespace posewarp
