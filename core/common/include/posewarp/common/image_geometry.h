// ImageGeometry: a voxel grid placed in physical space (ITK's LPS, millimetres).
#pragma once

#include <array>
#include <cstdint>
#include <string>

#include "posewarp/common/status.h"

namespace posewarp {

using Vec3 = std::array<double, 3>;
using Index3 = std::array<int64_t, 3>;

// A voxel grid: size in voxels, spacing and origin in mm, and a direction matrix whose column j is the unit
// direction of index axis j in LPS. Stored row-major: direction[3 * row + column].
// physical = origin + direction * diag(spacing) * index, exactly as ITK defines it.
struct ImageGeometry {
  Index3 size{0, 0, 0};
  Vec3 spacing{1.0, 1.0, 1.0};
  Vec3 origin{0.0, 0.0, 0.0};
  std::array<double, 9> direction{1, 0, 0, 0, 1, 0, 0, 0, 1};

  int64_t voxel_count() const { return size[0] * size[1] * size[2]; }

  // Linear offset of voxel (i, j, k) in an x-fastest buffer.
  int64_t offset(int64_t i, int64_t j, int64_t k) const { return i + size[0] * (j + size[1] * k); }

  // Physical point (mm, LPS) of a continuous index.
  Vec3 index_to_physical(const Vec3& index) const;
  // Continuous index of a physical point (mm, LPS); inverse of index_to_physical.
  Vec3 physical_to_index(const Vec3& point) const;

  // True when every field agrees within `tolerance` (mm for origin and spacing, unitless for direction).
  bool same_grid(const ImageGeometry& other, double tolerance = 1e-4) const;

  // INVALID_ARGUMENT unless sizes are positive, spacings positive and finite, origin finite and the direction
  // matrix orthonormal to 1e-3.
  Status validate() const;

  // "122 x 101 x 112 voxels, 3 x 3 x 3 mm"
  std::string describe() const;
};

// ImageGeometry::physical_to_index for many points: the direction's inverse worked out once instead of per point
// (the same arithmetic, so the same indices).
class PhysicalToIndex {
 public:
  explicit PhysicalToIndex(const ImageGeometry& geometry);
  Vec3 operator()(const Vec3& point) const {
    const Vec3 d{point[0] - origin_[0], point[1] - origin_[1], point[2] - origin_[2]};
    Vec3 index{};
    for (int r = 0; r < 3; ++r) {
      index[r] = (inverse_[3 * r] * d[0] + inverse_[3 * r + 1] * d[1] + inverse_[3 * r + 2] * d[2]) / spacing_[r];
    }
    return index;
  }

 private:
  std::array<double, 9> inverse_;
  Vec3 origin_, spacing_;
};

// The direction matrix (row-major, columns = index axes in LPS) of a rotation by `degrees` about `axis` (any
// non-zero length), by Rodrigues' formula.
std::array<double, 9> rotation_direction(Vec3 axis, double degrees);

}  // namespace posewarp
