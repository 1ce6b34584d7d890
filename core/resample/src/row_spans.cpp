#include "posewarp/resample/row_spans.h"

#include <algorithm>

#include "posewarp/common/parallel.h"

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
      const int32_t* row = values + r * m[0];
      int64_t lo = 0, hi = m[0];
      while (lo < hi && row[lo] == fill) ++lo;
      while (hi > lo && row[hi - 1] == fill) --hi;
      if (lo < hi) spans.span[static_cast<size_t>(r)] = static_cast<uint32_t>(lo) | static_cast<uint32_t>(hi) << 16;
    }
  });
  return spans;
}

bool RowSpans::only_fill(const int64_t lo[3], const int64_t hi[3]) const {
  if (empty()) return false;
  const int64_t x0 = std::max<int64_t>(lo[0], 0), x1 = std::min(hi[0], size[0] - 1);
  const int64_t y0 = std::max<int64_t>(lo[1], 0), y1 = std::min(hi[1], size[1] - 1);
  const int64_t z0 = std::max<int64_t>(lo[2], 0), z1 = std::min(hi[2], size[2] - 1);
  for (int64_t z = z0; z <= z1; ++z) {
    for (int64_t y = y0; y <= y1; ++y) {
      const uint32_t s = span[static_cast<size_t>(y + size[1] * z)];
      if (x0 <= x1 && static_cast<int64_t>(s & 0xffff) <= x1 && static_cast<int64_t>(s >> 16) > x0) return false;
    }
  }
  return true;
}

}  // namespace posewarp::resample
