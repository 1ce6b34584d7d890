#include "posewarp/resample/row_spans.h"

#include <algorithm>

#include "posewarp/common/parallel.h"
#include "posewarp/common/row_packed.h"

namespace posewarp::resample {

RowSpans row_spans(const int32_t* values, const Index3& m, int32_t fill) {
  RowSpans spans;
  spans.size = m;
  spans.fill = fill;
  if (m[0] < 1 || m[0] > RowSpans::kMaxRow || m[1] < 1 || m[2] < 1) return spans;
  const int64_t rows = m[1] * m[2];
  spans.span.assign(static_cast<size_t>(rows), 0);
  parallel_for(0, rows, 1024, [&](int64_t begin, int64_t end) {
    for (int64_t r = begin; r < end; ++r) {
      int64_t lo = 0, hi = 0;
      row_span(values + r * m[0], m[0], fill, lo, hi);
      spans.span[static_cast<size_t>(r)] = static_cast<uint32_t>(lo) | static_cast<uint32_t>(hi) << 16;
    }
  });
  return spans;
}

bool RowSpans::only_fill(const int64_t lo[3], const int64_t hi[3]) const {
  if (empty()) return false;
  return box_off_spans(size, lo, hi, [&](int64_t r) {
    const uint32_t s = span[static_cast<size_t>(r)];
    return std::pair{static_cast<int64_t>(s & 0xffff), static_cast<int64_t>(s >> 16)};
  });
}

}  // namespace posewarp::resample
