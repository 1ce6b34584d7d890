// A per-voxel table kept on its rows' spans: each row holds, between its first and last voxel of another value than
// the table's fill, its values; every voxel off that span holds the fill. Most of a body's grid is air around it, so
// its owner and region tables (a tet, a region, or none) take a fraction of the grid's bytes this way (the body
// phantom's rest owners: 15% of their voxels), and a lookup that lands off a row's span needs no load.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <utility>
#include <vector>

#include "posewarp/common/image_geometry.h"

namespace posewarp {

// The span of a row of n values around `fill`: [lo, hi) from its first to past its last other value; lo == hi == 0
// for a row of the fill alone.
template <typename T>
inline void row_span(const T* row, int64_t n, T fill, int64_t& lo, int64_t& hi) {
  lo = 0, hi = n;
  while (lo < hi && row[lo] == fill) ++lo;
  while (hi > lo && row[hi - 1] == fill) --hi;
  if (lo == hi) lo = hi = 0;
}

// Whether the index box [lo, hi] (inclusive, axes x y z) meets no span of the rows of grid m it lies on (true for a
// box off the grid): span_of(row) gives row y + m[1] z's span as a pair [lo, hi).
template <typename SpanOf>
bool box_off_spans(const Index3& m, const int64_t lo[3], const int64_t hi[3], const SpanOf& span_of) {
  const int64_t x0 = std::max<int64_t>(lo[0], 0), x1 = std::min(hi[0], m[0] - 1);
  const int64_t y0 = std::max<int64_t>(lo[1], 0), y1 = std::min(hi[1], m[1] - 1);
  const int64_t z0 = std::max<int64_t>(lo[2], 0), z1 = std::min(hi[2], m[2] - 1);
  if (x0 > x1) return true;
  for (int64_t z = z0; z <= z1; ++z) {
    for (int64_t y = y0; y <= y1; ++y) {
      const auto [a, b] = span_of(y + m[1] * z);
      if (a <= x1 && b > x0) return false;
    }
  }
  return true;
}

// A per-voxel table (a grid's values, x fastest) that keeps each row's span only: every voxel off it holds fill().
// A grid of fewer than 2^31 voxels whose rows are at most kMaxRow long is packed; any other keeps every voxel (the
// same answers, the grid's bytes).
template <typename T>
class RowPacked {
 public:
  static constexpr int64_t kMaxRow = 65535;  // a longer row is not packed
  RowPacked() = default;
  RowPacked(const RowPacked&) = default;
  RowPacked& operator=(const RowPacked&) = default;
  // A table moved from is empty (of no grid), as a vector moved from is.
  RowPacked(RowPacked&& other) noexcept { *this = std::move(other); }
  RowPacked& operator=(RowPacked&& other) noexcept {
    size_ = std::exchange(other.size_, Index3{0, 0, 0});
    fill_ = other.fill_;
    rows_ = std::move(other.rows_);
    values_ = std::move(other.values_);
    other.rows_.clear();
    other.values_.clear();
    return *this;
  }
  // `values` (grid m) packed around `fill`, rows in parallel. With whole_rows every row is kept whole, as packed
  // rows (a table whose lookups never skip: for tests). `spans`, when given, are the rows' spans already found (per
  // row lo | hi << 16, 0 for a row all fill, as RowSpans holds them): they are not looked for again.
  static RowPacked pack(const T* values, const Index3& m, T fill, bool whole_rows = false,
                        const uint32_t* spans = nullptr);
  // The same table from runs of equal values over the grid in order (run q: lengths[q] voxels of values[q]), which
  // must add up to the grid's voxels: two walks over the runs, never the whole grid.
  static RowPacked from_runs(const T* values, const uint32_t* lengths, size_t runs, const Index3& m, T fill);

  const Index3& size() const { return size_; }
  int64_t voxel_count() const { return size_[0] * size_[1] * size_[2]; }
  bool empty() const { return voxel_count() == 0; }
  T fill() const { return fill_; }
  // The value of voxel (x, y, z), which must lie on the grid.
  T at(int64_t x, int64_t y, int64_t z) const {
    const int64_t r = y + size_[1] * z;
    if (rows_.empty()) return values_[static_cast<size_t>(x + size_[0] * r)];
    const uint64_t e = rows_[static_cast<size_t>(r)];
    return x >= static_cast<int64_t>(e >> 32 & 0xffff) && x < static_cast<int64_t>(e >> 48)
               ? values_[static_cast<size_t>(static_cast<int32_t>(e) + x)]
               : fill_;
  }
  // Row (y, z) on the grid: its values for x in [lo, hi) are span[x - lo]; every other voxel of the row holds
  // fill().
  const T* row(int64_t y, int64_t z, int64_t& lo, int64_t& hi) const {
    const int64_t r = y + size_[1] * z;
    if (rows_.empty()) {
      lo = 0, hi = size_[0];
      return values_.data() + size_[0] * r;
    }
    const uint64_t e = rows_[static_cast<size_t>(r)];
    lo = static_cast<int64_t>(e >> 32 & 0xffff), hi = static_cast<int64_t>(e >> 48);
    return values_.data() + (static_cast<int32_t>(e) + lo);
  }
  // Whether every voxel of the index box [lo, hi] (inclusive) that lies on the grid holds fill(); true for a box
  // off the grid, false for a table that keeps every voxel.
  bool only_fill(const int64_t lo[3], const int64_t hi[3]) const;
  // Per row (y + size[1] z), packed: its values' base (int32: value of x at values()[base + x]) | lo << 32 | hi << 48.
  // Empty for a table that keeps every voxel.
  const std::vector<uint64_t>& rows() const { return rows_; }
  const T* values() const { return values_.data(); }
  size_t stored() const { return values_.size(); }  // how many values it keeps (its spans' voxels)
  // The whole grid's values again (tests, and writers of formats that hold every voxel).
  std::vector<T> unpacked() const;
  size_t bytes() const { return rows_.size() * sizeof(uint64_t) + values_.size() * sizeof(T); }

  friend bool operator==(const RowPacked& a, const RowPacked& b) {
    return a.size_ == b.size_ && a.fill_ == b.fill_ && a.rows_ == b.rows_ && a.values_ == b.values_;
  }

 private:
  Index3 size_{0, 0, 0};
  T fill_{};
  std::vector<uint64_t> rows_;
  std::vector<T> values_;
};

extern template class RowPacked<int32_t>;
extern template class RowPacked<int16_t>;

}  // namespace posewarp
