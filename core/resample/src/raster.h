// The raster's own pieces, shared by the warp's build (warp_builder.cpp) and its sampling (tet_warp.cpp): index
// spaces, per-tet raster data, the row and plane intersections, rounding without libm. Private to the stage.
#pragma once

#include <Eigen/Dense>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdint>
#include <limits>
#include <vector>

#include "posewarp/common/image_geometry.h"
#include "posewarp/common/parallel.h"
#include "posewarp/common/status.h"
#include "posewarp/resample/tet_warp.h"

namespace posewarp::resample::internal {

constexpr double kInsideTolerance = 1e-9;
// Tets whose index box holds at most this many voxels are rasterized voxel by voxel, larger ones row by row.
constexpr int64_t kSmallBox = 64;
// Raster buffers a thread keeps between warps, at most (a larger warp allocates its own and frees them).
constexpr size_t kKeptScratchBytes = size_t{128} << 20;
// The skin shell reaches at most this many output voxels (each shell voxel searches that neighbourhood).
constexpr int64_t kMaxShellVoxels = 8;

// Affine physical -> continuous index of a grid: u = M (x - o).
struct IndexSpace {
  Eigen::Matrix3d to_index;
  Eigen::Vector3d origin;
  Eigen::Matrix3d to_physical;  // inverse of to_index: x = o + to_physical u
};

inline IndexSpace index_space(const ImageGeometry& g) {
  Eigen::Matrix3d d;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      d(r, c) = g.direction[static_cast<size_t>(3 * r + c)] * g.spacing[static_cast<size_t>(c)];
  return {d.inverse(), Eigen::Vector3d(g.origin[0], g.origin[1], g.origin[2]), d};
}

// Per-tet data for rasterizing in output index space: barycentric map and the inside interval of a row.
// Barycentrics of voxel (i, j, k) are lambda_m = origin[m] + i * di[m] + j * dj[m] + k * dk[m] for m = 0..3
// (lambda_0 = 1 - lambda_1 - lambda_2 - lambda_3), all affine in the output index.
struct RasterTet {
  double origin[4], di[4], dj[4], dk[4];
  double lo[3], hi[3];  // index bounding box
};

// Buffers a thread reuses from one warp to the next, and whether a warp on that thread holds them.
struct RasterScratch {
  std::vector<RasterTet> raster;
  std::vector<int32_t> interior;        // per slab, in turn: the rasterized tets that meet it
  std::vector<int64_t> interior_first;  // where each slab's tets begin in interior (one more: the end)
  bool busy = false;
};

class ScratchLease {
 public:
  explicit ScratchLease(RasterScratch& scratch) : scratch_(scratch) { scratch_.busy = true; }
  ~ScratchLease() { scratch_.busy = false; }
  ScratchLease(const ScratchLease&) = delete;
  ScratchLease& operator=(const ScratchLease&) = delete;

 private:
  RasterScratch& scratch_;
};

// Items 0..n-1 put in order of their keys into `out`, `first[key]` (key_count + 1 entries) where each key's items
// begin: `for_keys(i, emit)` calls emit(key) for each key of item i (none, one or several; key < key_count). A
// counting sort in parallel, each thread counting and then filling whole blocks of items: within a key the items keep
// their order, so the result is what one thread would give.
template <typename ForKeys>
void sort_by_keys(int64_t n, int64_t key_count, const ForKeys& for_keys, std::vector<int32_t>& out,
                  std::vector<int64_t>& first) {
  const int64_t blocks = std::clamp<int64_t>((n + 4095) / 4096, 1, 4 * static_cast<int64_t>(thread_count()));
  const int64_t block = (n + blocks - 1) / blocks;
  std::vector<int64_t> at(static_cast<size_t>(blocks * key_count), 0);  // per block and key: a count, then a place
  parallel_for(0, blocks, 1, [&](int64_t b0, int64_t b1) {
    for (int64_t b = b0; b < b1; ++b) {
      int64_t* count = at.data() + b * key_count;
      for (int64_t i = b * block; i < std::min(n, (b + 1) * block); ++i)
        for_keys(i, [&](int64_t key) { ++count[key]; });
    }
  });
  first.assign(static_cast<size_t>(key_count) + 1, 0);
  int64_t total = 0;
  for (int64_t key = 0; key < key_count; ++key) {
    first[static_cast<size_t>(key)] = total;
    for (int64_t b = 0; b < blocks; ++b) {
      const int64_t count = at[static_cast<size_t>(b * key_count + key)];
      at[static_cast<size_t>(b * key_count + key)] = total;
      total += count;
    }
  }
  first[static_cast<size_t>(key_count)] = total;
  out.resize(static_cast<size_t>(total));
  parallel_for(0, blocks, 1, [&](int64_t b0, int64_t b1) {
    for (int64_t b = b0; b < b1; ++b) {
      int64_t* place = at.data() + b * key_count;
      for (int64_t i = b * block; i < std::min(n, (b + 1) * block); ++i) {
        for_keys(i, [&](int64_t key) { out[static_cast<size_t>(place[key]++)] = static_cast<int32_t>(i); });
      }
    }
  });
}

// floor and ceil without libm calls (baseline x86-64 has no SSE4.1 rounding instruction); |x| < 2^62.
inline double fast_floor(double x) {
  const double t = static_cast<double>(static_cast<int64_t>(x));
  return t - (x < t);
}
inline double fast_ceil(double x) {
  const double t = static_cast<double>(static_cast<int64_t>(x));
  return t + (x > t);
}

// Narrows [j0, j1] to the rows that the plane k cuts out of a tet with vertices' j and k y[], z[] (the j-extent
// of the cross-section, a triangle or a quadrilateral); false when the plane misses the tet.
inline bool slice_rows(const double y[4], const double z[4], double k, int64_t& j0, int64_t& j1) {
  constexpr double kSlack = 1e-6;  // index units: generous next to the raster's barycentric tolerance
  constexpr int kEdges[6][2] = {{0, 1}, {0, 2}, {0, 3}, {1, 2}, {1, 3}, {2, 3}};
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (int q = 0; q < 4; ++q) {
    if (std::abs(z[q] - k) <= kSlack) lo = std::min(lo, y[q]), hi = std::max(hi, y[q]);
  }
  for (const auto& e : kEdges) {
    const double za = z[e[0]] - k, zb = z[e[1]] - k;
    if ((za < 0.0 && zb > 0.0) || (za > 0.0 && zb < 0.0)) {
      const double y_cut = y[e[0]] + za / (za - zb) * (y[e[1]] - y[e[0]]);
      lo = std::min(lo, y_cut);
      hi = std::max(hi, y_cut);
    }
  }
  lo = std::max(lo - kSlack, static_cast<double>(j0) - 1.0);  // clamped before the casts
  hi = std::min(hi + kSlack, static_cast<double>(j1) + 1.0);
  if (!(lo <= hi)) return false;
  j0 = std::max(j0, static_cast<int64_t>(fast_ceil(lo)));
  j1 = std::min(j1, static_cast<int64_t>(fast_floor(hi)));
  return j0 <= j1;
}

// Barycentrics of the tet at i = 0 on row (j, k).
inline void row_start(const RasterTet& r, double j, double k, double alpha[4]) {
  for (int m = 0; m < 4; ++m) alpha[m] = r.origin[m] + j * r.dj[m] + k * r.dk[m];
}

// The i-interval of a row inside the tet (every barycentric >= -kInsideTolerance), intersected with [first, last];
// false when empty. Branch-free over the planes but for the rare one parallel to the row.
inline bool row_interval(const RasterTet& r, const double inv_di[4], const double alpha[4], int64_t& first,
                         int64_t& last) {
  double lo = static_cast<double>(first), hi = static_cast<double>(last);
  for (int m = 0; m < 4; ++m) {
    const double a = alpha[m] + kInsideTolerance;  // a + di * i >= 0
    const double x = -a * inv_di[m];
    lo = r.di[m] > 0.0 ? std::max(lo, x) : lo;
    hi = r.di[m] < 0.0 ? std::min(hi, x) : hi;
    if (r.di[m] == 0.0 && a < 0.0) return false;
  }
  if (!(lo <= hi)) return false;  // also keeps a far-away bound from reaching the casts
  lo = fast_ceil(lo);
  hi = fast_floor(hi);
  if (lo > hi) return false;
  first = static_cast<int64_t>(lo);
  last = static_cast<int64_t>(hi);
  return true;
}

// A map whose step along output x is one source voxel along x (to 1e-12: a direction matrix need not invert exactly).
inline bool steps_one_x(double dx, double dy, double dz) {
  return std::abs(dx - 1.0) < 1e-12 && std::abs(dy) < 1e-12 && std::abs(dz) < 1e-12;
}

// Round to nearest without a libm call (ties away from zero do not matter at voxel centres).
inline int64_t round_index(double x) {
  const double y = x + 0.5;
  int64_t r = static_cast<int64_t>(y);
  return r - (y < static_cast<double>(r));
}

// The box of source voxels that the nearest-voxel lookups at s0 + c ds for c in [c0, c1] land on: each index is
// round_index(s0 + c ds), every operation of which is monotone in c, so the two ends bound all the lookups between
// them, exactly (the arithmetic is the lookups' own; far values are clamped, which keeps them off any grid).
inline void lookup_box(const double s0[3], const double ds[3], int64_t c0, int64_t c1, int64_t lo[3], int64_t hi[3]) {
  for (int a = 0; a < 3; ++a) {
    const int64_t first = round_index(std::clamp(s0[a] + double(c0) * ds[a], -1e15, 1e15));
    const int64_t last = round_index(std::clamp(s0[a] + double(c1) * ds[a], -1e15, 1e15));
    lo[a] = std::min(first, last);
    hi[a] = std::max(first, last);
  }
}

// Nearest integer of x when x is one to within 1e-9, else false.
inline bool integral(double x, int64_t& n) {
  n = round_index(x);
  return std::abs(x - static_cast<double>(n)) < 1e-9;
}

inline void apply_map(const double* m, double i, double j, double k, double s[3]) {
  s[0] = m[0] * i + m[1] * j + m[2] * k + m[9];
  s[1] = m[3] * i + m[4] * j + m[5] * k + m[10];
  s[2] = m[6] * i + m[7] * j + m[8] * k + m[11];
}

// Whether `m` takes output row (j, k) along one source row: one source voxel along x per output voxel, from the whole
// source index (x0, y, z) at i = 0. `start` is the map at i = 0 either way.
inline bool along_source_row(const double* m, double j, double k, double start[3], int64_t& x0, int64_t& y,
                             int64_t& z) {
  apply_map(m, 0.0, j, k, start);
  return steps_one_x(m[0], m[3], m[6]) && integral(start[0], x0) && integral(start[1], y) && integral(start[2], z);
}

// A neighbour of an uncovered voxel within the skin shell, and how far it is (mm).
struct ShellOffset {
  int64_t di, dj, dk;
  double distance;
};

// The offsets within the shell's ellipsoid (semi-axes shell[a] mm, at most reach[a] voxels of `output`), nearest
// first.
inline std::vector<ShellOffset> shell_offsets(const ImageGeometry& output, const double shell[3],
                                              const int64_t reach[3]) {
  std::vector<ShellOffset> offsets;
  for (int64_t dk = -reach[2]; dk <= reach[2]; ++dk) {
    for (int64_t dj = -reach[1]; dj <= reach[1]; ++dj) {
      for (int64_t di = -reach[0]; di <= reach[0]; ++di) {
        const double x = double(di) * output.spacing[0], y = double(dj) * output.spacing[1],
                     z = double(dk) * output.spacing[2];
        const double inside =
            (x / shell[0]) * (x / shell[0]) + (y / shell[1]) * (y / shell[1]) + (z / shell[2]) * (z / shell[2]);
        if ((di || dj || dk) && inside <= 1.0 + 1e-12)
          offsets.push_back({di, dj, dk, std::sqrt(x * x + y * y + z * z)});
      }
    }
  }
  std::stable_sort(offsets.begin(), offsets.end(),
                   [](const ShellOffset& a, const ShellOffset& b) { return a.distance < b.distance; });
  return offsets;
}

// The output index box (lo x, y, z, hi x, y, z) of a source index box (i0, j0, k0, i1, j1, k1) moved by a rigid
// transform (rest -> posed, LPS), its voxels' outer faces included, clamped to just outside the output grid of size n.
inline std::array<double, 6> posed_index_box(const std::array<int64_t, 6>& box, const Eigen::Matrix3d& rotation,
                                             const Eigen::Vector3d& translation, const IndexSpace& source,
                                             const IndexSpace& output, const Index3& n) {
  std::array<double, 6> out;
  for (int a = 0; a < 3; ++a)
    out[static_cast<size_t>(a)] = std::numeric_limits<double>::infinity(),
    out[static_cast<size_t>(a + 3)] = -std::numeric_limits<double>::infinity();
  for (int corner = 0; corner < 8; ++corner) {
    const Eigen::Vector3d u((corner & 1) ? box[3] + 0.5 : box[0] - 0.5, (corner & 2) ? box[4] + 0.5 : box[1] - 0.5,
                            (corner & 4) ? box[5] + 0.5 : box[2] - 0.5);
    const Eigen::Vector3d rest_point = source.origin + source.to_physical * u;
    const Eigen::Vector3d o = output.to_index * (rotation * rest_point + translation - output.origin);
    for (int a = 0; a < 3; ++a) {
      const double top = static_cast<double>(n[static_cast<size_t>(a)]);
      out[static_cast<size_t>(a)] = std::min(out[static_cast<size_t>(a)], std::clamp(o(a), -2.0, top + 1.0));
      out[static_cast<size_t>(a + 3)] = std::max(out[static_cast<size_t>(a + 3)], std::clamp(o(a), -2.0, top + 1.0));
    }
  }
  return out;
}

// How TetWarp::build classifies a voxel without a rest owner: covered, shell (-2 - its tet) or background.
inline void classify_alone(int32_t& o, int32_t shell_owner, WarpStats& stats) {
  if (o >= 0) {
    ++stats.covered_voxels;
  } else if (shell_owner >= 0) {
    o = -2 - shell_owner;
    ++stats.extrapolated_voxels;
  } else {
    ++stats.background_voxels;
  }
}

// TetWarp::build's checks of its inputs, before anything is allocated.
Status check(const WarpInputs& inputs);

}  // namespace posewarp::resample::internal
