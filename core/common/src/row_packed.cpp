#include "posewarp/common/row_packed.h"

#include <algorithm>
#include <limits>

#include "posewarp/common/parallel.h"

namespace posewarp {

template <typename T>
RowPacked<T> RowPacked<T>::pack(const T* values, const Index3& m, T fill, bool whole_rows, const uint32_t* spans) {
  RowPacked packed;
  packed.size_ = m;
  packed.fill_ = fill;
  const int64_t voxels = packed.voxel_count();
  if (voxels <= 0) return packed;
  const int64_t rows = m[1] * m[2];
  if (m[0] > kMaxRow || voxels > std::numeric_limits<int32_t>::max()) {
    packed.values_.assign(values, values + voxels);
    return packed;
  }
  // Each row's span, then where its values begin (a sum over the rows), then the values, rows in parallel.
  std::vector<int64_t> first(static_cast<size_t>(rows) + 1, 0);
  packed.rows_.resize(static_cast<size_t>(rows));
  parallel_for(0, rows, 1024, [&](int64_t begin, int64_t end) {
    for (int64_t r = begin; r < end; ++r) {
      int64_t lo = 0, hi = m[0];
      if (spans && !whole_rows) {
        lo = spans[r] & 0xffff, hi = spans[r] >> 16;
      } else if (!whole_rows) {
        row_span(values + r * m[0], m[0], fill, lo, hi);
      }
      packed.rows_[static_cast<size_t>(r)] = static_cast<uint64_t>(lo) << 32 | static_cast<uint64_t>(hi) << 48;
      first[static_cast<size_t>(r) + 1] = hi - lo;
    }
  });
  for (int64_t r = 0; r < rows; ++r) first[static_cast<size_t>(r) + 1] += first[static_cast<size_t>(r)];
  packed.values_.resize(static_cast<size_t>(first[static_cast<size_t>(rows)]));
  parallel_for(0, rows, 1024, [&](int64_t begin, int64_t end) {
    for (int64_t r = begin; r < end; ++r) {
      uint64_t& e = packed.rows_[static_cast<size_t>(r)];
      const int64_t lo = static_cast<int64_t>(e >> 32 & 0xffff), hi = static_cast<int64_t>(e >> 48);
      const int64_t at = first[static_cast<size_t>(r)];
      std::copy(values + r * m[0] + lo, values + r * m[0] + hi, packed.values_.begin() + at);
      e |= static_cast<uint32_t>(static_cast<int32_t>(at - lo));  // fits: the grid holds fewer than 2^31 voxels
    }
  });
  return packed;
}

namespace {

// Calls piece(row, x, n, value) for each piece of the runs within one row, in order: n voxels of `value` from x on.
template <typename T, typename Piece>
void for_each_piece(const T* values, const uint32_t* lengths, size_t runs, int64_t width, const Piece& piece) {
  int64_t row = 0, x = 0;
  for (size_t q = 0; q < runs; ++q) {
    int64_t left = lengths[q];
    while (left > 0) {
      const int64_t n = std::min(left, width - x);
      piece(row, x, n, values[q]);
      left -= n;
      x += n;
      if (x == width) x = 0, ++row;
    }
  }
}

}  // namespace

template <typename T>
RowPacked<T> RowPacked<T>::from_runs(const T* values, const uint32_t* lengths, size_t runs, const Index3& m, T fill) {
  RowPacked packed;
  packed.size_ = m;
  packed.fill_ = fill;
  const int64_t voxels = packed.voxel_count();
  if (voxels <= 0) return packed;
  if (m[0] > kMaxRow || voxels > std::numeric_limits<int32_t>::max()) {
    packed.values_.reserve(static_cast<size_t>(voxels));
    for (size_t q = 0; q < runs; ++q) packed.values_.insert(packed.values_.end(), lengths[q], values[q]);
    return packed;
  }
  // Each row's span: from its first to its last voxel of a run of another value than the fill.
  const int64_t rows = m[1] * m[2];
  std::vector<int64_t> lo(static_cast<size_t>(rows), m[0]), hi(static_cast<size_t>(rows), 0);
  for_each_piece(values, lengths, runs, m[0], [&](int64_t r, int64_t x, int64_t n, T value) {
    if (value == fill) return;
    lo[static_cast<size_t>(r)] = std::min(lo[static_cast<size_t>(r)], x);
    hi[static_cast<size_t>(r)] = std::max(hi[static_cast<size_t>(r)], x + n);
  });
  packed.rows_.resize(static_cast<size_t>(rows));
  int64_t at = 0;
  for (int64_t r = 0; r < rows; ++r) {
    int64_t& l = lo[static_cast<size_t>(r)];
    int64_t& h = hi[static_cast<size_t>(r)];
    if (l >= h) l = h = 0;
    packed.rows_[static_cast<size_t>(r)] = static_cast<uint32_t>(static_cast<int32_t>(at - l)) |
                                           static_cast<uint64_t>(l) << 32 | static_cast<uint64_t>(h) << 48;
    at += h - l;
  }
  // Then the values on the spans (each voxel of a span is in some run).
  packed.values_.resize(static_cast<size_t>(at));
  for_each_piece(values, lengths, runs, m[0], [&](int64_t r, int64_t x, int64_t n, T value) {
    const int64_t from = std::max(x, lo[static_cast<size_t>(r)]), to = std::min(x + n, hi[static_cast<size_t>(r)]);
    if (from >= to) return;
    const int64_t base = static_cast<int32_t>(packed.rows_[static_cast<size_t>(r)]);
    std::fill_n(packed.values_.begin() + (base + from), to - from, value);
  });
  return packed;
}

template <typename T>
bool RowPacked<T>::only_fill(const int64_t lo[3], const int64_t hi[3]) const {
  if (rows_.empty() && !empty()) return false;
  return box_off_spans(size_, lo, hi, [&](int64_t r) {
    const uint64_t e = rows_[static_cast<size_t>(r)];
    return std::pair{static_cast<int64_t>(e >> 32 & 0xffff), static_cast<int64_t>(e >> 48)};
  });
}

template <typename T>
std::vector<T> RowPacked<T>::unpacked() const {
  std::vector<T> out(static_cast<size_t>(voxel_count()), fill_);
  const int64_t rows = size_[1] * size_[2];
  parallel_for(0, rows, 1024, [&](int64_t begin, int64_t end) {
    for (int64_t r = begin; r < end; ++r) {
      int64_t lo = 0, hi = 0;
      const T* span = row(r % size_[1], r / size_[1], lo, hi);
      std::copy(span, span + (hi - lo), out.begin() + (r * size_[0] + lo));
    }
  });
  return out;
}

template class RowPacked<int32_t>;
template class RowPacked<int16_t>;

}  // namespace posewarp
