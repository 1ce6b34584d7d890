// Parameter checks and grid fitting shared by the phantoms.
#include "support.h"

#include <algorithm>
#include <cmath>
#include <string>

namespace posewarp::phantom::detail {

Status validate_direction(const std::array<double, 9>& d) {
  ImageGeometry probe;
  probe.size = {1, 1, 1};
  probe.direction = d;
  return probe.validate().with_context("phantom direction");
}

Status check_positive(double value, const char* name) {
  if (!(value > 0.0) || !std::isfinite(value)) {
    return invalid_argument_error(std::string(name) + " must be positive and finite (got " + std::to_string(value) +
                                  ")");
  }
  return ok_status();
}

Status check_size(const ImageGeometry& g) {
  constexpr int64_t kMaxPhantomVoxels = int64_t{1} << 30;
  if (g.voxel_count() > kMaxPhantomVoxels) {
    return resource_exhausted_error("the phantom would have " + std::to_string(g.voxel_count()) + " voxels (" +
                                    g.describe() + "); use a coarser spacing");
  }
  return ok_status();
}

ImageGeometry grid_for(const std::vector<Shape>& shapes, const Vec3& spacing, const std::array<double, 9>& direction,
                       double margin) {
  Vec3 lo{kInf, kInf, kInf};
  Vec3 hi{-kInf, -kInf, -kInf};
  for (const Shape& shape : shapes) {
    Vec3 slo{};
    Vec3 shi{};
    shape.bounds(slo, shi);
    for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], slo[a]), hi[a] = std::max(hi[a], shi[a]);
  }
  return fit_grid(lo, hi, spacing, direction, margin);
}

std::vector<LabelEntry> tissue_entries() {
  return {{0, "background", LabelRole::kBackground, ""},
          {kSoftLabel, "soft_tissue", LabelRole::kTissue, ""},
          {kFatLabel, "fat", LabelRole::kTissue, ""},
          {kLiverLabel, "liver", LabelRole::kTissue, ""},
          {kBrainLabel, "brain", LabelRole::kTissue, ""}};
}

std::vector<LabelEntry> lumbar_entries(Label l5_value) {
  std::vector<LabelEntry> entries;
  for (int n = 5; n >= 1; --n) {
    const std::string name = "vertebrae_L" + std::to_string(n);
    entries.push_back({l5_value + (5 - n), name, LabelRole::kBone, name});
  }
  return entries;
}

}  // namespace posewarp::phantom::detail
