// TetWarp::Builder's passes 1 and 2 over output slabs: rasterize the moving tets (resolving folds), then find the
// skin shell around what they cover.
#include "warp_builder.h"

#include <algorithm>
#include <cmath>

namespace posewarp::resample {

using namespace internal;

// Pass 1 over slab s: rasterize its moving tets; where two cover a voxel, resolve the fold. Each row (j, k)
// remembers the first and last voxel any tet covered and which voxels, for the skin shell.
void TetWarp::Builder::rasterize_slab(int64_t s) {
  int64_t kb = 0, ke = 0;
  if (!slab_range(s, kb, ke)) return;
  const int64_t slab_begin = kb * n_[0] * n_[1], slab_voxels = (ke - kb) * n_[0] * n_[1];
  std::fill(owner_ + slab_begin, owner_ + slab_begin + slab_voxels, -1);
  std::fill(row_first_.begin() + kb * n_[1], row_first_.begin() + ke * n_[1], static_cast<int32_t>(n_[0]));
  std::fill(row_last_.begin() + kb * n_[1], row_last_.begin() + ke * n_[1], -1);
  std::fill(covered_bits_.begin() + kb * n_[1] * row_words_, covered_bits_.begin() + ke * n_[1] * row_words_, 0);
  std::vector<int64_t>& conflicts = conflicts_[static_cast<size_t>(s)];
  const int32_t* interior = scratch_->interior.data();
  for (int64_t at = scratch_->interior_first[static_cast<size_t>(s)];
       at < scratch_->interior_first[static_cast<size_t>(s) + 1]; ++at) {
    const int32_t t = interior[at];
    const RasterTet& r = raster_[static_cast<size_t>(t)];
    const int64_t k0 = std::max(kb, static_cast<int64_t>(fast_ceil(r.lo[2])));
    const int64_t k1 = std::min(ke - 1, static_cast<int64_t>(fast_floor(r.hi[2])));
    const int64_t j0 = std::max<int64_t>(0, static_cast<int64_t>(fast_ceil(r.lo[1])));
    const int64_t j1 = std::min<int64_t>(n_[1] - 1, static_cast<int64_t>(fast_floor(r.hi[1])));
    const int64_t i0 = std::max<int64_t>(0, static_cast<int64_t>(fast_ceil(r.lo[0])));
    const int64_t i1 = std::min<int64_t>(n_[0] - 1, static_cast<int64_t>(fast_floor(r.hi[0])));
    if (k0 > k1 || j0 > j1 || i0 > i1) continue;
    auto claim = [&](int64_t v, int64_t i, int64_t j, int64_t k) {
      int32_t& o = owner_[v];
      if (o < 0) {
        o = t;
        covered_bits_[static_cast<size_t>((j + n_[1] * k) * row_words_ + (i >> 6))] |= uint64_t{1} << (i & 63);
        return;
      }
      uint8_t folded = 0;
      if (wins(warp_.maps_.get() + 12 * t, warp_.tets_[static_cast<size_t>(t)], warp_.maps_.get() + 12 * o,
               warp_.tets_[static_cast<size_t>(o)], double(i), double(j), double(k), folded)) {
        o = t;
      }
      if (folded) conflicts.push_back(v - slab_begin);
    };
    if ((i1 - i0 + 1) * (j1 - j0 + 1) * (k1 - k0 + 1) <= kSmallBox) {
      rasterize_small(r, {i0, j0, k0}, {i1, j1, k1}, claim);
    } else {
      rasterize_large(t, r, {i0, j0, k0}, {i1, j1, k1}, claim);
    }
  }
  progress_->advance(1, 2 * slab_count_);
}

// A small tet (most are a few voxels): every voxel of its box is tested, which costs less than finding each row's
// interval.
template <typename Claim>
inline void TetWarp::Builder::rasterize_small(const RasterTet& r, const Index3& lo, const Index3& hi,
                                              const Claim& claim) {
  for (int64_t k = lo[2]; k <= hi[2]; ++k) {
    for (int64_t j = lo[1]; j <= hi[1]; ++j) {
      double alpha[4];
      row_start(r, double(j), double(k), alpha);
      int32_t first = static_cast<int32_t>(n_[0]), last = -1;
      int64_t v = in_.output.offset(lo[0], j, k);
      for (int64_t i = lo[0]; i <= hi[0]; ++i, ++v) {
        const double di = double(i);
        const double lambda = std::min(std::min(alpha[0] + di * r.di[0], alpha[1] + di * r.di[1]),
                                       std::min(alpha[2] + di * r.di[2], alpha[3] + di * r.di[3]));
        if (lambda < -kInsideTolerance) continue;
        claim(v, i, j, k);
        first = std::min(first, static_cast<int32_t>(i));
        last = static_cast<int32_t>(i);
      }
      if (last < 0) continue;
      const size_t row = static_cast<size_t>(j + n_[1] * k);
      row_first_[row] = std::min(row_first_[row], first);
      row_last_[row] = std::max(row_last_[row], last);
    }
  }
}

// A larger tet, row by row: each plane k's cross-section gives the rows, each row its interval.
template <typename Claim>
inline void TetWarp::Builder::rasterize_large(int32_t t, const RasterTet& r, const Index3& lo, const Index3& hi,
                                              const Claim& claim) {
  double inv_di[4], y[4], z[4];
  for (int m = 0; m < 4; ++m) inv_di[m] = r.di[m] != 0.0 ? 1.0 / r.di[m] : 0.0;
  for (int q = 0; q < 4; ++q) {
    const size_t vertex = static_cast<size_t>(in_.rest.tets(warp_.tets_[static_cast<size_t>(t)], q)) * 3;
    y[q] = posed_index_[vertex + 1];
    z[q] = posed_index_[vertex + 2];
  }
  for (int64_t k = lo[2]; k <= hi[2]; ++k) {
    int64_t jb = lo[1], je = hi[1];
    if (!slice_rows(y, z, double(k), jb, je)) continue;
    for (int64_t j = jb; j <= je; ++j) {
      double alpha[4];
      row_start(r, double(j), double(k), alpha);
      int64_t first = lo[0], last = hi[0];
      if (!row_interval(r, inv_di, alpha, first, last)) continue;
      const size_t row = static_cast<size_t>(j + n_[1] * k);
      row_first_[row] = std::min(row_first_[row], static_cast<int32_t>(first));
      row_last_[row] = std::max(row_last_[row], static_cast<int32_t>(last));
      int64_t v = in_.output.offset(first, j, k);
      for (int64_t i = first; i <= last; ++i, ++v) claim(v, i, j, k);
    }
  }
}

// Pass 2 over slab s, the skin shell: an uncovered voxel whose shell ellipsoid holds a covered voxel's centre takes
// the map of the nearest such voxel's tet. Only voxels within the shell's box of some covered voxel look: a row's
// covered voxels from the neighbour rows within reach, ORed and widened by the reach along the row (a row that
// crosses both moved arms has the chest between them, far from either).
void TetWarp::Builder::find_shell(int64_t s) {
  int64_t kb = 0, ke = 0;
  if (!slab_range(s, kb, ke) || offsets_.empty()) return;
  const int64_t slab_begin = kb * n_[0] * n_[1];
  std::vector<std::pair<int64_t, int32_t>>& found = shells_[static_cast<size_t>(s)];
  std::vector<uint64_t> near(static_cast<size_t>(row_words_)), wider(static_cast<size_t>(row_words_));
  for (int64_t k = kb; k < ke; ++k) {
    for (int64_t j = 0; j < n_[1]; ++j) {
      int64_t lo = n_[0], hi = -1;  // the hull of the neighbour rows' covered extents, grown by the reach
      std::fill(near.begin(), near.end(), 0);
      for (int64_t dk = std::max<int64_t>(-reach_[2], -k); dk <= reach_[2] && k + dk < n_[2]; ++dk) {
        for (int64_t dj = std::max<int64_t>(-reach_[1], -j); dj <= reach_[1] && j + dj < n_[1]; ++dj) {
          const size_t row = static_cast<size_t>(j + dj + n_[1] * (k + dk));
          if (row_first_[row] > row_last_[row]) continue;
          lo = std::min<int64_t>(lo, row_first_[row] - reach_[0]);
          hi = std::max<int64_t>(hi, row_last_[row] + reach_[0]);
          const uint64_t* bits = covered_bits_.data() + row * static_cast<size_t>(row_words_);
          for (int64_t w = row_first_[row] >> 6; w <= row_last_[row] >> 6; ++w) near[static_cast<size_t>(w)] |= bits[w];
        }
      }
      lo = std::max<int64_t>(lo, 0);
      hi = std::min<int64_t>(hi, n_[0] - 1);
      if (lo > hi) continue;
      for (int64_t step = 0; step < reach_[0]; ++step) widen_by_one(near, wider);
      for (int64_t w = lo >> 6; w <= hi >> 6; ++w) {
        uint64_t b = near[static_cast<size_t>(w)];
        if (w << 6 < lo) b &= ~uint64_t{0} << (lo & 63);
        if ((w + 1) << 6 > hi + 1) b &= ~(~uint64_t{0} << ((hi + 1) & 63));
        for (; b != 0; b &= b - 1) {
          const int64_t i = (w << 6) + __builtin_ctzll(b);
          const int64_t v = in_.output.offset(i, j, k);
          if (owner_[v] >= 0) continue;
          for (const ShellOffset& o : offsets_) {
            const int64_t x = i + o.di, y = j + o.dj, z = k + o.dk;
            if (x < 0 || y < 0 || z < 0 || x >= n_[0] || y >= n_[1] || z >= n_[2]) continue;
            const int32_t near_owner = owner_[in_.output.offset(x, y, z)];
            if (near_owner >= 0) {
              found.emplace_back(v - slab_begin, near_owner);
              break;
            }
          }
        }
      }
    }
  }
}

// Sets in `bits` (a row's bit per voxel) the neighbours along the row of every bit set; `scratch` is its size.
inline void TetWarp::Builder::widen_by_one(std::vector<uint64_t>& bits, std::vector<uint64_t>& scratch) {
  const size_t words = bits.size();
  for (size_t w = 0; w < words; ++w) {
    const uint64_t below = w > 0 ? bits[w - 1] >> 63 : 0, above = w + 1 < words ? bits[w + 1] << 63 : 0;
    scratch[w] = bits[w] | (bits[w] << 1) | (bits[w] >> 1) | below | above;
  }
  bits.swap(scratch);
}

}  // namespace posewarp::resample
