// The warp's loops four voxels at a time in AVX2 (avx2.h): compiled for AVX2 alone and chosen at run time.
#include "avx2.h"

#if defined(__x86_64__)
#include <immintrin.h>

#include <cstring>

namespace posewarp::resample::internal {

bool has_avx2() {
  static const bool yes = (__builtin_cpu_init(), __builtin_cpu_supports("avx2"));
  return yes;
}

namespace {

// The nearest voxel's index along each axis at s0 + cc ds (four lanes): round_index's floor(x + 0.5), in double.
__attribute__((target("avx2"), always_inline)) inline void nearest_x4(const __m256d s0[3], const __m256d ds[3],
                                                                      __m256d cc, __m256d u[3]) {
  const __m256d half = _mm256_set1_pd(0.5);
  for (int a = 0; a < 3; ++a)
    u[a] = _mm256_floor_pd(_mm256_add_pd(_mm256_add_pd(s0[a], _mm256_mul_pd(cc, ds[a])), half));
}

// The offset u0 + m0 (u1 + m1 u2) of whole indices in a grid of m0 x m1 x ... voxels: exact in double.
__attribute__((target("avx2"), always_inline)) inline __m256d offset_x4(const __m256d u[3], __m256d m0, __m256d m1) {
  return _mm256_add_pd(u[0], _mm256_mul_pd(m0, _mm256_add_pd(u[1], _mm256_mul_pd(m1, u[2]))));
}

// Two floats from `at` in the low half.
inline __m128 float_pair(const float* at) {
  return _mm_castpd_ps(_mm_load_sd(reinterpret_cast<const double*>(at)));
}

// p[l][at] and p[l][at + 1] for the four lanes l, as floats (exact from int16): low and high.
__attribute__((target("avx2"), always_inline)) inline void pairs_x4(const float* const p[4], int64_t at, __m128& low,
                                                                    __m128& high) {
  const __m128 a = _mm_movelh_ps(float_pair(p[0] + at), float_pair(p[1] + at));  // p0[at] p0[at+1] p1[at] p1[at+1]
  const __m128 b = _mm_movelh_ps(float_pair(p[2] + at), float_pair(p[3] + at));
  low = _mm_shuffle_ps(a, b, _MM_SHUFFLE(2, 0, 2, 0));
  high = _mm_shuffle_ps(a, b, _MM_SHUFFLE(3, 1, 3, 1));
}
__attribute__((target("avx2"), always_inline)) inline void pairs_x4(const int16_t* const p[4], int64_t at, __m128& low,
                                                                    __m128& high) {
  int32_t both[4];
  for (int l = 0; l < 4; ++l) std::memcpy(&both[l], p[l] + at, sizeof(int32_t));
  const __m128i x = _mm_loadu_si128(reinterpret_cast<const __m128i*>(both));  // lane l: p[l][at] | p[l][at+1] << 16
  low = _mm_cvtepi32_ps(_mm_srai_epi32(_mm_slli_epi32(x, 16), 16));
  high = _mm_cvtepi32_ps(_mm_srai_epi32(x, 16));
}

// p[l][at] + fx[l] (p[l][at + 1] - p[l][at]) for the four lanes l.
template <typename T>
__attribute__((target("avx2"), always_inline)) inline __m256d lerp_x4(const T* const p[4], int64_t at, __m256d fx) {
  __m128 low, high;
  pairs_x4(p, at, low, high);
  return _mm256_add_pd(_mm256_cvtps_pd(low), _mm256_mul_pd(fx, _mm256_cvtps_pd(_mm_sub_ps(high, low))));
}

}  // namespace

// nearest_inside's loop four voxels at a time in AVX2 (no FMA: each lane rounds what the scalar code does), the
// source lines kAhead voxels on asked for ahead: a turned run crosses a source row every few voxels. From c up to the
// last whole four; returns where it stopped. The grid must hold fewer than 2^31 voxels (the offsets are int32).
__attribute__((target("avx2"))) int64_t nearest_avx2(const int32_t* __restrict in, const Index3& m, const double s0[3],
                                                     const double ds[3], int64_t c, int64_t end,
                                                     int32_t* __restrict out) {
  constexpr int64_t kAhead = 64;
  const bool across_rows = ds[1] != 0.0 || ds[2] != 0.0;  // along a row, the hardware's prefetcher sees them coming
  const __m256d m0 = _mm256_set1_pd(double(m[0])), m1 = _mm256_set1_pd(double(m[1]));
  const __m256d start[3] = {_mm256_set1_pd(s0[0]), _mm256_set1_pd(s0[1]), _mm256_set1_pd(s0[2])};
  const __m256d step[3] = {_mm256_set1_pd(ds[0]), _mm256_set1_pd(ds[1]), _mm256_set1_pd(ds[2])};
  __m256d u[3];
  for (; c + 3 < end; c += 4) {
    const double at = double(c);
    const __m256d cc = _mm256_set_pd(at + 3.0, at + 2.0, at + 1.0, at);
    if (across_rows && c + kAhead + 3 < end) {
      nearest_x4(start, step, _mm256_add_pd(cc, _mm256_set1_pd(double(kAhead))), u);
      const __m128i ahead = _mm256_cvttpd_epi32(offset_x4(u, m0, m1));
      _mm_prefetch(reinterpret_cast<const char*>(in + _mm_cvtsi128_si32(ahead)), _MM_HINT_T0);
      _mm_prefetch(reinterpret_cast<const char*>(in + _mm_extract_epi32(ahead, 2)), _MM_HINT_T0);
    }
    nearest_x4(start, step, cc, u);  // each in the grid: offsets under 2^31
    _mm_storeu_si128(reinterpret_cast<__m128i*>(out + c),
                     _mm_i32gather_epi32(in, _mm256_cvttpd_epi32(offset_x4(u, m0, m1)), 4));
  }
  return c;
}

namespace {

// trilinear_inside's loop four voxels at a time in AVX2, without FMA: each lane does the scalar code's IEEE operations
// on the same values, so the same bits. From c up to the last whole four; returns where it stopped. For machines that
// have AVX2 (x86-64's baseline stops at SSE2): the body's moved root, warp-ct 88-95 -> 75-76 ms.
template <typename T>
__attribute__((target("avx2"))) int64_t trilinear_x4(const T* __restrict in, const Index3& m, const double s0[3],
                                                     const double ds[3], int64_t c, int64_t end,
                                                     float* __restrict out) {
  const int64_t sy = m[0], sz = m[0] * m[1];
  // A run across the source rows (a turned map) asks for its lines ahead; along a row the hardware's prefetcher sees
  // them coming.
  constexpr int64_t kAheadCt = 48;
  const bool across_rows = ds[1] != 0.0 || ds[2] != 0.0;
  const __m256d x0 = _mm256_set1_pd(s0[0]), y0 = _mm256_set1_pd(s0[1]), z0 = _mm256_set1_pd(s0[2]);
  const __m256d dx = _mm256_set1_pd(ds[0]), dy = _mm256_set1_pd(ds[1]), dz = _mm256_set1_pd(ds[2]);
  for (__m256d cc = _mm256_set_pd(double(c + 3), double(c + 2), double(c + 1), double(c)); c + 3 < end;
       c += 4, cc = _mm256_add_pd(cc, _mm256_set1_pd(4.0))) {
    const __m256d x = _mm256_add_pd(x0, _mm256_mul_pd(cc, dx)), y = _mm256_add_pd(y0, _mm256_mul_pd(cc, dy)),
                  z = _mm256_add_pd(z0, _mm256_mul_pd(cc, dz));
    const __m128i bx = _mm256_cvttpd_epi32(x), by = _mm256_cvttpd_epi32(y), bz = _mm256_cvttpd_epi32(z);
    const __m256d fx = _mm256_sub_pd(x, _mm256_cvtepi32_pd(bx)), fy = _mm256_sub_pd(y, _mm256_cvtepi32_pd(by)),
                  fz = _mm256_sub_pd(z, _mm256_cvtepi32_pd(bz));
    alignas(16) int32_t ix[4], iy[4], iz[4];
    _mm_store_si128(reinterpret_cast<__m128i*>(ix), bx);
    _mm_store_si128(reinterpret_cast<__m128i*>(iy), by);
    _mm_store_si128(reinterpret_cast<__m128i*>(iz), bz);
    const T* p[4];
    for (int l = 0; l < 4; ++l) p[l] = in + int64_t{ix[l]} + int64_t{iy[l]} * sy + int64_t{iz[l]} * sz;
    if (across_rows && c + 4 + kAheadCt < end) {
      const double da = double(c + kAheadCt);
      const T* q = in + static_cast<int64_t>(s0[0] + da * ds[0]) + static_cast<int64_t>(s0[1] + da * ds[1]) * sy +
                   static_cast<int64_t>(s0[2] + da * ds[2]) * sz;
      __builtin_prefetch(q);
      __builtin_prefetch(q + sy);
      __builtin_prefetch(q + sz);
      __builtin_prefetch(q + sz + sy);
    }
    const __m256d c00 = lerp_x4(p, 0, fx), c10 = lerp_x4(p, sy, fx), c01 = lerp_x4(p, sz, fx),
                  c11 = lerp_x4(p, sz + sy, fx);
    const __m256d e0 = _mm256_add_pd(c00, _mm256_mul_pd(fy, _mm256_sub_pd(c10, c00)));
    const __m256d e1 = _mm256_add_pd(c01, _mm256_mul_pd(fy, _mm256_sub_pd(c11, c01)));
    _mm_storeu_ps(out + c, _mm256_cvtpd_ps(_mm256_add_pd(e0, _mm256_mul_pd(fz, _mm256_sub_pd(e1, e0)))));
  }
  return c;
}

}  // namespace

__attribute__((target("avx2"))) int64_t trilinear_avx2(const float* __restrict in, const Index3& m, const double s0[3],
                                                       const double ds[3], int64_t c, int64_t end,
                                                       float* __restrict out) {
  return trilinear_x4(in, m, s0, ds, c, end, out);
}
__attribute__((target("avx2"))) int64_t trilinear_avx2(const int16_t* __restrict in, const Index3& m,
                                                       const double s0[3], const double ds[3], int64_t c, int64_t end,
                                                       float* __restrict out) {
  return trilinear_x4(in, m, s0, ds, c, end, out);
}

// rest_owner at the nearest source voxel of start + c step, for c in [c0, c0 + n), to ro[c - c0] (-1 off the grid or
// off its row's span), four voxels at a time in AVX2, without FMA: each lane does source_voxel's IEEE operations
// (round_index(x) is floor(x + 0.5)), so it finds the same voxel; then its row's entry (base | lo << 32 | hi << 48)
// and, on the span, its value. The grid must hold fewer than 2^31 voxels and be packed (rows() not empty). No lines
// are asked for ahead: the packed values are a sixth of the grid's on a body, and asking (a row entry read per lane
// ahead) cost more than it saved. Returns how many it did (a whole number of fours).
__attribute__((target("avx2"))) int64_t rest_owners_avx2(const RowPacked<int32_t>& rest_owner, const double start[3],
                                                         const double step[3], int64_t c0, int64_t n, int32_t* ro) {
  const Index3& m = rest_owner.size();
  const long long* rows = reinterpret_cast<const long long*>(rest_owner.rows().data());
  const int32_t* values = rest_owner.values();
  const __m256d zero = _mm256_setzero_pd();
  const __m256d mx = _mm256_set1_pd(double(m[0])), my = _mm256_set1_pd(double(m[1])), mz = _mm256_set1_pd(double(m[2]));
  const __m256d s0[3] = {_mm256_set1_pd(start[0]), _mm256_set1_pd(start[1]), _mm256_set1_pd(start[2])};
  const __m256d ds[3] = {_mm256_set1_pd(step[0]), _mm256_set1_pd(step[1]), _mm256_set1_pd(step[2])};
  const __m256i low_halves = _mm256_setr_epi32(0, 2, 4, 6, 0, 2, 4, 6);
  const __m256i span_bits = _mm256_set1_epi64x(0xffff);
  int64_t c = 0;
  for (; c + 4 <= n; c += 4) {
    const double at = double(c0 + c);
    const __m256d cc = _mm256_set_pd(at + 3.0, at + 2.0, at + 1.0, at);
    __m256d u[3];
    nearest_x4(s0, ds, cc, u);
    const __m256d inside = _mm256_and_pd(
        _mm256_and_pd(_mm256_and_pd(_mm256_cmp_pd(u[0], zero, _CMP_GE_OQ), _mm256_cmp_pd(u[0], mx, _CMP_LT_OQ)),
                      _mm256_and_pd(_mm256_cmp_pd(u[1], zero, _CMP_GE_OQ), _mm256_cmp_pd(u[1], my, _CMP_LT_OQ))),
        _mm256_and_pd(_mm256_cmp_pd(u[2], zero, _CMP_GE_OQ), _mm256_cmp_pd(u[2], mz, _CMP_LT_OQ)));
    // Each lane's row y + m1 z and x, under 2^31 inside; the lanes outside look nothing up.
    const __m128i row = _mm256_cvttpd_epi32(_mm256_and_pd(_mm256_add_pd(u[1], _mm256_mul_pd(my, u[2])), inside));
    const __m128i x = _mm256_cvttpd_epi32(_mm256_and_pd(u[0], inside));
    const __m256i entry =
        _mm256_mask_i32gather_epi64(_mm256_setzero_si256(), rows, row, _mm256_castpd_si256(inside), 8);
    // On the span: lo <= x < hi, in 64-bit lanes (an empty row's lo == hi == 0 holds no x).
    const __m256i x64 = _mm256_cvtepi32_epi64(x);
    const __m256i lo = _mm256_and_si256(_mm256_srli_epi64(entry, 32), span_bits), hi = _mm256_srli_epi64(entry, 48);
    const __m256i on_span = _mm256_andnot_si256(_mm256_cmpgt_epi64(lo, x64), _mm256_cmpgt_epi64(hi, x64));
    const __m256i found_mask = _mm256_and_si256(on_span, _mm256_castpd_si256(inside));
    const __m128i mask = _mm256_castsi256_si128(_mm256_permutevar8x32_epi32(found_mask, low_halves));
    const __m128i base = _mm256_castsi256_si128(_mm256_permutevar8x32_epi32(entry, low_halves));
    const __m128i index = _mm_and_si128(_mm_add_epi32(base, x), mask);
    const __m128i found = _mm_mask_i32gather_epi32(_mm_set1_epi32(-1), values, index, mask, 4);
    _mm_storeu_si128(reinterpret_cast<__m128i*>(ro + c), found);
  }
  return c;
}

}  // namespace posewarp::resample::internal
#endif
