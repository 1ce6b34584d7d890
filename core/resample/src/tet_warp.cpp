// TetWarp: the inputs' checks and the sampling of the source through a built warp (labels, intensities, owners,
// the bones' deviation, the displacement field); the build itself is warp_builder.cpp.
#include "posewarp/resample/tet_warp.h"
#include "posewarp/common/exception_wall.h"

#include <Eigen/Dense>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstring>
#include <limits>
#include <mutex>
#include <new>
#include <optional>
#include <string>
#include <tuple>
#include <utility>

#include "avx2.h"
#include "posewarp/common/parallel.h"
#include "raster.h"

#if defined(__SSE2__)
#include <emmintrin.h>
#endif

namespace posewarp::resample {

using namespace internal;

namespace {

// Runs at least this long look for their span inside the grid (inside_span); shorter ones check each voxel.
constexpr int64_t kSpanFrom = 16;

// Copies `count` source voxels from whole index (x0, y, z) along x to dst, the part that lies in the grid m.
template <typename T, typename Out>
inline void copy_source_row(const T* in, const Index3& m, int64_t x0, int64_t y, int64_t z, int64_t count, Out* dst) {
  if (y < 0 || z < 0 || y >= m[1] || z >= m[2]) return;
  const int64_t c0 = std::max<int64_t>(0, -x0), c1 = std::min<int64_t>(count, m[0] - x0);
  const T* row = in + m[0] * (y + m[1] * z) + x0;
  if (c0 < c1) std::copy(row + c0, row + c1, dst + c0);
}

// The voxels [first, end) of a run whose samples s0 + c ds all satisfy `inside(c)`, a test that holds on a box of
// source index space [lo, hi) per axis. Each coordinate of s0 + c ds is monotone in c, so the voxels inside form one
// interval: its real bounds, a voxel narrower on each side, then widened or narrowed to where `inside` says, voxel by
// voxel (none, or a few, for the rounding). first == end when no voxel is inside.
template <typename Inside>
std::pair<int64_t, int64_t> inside_span(const double s0[3], const double ds[3], int64_t count, const double lo[3],
                                        const double hi[3], const Inside& inside) {
  double c_lo = 0.0, c_hi = static_cast<double>(count - 1);
  for (int a = 0; a < 3; ++a) {
    if (ds[a] == 0.0) {
      if (!(s0[a] >= lo[a] && s0[a] < hi[a])) return {0, 0};
      continue;
    }
    double from = (lo[a] - s0[a]) / ds[a], to = (hi[a] - s0[a]) / ds[a];
    if (from > to) std::swap(from, to);
    c_lo = std::max(c_lo, from);
    c_hi = std::min(c_hi, to);
  }
  if (!(c_lo <= c_hi)) return {0, 0};
  int64_t first = static_cast<int64_t>(std::ceil(c_lo)) + 1, last = static_cast<int64_t>(std::floor(c_hi)) - 1;
  first = std::clamp<int64_t>(first, 0, count - 1);
  last = std::clamp<int64_t>(last, 0, count - 1);
  if (first > last) return {0, 0};
  if (!inside(first) || !inside(last)) return {0, 0};  // the rounding took the margin: no fast span
  while (first > 0 && inside(first - 1)) --first;
  while (last + 1 < count && inside(last + 1)) ++last;
  return {first, last + 1};
}

// The nearest voxels of `in` (grid m) at s0 + c ds for c in [c, end), each in the grid, to out[c]. The run's values
// are copied to locals, so that the compiler keeps them in registers across out's stores.
template <typename T>
void nearest_run(const T* __restrict in, const Index3& m, const double s0[3], const double ds[3], int64_t c,
                 int64_t end, T* __restrict out) {
  const double a0 = s0[0], a1 = s0[1], a2 = s0[2], d0 = ds[0], d1 = ds[1], d2 = ds[2];
  const int64_t sy = m[0], sz = m[0] * m[1];
  // round_index of a sample in the grid: x + 0.5 >= 0 there, where truncation is the floor it takes.
  auto rounded = [](double x) { return static_cast<int64_t>(x + 0.5); };
#if defined(__x86_64__)
  if constexpr (sizeof(T) == 4) {
    if (avx2_gathers(m)) {
      c = nearest_avx2(reinterpret_cast<const int32_t*>(in), m, s0, ds, c, end, reinterpret_cast<int32_t*>(out));
    }
  }
#endif
  for (; c < end; ++c) {
    const double dc = double(c);
    out[c] = in[rounded(a0 + dc * d0) + sy * rounded(a1 + dc * d1) + sz * rounded(a2 + dc * d2)];
  }
}

// nearest_run over [first, end), where with `spans` (RowSpans of `in`, or null) the stretches of a run across the
// source rows that land off them (a body's air) take the spans' fill without a load.
template <typename T>
void nearest_inside(const T* __restrict in, const Index3& m, const double s0[3], const double ds[3], int64_t first,
                    int64_t end, T* __restrict out, const RowSpans* spans) {
  if (!spans || (ds[1] == 0.0 && ds[2] == 0.0)) {  // along a source row the loads are a stream
    nearest_run(in, m, s0, ds, first, end, out);
    return;
  }
  constexpr int64_t kStretch = 64;  // voxels whose landing box is looked up at once
  int64_t looked_up = first;        // where the voxels not yet written begin
  for (int64_t c = first; c < end; c += kStretch) {
    const int64_t stretch_end = std::min(end, c + kStretch);
    int64_t lo[3], hi[3];
    lookup_box(s0, ds, c, stretch_end - 1, lo, hi);
    if (!spans->only_fill(lo, hi)) continue;
    nearest_run(in, m, s0, ds, looked_up, c, out);  // the stretches before it that land on the body, in one run
    std::fill(out + c, out + stretch_end, static_cast<T>(spans->fill));
    looked_up = stretch_end;
  }
  nearest_run(in, m, s0, ds, looked_up, end, out);
}

#if defined(__SSE2__)
// Samples at[0] and at[1] as floats in the two low lanes (exact: an int16 is a float).
inline __m128 pair_of(const float* at) {
  return _mm_castpd_ps(_mm_load_sd(reinterpret_cast<const double*>(at)));
}
inline __m128 pair_of(const int16_t* at) {
  int32_t both = 0;
  std::memcpy(&both, at, sizeof(both));
  const __m128i x = _mm_cvtsi32_si128(both);
  return _mm_cvtepi32_ps(_mm_srai_epi32(_mm_unpacklo_epi16(x, x), 16));  // each int16 sign-extended to int32
}
#endif

// Trilinear samples of `in` (grid m, two voxels or more on every axis) at s0 + c ds for c in [first, end), each with
// its 8 neighbours in the grid (no clamping), to out[c]: the arithmetic of warp_intensities' checked loop. From int16
// samples each difference p[1] - p[0] is the float one exactly (under 2^24), so the bits are those of the floats.
template <typename T>
void trilinear_inside(const T* __restrict in, const Index3& m, const double s0[3], const double ds[3], int64_t first,
                      int64_t end, float* __restrict out) {
  const double a0 = s0[0], a1 = s0[1], a2 = s0[2], d0 = ds[0], d1 = ds[1], d2 = ds[2];
  const int64_t sy = m[0], sz = m[0] * m[1];
  int64_t c = first;
#if defined(__x86_64__)
  if (has_avx2()) c = trilinear_avx2(in, m, s0, ds, c, end, out);
#endif
#if defined(__SSE2__)
  // Two voxels at a time, one in each lane: the same IEEE operations on the same values, so the same bits (the
  // indices truncated to int32, which holds any grid's). The body's moved root: warp-ct 121 -> 91 ms.
  const __m128d x0 = _mm_set1_pd(a0), y0 = _mm_set1_pd(a1), z0 = _mm_set1_pd(a2);
  const __m128d dx = _mm_set1_pd(d0), dy = _mm_set1_pd(d1), dz = _mm_set1_pd(d2);
  auto lane = [](__m128i v, int l) { return static_cast<int64_t>(_mm_cvtsi128_si32(l ? _mm_shuffle_epi32(v, 1) : v)); };
  __m128d cc = _mm_set_pd(double(c + 1), double(c));
  for (; c + 1 < end; c += 2, cc = _mm_add_pd(cc, _mm_set1_pd(2.0))) {
    const __m128d x = _mm_add_pd(x0, _mm_mul_pd(cc, dx)), y = _mm_add_pd(y0, _mm_mul_pd(cc, dy)),
                  z = _mm_add_pd(z0, _mm_mul_pd(cc, dz));
    const __m128i bx = _mm_cvttpd_epi32(x), by = _mm_cvttpd_epi32(y), bz = _mm_cvttpd_epi32(z);
    const __m128d fx = _mm_sub_pd(x, _mm_cvtepi32_pd(bx)), fy = _mm_sub_pd(y, _mm_cvtepi32_pd(by)),
                  fz = _mm_sub_pd(z, _mm_cvtepi32_pd(bz));
    const T* p = in + lane(bx, 0) + lane(by, 0) * sy + lane(bz, 0) * sz;
    const T* q = in + lane(bx, 1) + lane(by, 1) * sy + lane(bz, 1) * sz;
    auto along_x = [&](int64_t at) {                                           // p[at] + f0 (p[at + 1] - p[at]) | at q
      const __m128 both = _mm_movelh_ps(pair_of(p + at), pair_of(q + at));     // p0 p1 q0 q1
      const __m128 low = _mm_shuffle_ps(both, both, _MM_SHUFFLE(3, 1, 2, 0));  // p0 q0 p1 q1
      const __m128 diff = _mm_sub_ps(_mm_movehl_ps(low, low), low);            // p1 - p0, q1 - q0
      return _mm_add_pd(_mm_cvtps_pd(low), _mm_mul_pd(fx, _mm_cvtps_pd(diff)));
    };
    const __m128d c00 = along_x(0), c10 = along_x(sy), c01 = along_x(sz), c11 = along_x(sz + sy);
    const __m128d e0 = _mm_add_pd(c00, _mm_mul_pd(fy, _mm_sub_pd(c10, c00)));
    const __m128d e1 = _mm_add_pd(c01, _mm_mul_pd(fy, _mm_sub_pd(c11, c01)));
    _mm_storel_pi(reinterpret_cast<__m64*>(out + c), _mm_cvtpd_ps(_mm_add_pd(e0, _mm_mul_pd(fz, _mm_sub_pd(e1, e0)))));
  }
#endif
  for (; c < end; ++c) {
    const double dc = double(c);
    const double x = a0 + dc * d0, y = a1 + dc * d1, z = a2 + dc * d2;
    const int64_t b0 = static_cast<int64_t>(x), b1 = static_cast<int64_t>(y), b2 = static_cast<int64_t>(z);
    const double f0 = x - static_cast<double>(b0), f1 = y - static_cast<double>(b1), f2 = z - static_cast<double>(b2);
    const T* p = in + b0 + b1 * sy + b2 * sz;
    const double c00 = p[0] + f0 * (p[1] - p[0]);
    const double c10 = p[sy] + f0 * (p[sy + 1] - p[sy]);
    const double c01 = p[sz] + f0 * (p[sz + 1] - p[sz]);
    const double c11 = p[sz + sy] + f0 * (p[sz + sy + 1] - p[sz + sy]);
    const double e0 = c00 + f1 * (c10 - c00);
    const double e1 = c01 + f1 * (c11 - c01);
    out[c] = static_cast<float>(e0 + f2 * (e1 - e0));
  }
}

}  // namespace

Status validate(const ResampleParams& params) {
  if (params.shell_mm < 0.0 || !std::isfinite(params.shell_mm)) return invalid_argument_error("shell_mm must be >= 0");
  if (params.max_output_voxels < 1) return invalid_argument_error("max_output_voxels must be positive");
  if (params.grow_margin_mm < 0.0) return invalid_argument_error("grow_margin_mm must be >= 0");
  return ok_status();
}

namespace internal {

// The inputs' consistency, before anything is allocated (TetWarp::build's first step).
Status check(const WarpInputs& in) {
  POSEWARP_RETURN_IF_ERROR(validate(in.params));
  if (const RigidBones* bones = in.bones) {
    const BoneVoxels* voxels = bones->voxels;
    if (!voxels || voxels->voxel_count != in.source.voxel_count() ||
        static_cast<int64_t>(voxels->bone_bits.size()) != (voxels->voxel_count + 63) / 64 ||
        voxels->bones_before.size() != voxels->bone_bits.size() ||
        static_cast<int64_t>(voxels->bone_segment.size()) != voxels->bone_voxels ||
        voxels->substitute.size() != voxels->bone_segment.size()) {
      return invalid_argument_error("the bone voxels do not match the source grid");
    }
    if (bones->rotation.size() != bones->translation.size() || bones->rotation.size() != bones->voxels->box.size() ||
        bones->rotation.size() > static_cast<size_t>(TetWarp::kMaxBoneSegments)) {
      return invalid_argument_error("the bone transforms do not match the bone segments");
    }
    if (bones->region && (bones->region->size() != in.source.size || !bones->tet_region ||
                          static_cast<int64_t>(bones->tet_region->size()) != in.rest.tet_count() || !bones->separated ||
                          bones->separated->size() != bones->rotation.size() * bones->rotation.size())) {
      return invalid_argument_error("the body regions do not match the source grid, the mesh or the segments");
    }
  }
  if (in.posed.rows() != in.rest.vertex_count() || in.posed.cols() != 3) {
    return invalid_argument_error("posed vertices (" + std::to_string(in.posed.rows()) + ") do not match the mesh (" +
                                  std::to_string(in.rest.vertex_count()) + ")");
  }
  POSEWARP_RETURN_IF_ERROR(in.source.validate().with_context("source grid"));
  POSEWARP_RETURN_IF_ERROR(in.output.validate().with_context("output grid"));
  if (in.output.voxel_count() > in.params.max_output_voxels) {
    return resource_exhausted_error("the output grid has " + std::to_string(in.output.voxel_count()) +
                                    " voxels, over the limit of " + std::to_string(in.params.max_output_voxels));
  }
  if (in.rest_owner && (in.rest_owner->size() != in.source.size || in.rest_owner->fill() != -1)) {
    return invalid_argument_error("the rest ownership does not match the source grid");
  }
  return ok_status();
}

}  // namespace internal

const double* TetWarp::map_of(int32_t o) const {
  if (o >= 0) return maps_.get() + 12 * o;
  if (is_bone_owner(o)) return bone_maps_.data() + 12 * (o - kBoneOwner);
  if (o <= -2 && o != kNoSample) return maps_.get() + 12 * (-2 - o);
  return background_map_;
}

template <typename Sample>
void TetWarp::for_each_mapped_run(const Sample& sample) const {
  const Index3& n = output_.size;
  const RowPacked<int32_t>& owner = *owner_;
  const double* maps = maps_.get();
  constexpr int64_t kMapLookahead = 16;
  parallel_for(0, n[2], 1, [&](int64_t k0, int64_t k1) {
    for (int64_t k = k0; k < k1; ++k) {
      for (int64_t j = 0; j < n[1]; ++j) {
        const int64_t row = output_.offset(0, j, k);
        auto run = [&](int64_t i, int64_t end, int32_t o) {
          if (o == kNoSample) return;
          const double* m = map_of(o);
          double s[3];
          apply_map(m, double(i), double(j), double(k), s);
          const double ds[3] = {m[0], m[3], m[6]};
          const bool soft = o >= 0 || (o <= -2 && !is_bone_owner(o));
          sample(row + i, end - i, s, ds, soft);
        };
        // Off the row's span every voxel takes the background's map (-1): a run before the span and one after it;
        // the span's first and last voxels hold other owners, so its runs are those of the whole row.
        int64_t lo = 0, hi = 0;
        const int32_t* span = owner.row(j, k, lo, hi);
        if (lo > 0) run(0, lo, -1);
        for (int64_t i = lo; i < hi;) {
          const int32_t o = span[i - lo];
          // Asks for the map of the tet 16 voxels on: maps lie in the raster's tet order, not along a row, and a
          // short run (1-2 voxels where every tet moves) would otherwise wait for its map's cache lines.
          if (i + kMapLookahead < hi) {
            const int32_t ahead = span[i + kMapLookahead - lo];
            if (ahead >= 0) {
              __builtin_prefetch(maps + 12 * ahead);
              __builtin_prefetch(maps + 12 * ahead + 8);
            }
          }
          int64_t end = i + 1;
          while (end < hi && span[end - lo] == o) ++end;
          run(i, end, o);
          i = end;
        }
        if (hi < n[0]) run(hi, n[0], -1);
      }
    }
  });
}

// Where warp_labels puts bone values, per output slice and bone segment: how many output voxels hold a value of that
// bone exactly where its own rigid inverse would sample (deviation 0, counted, not stored) and how far (mm) the others
// are; then max and 99th percentile over the zeros and the rest together. A run is tallied from the source voxels its
// labels are taken from, with the same arithmetic: the report describes the labels written.
class TetWarp::BoneTally {
 public:
  // `source`: the labels warped.
  BoneTally(const TetWarp& warp, const LabelVolume& source)
      : warp_(warp),
        source_(source),
        segments_(warp.bone_maps_.size() / 12),
        found_(static_cast<size_t>(warp.output_.size[2])) {
    for (int r = 0; r < 3; ++r)
      for (int c = 0; c < 3; ++c)
        to_mm_(r, c) =
            warp.source_.direction[static_cast<size_t>(3 * r + c)] * warp.source_.spacing[static_cast<size_t>(c)];
    // The segments whose map is the background's, bit for bit (those that did not move off the root): a background
    // voxel that lands on one of their voxels is where its bone puts it, deviation exactly 0, counted with the zeros.
    as_background_.assign(segments_, 0);
    for (size_t segment = 0; segment < segments_; ++segment) {
      as_background_[segment] =
          std::equal(warp.background_map_, warp.background_map_ + 12, warp.bone_maps_.data() + 12 * segment);
    }
    for (Slice& slice : found_) slice.exact.assign(segments_, 0);
    // Only runs across the source rows (the background's where the root moved) look the bones' values up.
    if (!steps_one_x(warp.background_map_[0], warp.background_map_[3], warp.background_map_[6])) find_bone_values();
  }

  // warp_labels' run of `count` output voxels from v, whose labels are the source's at s0 + c ds, mapped by a bone
  // or the background (a soft map puts no bone value: it samples the substitute). `written`: the run's labels.
  void run(int64_t v, int64_t count, const double s0[3], const double ds[3], const Label* written) {
    const Index3& n = warp_.output_.size;
    const int64_t i0 = v % n[0], j = (v / n[0]) % n[1], k = v / (n[0] * n[1]);
    const int32_t o = warp_.owner_->at(i0, j, k);
    Slice& slice = found_[static_cast<size_t>(k)];
    const int own = is_bone_owner(o) ? o - kBoneOwner : -1;  // -1: the background's run
    if (own >= 0 && warp_.claimed_by_own_map_[static_cast<size_t>(own)]) {
      // Claimed where its own map lands on its own bone (claim_bone's test, the same arithmetic): exact.
      slice.exact[static_cast<size_t>(own)] += count;
      return;
    }
    const BoneVoxels& bones = *warp_.bones_;
    const Index3& m = warp_.source_.size;
    auto land = [&](int64_t c, int64_t at) {  // output voxel i0 + c holds bone voxel `at`
      const int segment = bones.bone_segment[bones.rank_of(at)];
      if (segment == own || (own < 0 && as_background_[static_cast<size_t>(segment)])) {  // its bone's own map
        ++slice.exact[static_cast<size_t>(segment)];
        return;
      }
      double s[3], b[3];
      apply_map(warp_.map_of(o), double(i0 + c), double(j), double(k), s);
      apply_map(warp_.bone_maps_.data() + 12 * segment, double(i0 + c), double(j), double(k), b);
      const Eigen::Vector3d d(s[0] - b[0], s[1] - b[1], s[2] - b[2]);
      slice.off.push_back({static_cast<int16_t>(segment), static_cast<float>((to_mm_ * d).norm())});
    };
    if (steps_one_x(ds[0], ds[1], ds[2])) {  // warp_labels copies the run from one source row
      const int64_t x0 = round_index(s0[0]), y = round_index(s0[1]), z = round_index(s0[2]);
      if (y < 0 || z < 0 || y >= m[1] || z >= m[2]) return;
      // The run takes source voxels [first, end) of that row (output voxel c from row + x0 + c): their bone voxels,
      // 64 bits at a time.
      const int64_t row = m[0] * (y + m[1] * z);
      const int64_t first = row + std::max<int64_t>(0, x0), end = row + std::min(m[0], x0 + count);
      const std::vector<uint64_t>& bits = bones.bone_bits;
      for (int64_t word = first >> 6; word << 6 < end; ++word) {
        uint64_t b = bits[static_cast<size_t>(word)];
        if (word << 6 < first) b &= ~uint64_t{0} << (first & 63);
        if ((word + 1) << 6 > end) b &= ~(~uint64_t{0} << (end & 63));
        for (; b != 0; b &= b - 1) {
          const int64_t at = (word << 6) + __builtin_ctzll(b);
          land(at - row - x0, at);
        }
      }
      return;
    }
    for (int64_t c = 0; c < count; ++c) {
      if (!maybe_bone(written[c])) continue;
      const double dc = double(c);
      const int64_t x = round_index(s0[0] + dc * ds[0]), y = round_index(s0[1] + dc * ds[1]),
                    z = round_index(s0[2] + dc * ds[2]);
      if (x < 0 || y < 0 || z < 0 || x >= m[0] || y >= m[1] || z >= m[2]) continue;
      const int64_t at = x + m[0] * (y + m[1] * z);
      if (bones.is_bone(at)) land(c, at);
    }
  }

  // Per segment, {max, 99th percentile} of the deviations tallied.
  std::vector<std::pair<double, double>> deviation_mm() const {
    std::vector<int64_t> zeros(segments_, 0);
    std::vector<std::vector<float>> off(segments_);
    for (const Slice& slice : found_) {
      for (size_t segment = 0; segment < segments_; ++segment) zeros[segment] += slice.exact[segment];
      for (const auto& [segment, mm] : slice.off) off[static_cast<size_t>(segment)].push_back(mm);
    }
    std::vector<std::pair<double, double>> result(segments_, {0.0, 0.0});
    for (size_t segment = 0; segment < segments_; ++segment) {
      std::vector<float>& rest = off[segment];
      const size_t exact = static_cast<size_t>(zeros[segment]), count = exact + rest.size();
      if (count == 0) continue;
      // Sorted, the deviations (norms, never below zero) are the zeros and then the rest: the percentile is a zero or
      // the rest's element, the maximum the rest's.
      const size_t p99 = std::min(count - 1, static_cast<size_t>(0.99 * static_cast<double>(count)));
      double percentile = 0.0, highest = 0.0;
      if (!rest.empty()) highest = *std::max_element(rest.begin(), rest.end());
      if (p99 >= exact) {
        const auto at = rest.begin() + static_cast<std::ptrdiff_t>(p99 - exact);
        std::nth_element(rest.begin(), at, rest.end());
        percentile = *at;
      }
      result[segment] = {highest, percentile};
    }
    return result;
  }

 private:
  struct Slice {
    std::vector<int64_t> exact;                  // per segment
    std::vector<std::pair<int16_t, float>> off;  // (segment, mm)
  };
  // Wider ranges of bone values are not tabled.
  static constexpr int64_t kMaxBoneLabelRange = int64_t{1} << 16;

  // The values bone voxels hold (a bone's few labels), tabled for maybe_bone: an output voxel holding another value
  // holds no bone's, found without mapping it (without the table every voxel of such a run is mapped).
  void find_bone_values() {
    const std::vector<uint64_t>& bits = warp_.bones_->bone_bits;
    const Label* in = source_.data();
    std::mutex merge;
    std::vector<Label> values;
    parallel_for(0, static_cast<int64_t>(bits.size()), 4096, [&](int64_t begin, int64_t end) {
      std::vector<Label> found;  // few, and most bone voxels hold the value of the one before
      for (int64_t word = begin; word < end; ++word) {
        for (uint64_t b = bits[static_cast<size_t>(word)]; b != 0; b &= b - 1) {
          const Label value = in[64 * word + __builtin_ctzll(b)];
          if (!found.empty() && found.back() == value) continue;
          if (std::find(found.begin(), found.end(), value) == found.end()) found.push_back(value);
        }
      }
      const std::lock_guard<std::mutex> lock(merge);
      values.insert(values.end(), found.begin(), found.end());
    });
    if (values.empty()) return;
    const auto [lo, hi] = std::minmax_element(values.begin(), values.end());
    if (static_cast<int64_t>(*hi) - *lo >= kMaxBoneLabelRange) return;  // too wide a range: every voxel is mapped
    bone_value_lo_ = *lo;
    bone_value_.assign(static_cast<size_t>(static_cast<int64_t>(*hi) - *lo + 1), 0);
    for (const Label value : values) bone_value_[static_cast<size_t>(value - *lo)] = 1;
  }

  // Whether `value` may be a bone voxel's (every value where the bones' values were not tabled).
  bool maybe_bone(Label value) const {
    if (bone_value_.empty()) return true;
    const auto at = static_cast<uint64_t>(static_cast<int64_t>(value) - bone_value_lo_);
    return at < bone_value_.size() && bone_value_[at];
  }

  const TetWarp& warp_;
  const LabelVolume& source_;
  size_t segments_;
  Label bone_value_lo_ = 0;
  std::vector<uint8_t> bone_value_;  // per value from bone_value_lo_: whether a bone voxel holds it
  Eigen::Matrix3d to_mm_;            // source index step -> mm
  std::vector<uint8_t> as_background_;
  std::vector<Slice> found_;  // per output slice, each filled by the thread that walks it
};

Result<LabelVolume> TetWarp::warp_labels(const LabelVolume& labels,
                                         std::vector<std::pair<double, double>>* bone_deviation_mm,
                                         const RowSpans* spans) const {
  if (!labels.geometry().same_grid(source_, 1e-3)) {
    return invalid_argument_error("the label volume is not on the grid the rig was built from");
  }
  if (spans && spans->size != labels.size()) {
    return invalid_argument_error("the labels' row spans are not of the labels' grid");
  }
  if (spans && spans->empty()) spans = nullptr;
  POSEWARP_ASSIGN_OR_RETURN(LabelVolume out,
                            guarded("for the output labels (" + output_.describe() + ")",
                                    [&]() -> Result<LabelVolume> { return LabelVolume(output_, label_background_); }));
  out.set_source_type(labels.source_type());
  const Index3& m = source_.size;
  const Label* in = labels.data();
  Label* dst = out.data();
  const bool has_bones = bones_ != nullptr;
  const double nearest_lo[3] = {-0.5, -0.5, -0.5};
  const double nearest_hi[3] = {static_cast<double>(m[0]) - 0.5, static_cast<double>(m[1]) - 0.5,
                                static_cast<double>(m[2]) - 0.5};
  std::optional<BoneTally> tally;
  if (bone_deviation_mm && has_bones) tally.emplace(*this, labels);
  auto write = [&](int64_t v, int64_t count, const double s0[3], const double ds[3], bool soft) {
    const bool keep_bones_out = soft && has_bones;
    if (!keep_bones_out && steps_one_x(ds[0], ds[1], ds[2])) {  // a run along a source row: copy it
      copy_source_row(in, m, round_index(s0[0]), round_index(s0[1]), round_index(s0[2]), count, dst + v);
      return;
    }
    auto nearest = [&](int64_t c, int64_t& x, int64_t& y, int64_t& z) {
      const double dc = double(c);
      x = round_index(s0[0] + dc * ds[0]), y = round_index(s0[1] + dc * ds[1]), z = round_index(s0[2] + dc * ds[2]);
    };
    auto sample = [&](int64_t c0, int64_t c1) {  // with the bounds checked and the bones kept out
      for (int64_t c = c0; c < c1; ++c) {
        int64_t x = 0, y = 0, z = 0;
        nearest(c, x, y, z);
        if (x < 0 || y < 0 || z < 0 || x >= m[0] || y >= m[1] || z >= m[2]) continue;
        int64_t at = x + m[0] * (y + m[1] * z);
        if (keep_bones_out && bones_->is_bone(at)) at = bones_->substitute_of(at);
        dst[v + c] = in[at];
      }
    };
    if (keep_bones_out || count < kSpanFrom) {
      sample(0, count);
      return;
    }
    // A long run (the background where the root moved): the voxels whose nearest source voxel is in the grid without
    // a check each, the ends with theirs.
    const auto [first, end] = inside_span(s0, ds, count, nearest_lo, nearest_hi, [&](int64_t c) {
      int64_t x = 0, y = 0, z = 0;
      nearest(c, x, y, z);
      return x >= 0 && y >= 0 && z >= 0 && x < m[0] && y < m[1] && z < m[2];
    });
    sample(0, first);
    nearest_inside(in, m, s0, ds, first, end, dst + v, spans);
    sample(std::max(first, end), count);
  };
  for_each_mapped_run([&](int64_t v, int64_t count, const double s0[3], const double ds[3], bool soft) {
    write(v, count, s0, ds, soft);
    if (tally && !soft) tally->run(v, count, s0, ds, dst + v);
  });
  if (bone_deviation_mm) *bone_deviation_mm = tally ? tally->deviation_mm() : std::vector<std::pair<double, double>>{};
  return out;
}

Result<IntensityVolume> TetWarp::warp_intensities(const IntensityVolume& source, Interpolation interpolation) const {
  return warp_intensities_from(source, interpolation);
}

Result<IntensityVolume> TetWarp::warp_intensities(const Volume<int16_t>& source, Interpolation interpolation) const {
  return warp_intensities_from(source, interpolation);
}

template <typename T>
Result<IntensityVolume> TetWarp::warp_intensities_from(const Volume<T>& source, Interpolation interpolation) const {
  if (!source.geometry().same_grid(source_, 1e-3)) {
    return invalid_argument_error("the intensity volume is not on the grid the rig was built from");
  }
  POSEWARP_ASSIGN_OR_RETURN(IntensityVolume out, guarded("for the output intensities (" + output_.describe() + ")",
                                                         [&]() -> Result<IntensityVolume> {
                                                           return IntensityVolume(output_, intensity_background_);
                                                         }));
  out.set_source_type(source.source_type());
  const Index3& m = source_.size;
  const T* in = source.data();
  float* dst = out.data();
  const int64_t sy = m[0], sz = m[0] * m[1];
  const int64_t dx = m[0] > 1 ? 1 : 0, dy = m[1] > 1 ? sy : 0, dz = m[2] > 1 ? sz : 0;
  const double hi[3] = {static_cast<double>(m[0]) - 0.5, static_cast<double>(m[1]) - 0.5,
                        static_cast<double>(m[2]) - 0.5};
  const double top[3] = {static_cast<double>(m[0] - 1), static_cast<double>(m[1] - 1), static_cast<double>(m[2] - 1)};
  const int64_t base_max[3] = {std::max<int64_t>(0, m[0] - 2), std::max<int64_t>(0, m[1] - 2),
                               std::max<int64_t>(0, m[2] - 2)};
  const bool has_bones = bones_ != nullptr;
  // Where every axis has two voxels or more, a sample in [0, m - 1) on each axis has its 8 neighbours in the grid.
  const bool interior = m[0] > 1 && m[1] > 1 && m[2] > 1;
  const double interior_lo[3] = {0.0, 0.0, 0.0};
  for_each_mapped_run([&](int64_t v, int64_t count, const double s0[3], const double ds[3], bool soft) {
    const bool keep_bones_out = soft && has_bones;
    int64_t x0 = 0, y = 0, z = 0;
    if (!keep_bones_out && steps_one_x(ds[0], ds[1], ds[2]) && integral(s0[0], x0) && integral(s0[1], y) &&
        integral(s0[2], z)) {
      // A run along a source row through voxel centres: either interpolation gives the voxels themselves.
      copy_source_row(in, m, x0, y, z, count, dst + v);
      return;
    }
    int64_t first = 0, end = 0;  // the span whose 8 neighbours are all in the grid, interpolated without clamping
    if (!keep_bones_out && interpolation == Interpolation::kLinear && interior && count >= kSpanFrom) {
      std::tie(first, end) = inside_span(s0, ds, count, interior_lo, top, [&](int64_t c) {
        const double dc = double(c);
        for (int a = 0; a < 3; ++a) {
          const double x = s0[a] + dc * ds[a];
          if (!(x >= 0.0 && x < top[a])) return false;
        }
        return true;
      });
    }
    auto sample = [&](int64_t c0, int64_t c1) {  // with the bounds checked, clamped, and the bones kept out
      for (int64_t c = c0; c < c1; ++c) {
        const double dc = double(c);
        const double s[3] = {s0[0] + dc * ds[0], s0[1] + dc * ds[1], s0[2] + dc * ds[2]};
        if (s[0] < -0.5 || s[1] < -0.5 || s[2] < -0.5 || s[0] > hi[0] || s[1] > hi[1] || s[2] > hi[2]) continue;
        if (keep_bones_out) {
          const int64_t nearest = round_index(s[0]) + sy * round_index(s[1]) + sz * round_index(s[2]);
          if (bones_->is_bone(nearest)) {
            dst[v + c] = in[bones_->substitute_of(nearest)];
            continue;
          }
        }
        if (interpolation == Interpolation::kNearest) {
          dst[v + c] = in[round_index(s[0]) + sy * round_index(s[1]) + sz * round_index(s[2])];
          continue;
        }
        int64_t base[3];
        double f[3];
        for (int a = 0; a < 3; ++a) {
          const double x = std::clamp(s[a], 0.0, top[a]);
          base[a] = std::min<int64_t>(static_cast<int64_t>(x), base_max[a]);  // x >= 0
          f[a] = m[a] > 1 ? x - static_cast<double>(base[a]) : 0.0;
        }
        const T* p = in + base[0] + base[1] * sy + base[2] * sz;
        const double c00 = p[0] + f[0] * (p[dx] - p[0]);
        const double c10 = p[dy] + f[0] * (p[dy + dx] - p[dy]);
        const double c01 = p[dz] + f[0] * (p[dz + dx] - p[dz]);
        const double c11 = p[dz + dy] + f[0] * (p[dz + dy + dx] - p[dz + dy]);
        const double e0 = c00 + f[1] * (c10 - c00);
        const double e1 = c01 + f[1] * (c11 - c01);
        dst[v + c] = static_cast<float>(e0 + f[2] * (e1 - e0));
      }
    };
    sample(0, first);
    trilinear_inside(in, m, s0, ds, first, end, dst + v);
    sample(std::max(first, end), count);
  });
  return out;
}

std::vector<int32_t> TetWarp::owner() const {
  std::vector<int32_t> tet_owner = owner_->unpacked();
  for (int32_t& o : tet_owner) {
    if (o >= 0) {
      o = tets_[static_cast<size_t>(o)];
    } else if (o <= -2 && o != kNoSample && !is_bone_owner(o)) {
      o = -2 - tets_[static_cast<size_t>(-2 - o)];
    }
  }
  return tet_owner;
}

std::vector<float> TetWarp::inverse_displacement() const {
  const Index3& n = output_.size;
  std::vector<float> field(static_cast<size_t>(output_.voxel_count()) * 3, 0.0f);
  parallel_for(0, n[2], 1, [&](int64_t k0, int64_t k1) {
    for (int64_t k = k0; k < k1; ++k) {
      for (int64_t j = 0; j < n[1]; ++j) {
        for (int64_t i = 0; i < n[0]; ++i) {
          const int64_t v = output_.offset(i, j, k);
          double s[3];
          apply_map(map_of(owner_->at(i, j, k)), double(i), double(j), double(k), s);
          const Vec3 from = output_.index_to_physical({double(i), double(j), double(k)});
          const Vec3 to = source_.index_to_physical({s[0], s[1], s[2]});
          for (int a = 0; a < 3; ++a) field[static_cast<size_t>(3 * v + a)] = static_cast<float>(to[a] - from[a]);
        }
      }
    }
  });
  return field;
}

}  // namespace posewarp::resample
