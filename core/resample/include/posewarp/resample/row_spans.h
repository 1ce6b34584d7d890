// Per row of a volume, the stretch outside which every voxel holds one value: a lookup that crosses the source rows
// (the background's map where the root moved) needs no load for a voxel it already knows, and most of a body's grid
// is air around it (the body phantom's labels: 14% of each row's voxels lie between its first and last non-zero).
// A per-voxel table can be kept on its spans alone (posewarp/common/row_packed.h).
#pragma once

#include <cstdint>
#include <vector>

#include "posewarp/common/image_geometry.h"

namespace posewarp::resample {

struct RowSpans {
  static constexpr int64_t kMaxRow = 65535;  // a longer row has no spans: every voxel of the grid is looked up
  Index3 size{0, 0, 0};                      // the grid's
  int32_t fill = 0;                          // the value of every voxel off its row's span
  // Per row (y + size[1] z): lo | hi << 16, its voxels [lo, hi) that may hold another value than `fill` (none where
  // lo == hi). Empty when the grid's rows are longer than kMaxRow.
  std::vector<uint32_t> span;

  bool empty() const { return span.empty(); }
  // Whether every voxel of the index box [lo, hi] (inclusive, axes x y z) that lies on the grid holds `fill`: the
  // box's rows looked up, none of its voxels. True for a box off the grid; false without spans.
  bool only_fill(const int64_t lo[3], const int64_t hi[3]) const;
};

// The spans of `values` (a grid of size m, x fastest) around `fill`, rows in parallel: one read of each row's ends.
RowSpans row_spans(const int32_t* values, const Index3& m, int32_t fill);

}  // namespace posewarp::resample
