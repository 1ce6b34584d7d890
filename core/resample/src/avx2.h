// The warp's loops four voxels at a time in AVX2, for the machines that have it (x86-64's baseline stops at SSE2):
// compiled for AVX2 alone (avx2.cpp) and chosen at run time with has_avx2(). Each lane does its scalar loop's IEEE
// operations in the same order, without FMA, so every output is the same bits either way. Private to the stage.
#pragma once

#include <cstdint>

#include "posewarp/common/image_geometry.h"
#include "posewarp/common/row_packed.h"

namespace posewarp::resample::internal {

#if defined(__x86_64__)
// Whether this machine runs AVX2.
bool has_avx2();
// Whether the lookups of a grid of size m may take AVX2's gathers: the machine has it and every offset fits int32.
inline bool avx2_gathers(const Index3& m) {
  return has_avx2() && m[0] * m[1] * m[2] < (int64_t{1} << 31);
}

// nearest_inside's loop (tet_warp.cpp): the nearest voxels of `in` (grid m, fewer than 2^31 voxels) at s0 + c ds for
// c from `c` to the last whole four before `end`, each in the grid, to out[c]; a run across the source rows asks for
// its lines 64 voxels ahead. Returns where it stopped.
__attribute__((target("avx2"))) int64_t nearest_avx2(const int32_t* __restrict in, const Index3& m, const double s0[3],
                                                     const double ds[3], int64_t c, int64_t end,
                                                     int32_t* __restrict out);

// trilinear_inside's loop (tet_warp.cpp): trilinear samples of `in` (grid m) at s0 + c ds, each with its 8 neighbours
// in the grid, from `c` to the last whole four before `end`, to out[c]; a run across the source rows asks for its
// lines 48 voxels ahead. Returns where it stopped.
__attribute__((target("avx2"))) int64_t trilinear_avx2(const float* __restrict in, const Index3& m, const double s0[3],
                                                       const double ds[3], int64_t c, int64_t end,
                                                       float* __restrict out);
// The same from int16 samples (each a float exactly, so the same bits as from the float volume of their values).
__attribute__((target("avx2"))) int64_t trilinear_avx2(const int16_t* __restrict in, const Index3& m,
                                                       const double s0[3], const double ds[3], int64_t c, int64_t end,
                                                       float* __restrict out);

// The classification's lookups along a turned background (warp_builder.cpp): rest_owner (packed rows, a grid of
// fewer than 2^31 voxels) at the nearest source voxel of start + c step for c in [c0, c0 + n), to ro[c - c0], -1 off
// the grid or off its row's span. Returns how many it did (a whole number of fours).
__attribute__((target("avx2"))) int64_t rest_owners_avx2(const RowPacked<int32_t>& rest_owner, const double start[3],
                                                         const double step[3], int64_t c0, int64_t n, int32_t* ro);
#endif

}  // namespace posewarp::resample::internal
