// TetWarp: rasterize the posed tets that move off the root over output slabs (each thread owns whole slabs, as ITK
// threads over output regions), resolve folds (bones win), extend the covered voxels' maps over the skin shell,
// classify the rest through the rest ownership, then sample the source.
#include "posewarp/common/exception_wall.h"
#include "posewarp/resample/tet_warp.h"

#include <Eigen/Dense>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <new>
#include <string>
#include <utility>

#include "posewarp/common/parallel.h"

namespace posewarp::resample {
namespace {

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

IndexSpace index_space(const ImageGeometry& g) {
  Eigen::Matrix3d d;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) d(r, c) = g.direction[static_cast<size_t>(3 * r + c)] * g.spacing[static_cast<size_t>(c)];
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
  std::vector<std::vector<int32_t>> interior;  // per slab: the rasterized tets that meet it
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

// Nearest integer of x when x is one to within 1e-9, else false.
inline bool integral(double x, int64_t& n) {
  n = round_index(x);
  return std::abs(x - static_cast<double>(n)) < 1e-9;
}

// Copies `count` source voxels from whole index (x0, y, z) along x to dst, the part that lies in the grid m.
template <typename T>
inline void copy_source_row(const T* in, const Index3& m, int64_t x0, int64_t y, int64_t z, int64_t count, T* dst) {
  if (y < 0 || z < 0 || y >= m[1] || z >= m[2]) return;
  const int64_t c0 = std::max<int64_t>(0, -x0), c1 = std::min<int64_t>(count, m[0] - x0);
  const T* row = in + m[0] * (y + m[1] * z) + x0;
  if (c0 < c1) std::copy(row + c0, row + c1, dst + c0);
}

inline void apply_map(const double* m, double i, double j, double k, double s[3]) {
  s[0] = m[0] * i + m[1] * j + m[2] * k + m[9];
  s[1] = m[3] * i + m[4] * j + m[5] * k + m[10];
  s[2] = m[6] * i + m[7] * j + m[8] * k + m[11];
}

}  // namespace

Status validate(const ResampleParams& params) {
  if (params.shell_mm < 0.0 || !std::isfinite(params.shell_mm)) return invalid_argument_error("shell_mm must be >= 0");
  if (params.max_output_voxels < 1) return invalid_argument_error("max_output_voxels must be positive");
  if (params.grow_margin_mm < 0.0) return invalid_argument_error("grow_margin_mm must be >= 0");
  return ok_status();
}

Result<TetWarp> TetWarp::build(const TetMesh& rest, const Eigen::MatrixXd& posed,
                               const ImageGeometry& source, const ImageGeometry& output,
                               const Eigen::Matrix3d& background_rotation, const Eigen::Vector3d& background_translation,
                               const std::vector<int32_t>* rest_owner, const ResampleParams& params,
                               const ProgressHooks& hooks, const RigidBones* bones) {
  POSEWARP_RETURN_IF_ERROR(validate(params));
  if (bones) {
    if (!bones->voxels || static_cast<int64_t>(bones->voxels->segment.size()) != source.voxel_count() ||
        bones->voxels->substitute.size() != bones->voxels->segment.size()) {
      return invalid_argument_error("the bone voxels do not match the source grid");
    }
    if (bones->rotation.size() != bones->translation.size() || bones->rotation.size() != bones->voxels->box.size() ||
        bones->rotation.size() > static_cast<size_t>(kMaxBoneSegments)) {
      return invalid_argument_error("the bone transforms do not match the bone segments");
    }
    if (bones->region && (static_cast<int64_t>(bones->region->size()) != source.voxel_count() || !bones->tet_region ||
                          static_cast<int64_t>(bones->tet_region->size()) != rest.tet_count() || !bones->separated ||
                          bones->separated->size() != bones->rotation.size() * bones->rotation.size())) {
      return invalid_argument_error("the body regions do not match the source grid, the mesh or the segments");
    }
  }
  if (posed.rows() != rest.vertex_count() || posed.cols() != 3) {
    return invalid_argument_error("posed vertices (" + std::to_string(posed.rows()) + ") do not match the mesh (" +
                                  std::to_string(rest.vertex_count()) + ")");
  }
  POSEWARP_RETURN_IF_ERROR(source.validate().with_context("source grid"));
  POSEWARP_RETURN_IF_ERROR(output.validate().with_context("output grid"));
  if (output.voxel_count() > params.max_output_voxels) {
    return resource_exhausted_error("the output grid has " + std::to_string(output.voxel_count()) +
                                    " voxels, over the limit of " + std::to_string(params.max_output_voxels));
  }
  if (rest_owner && static_cast<int64_t>(rest_owner->size()) != source.voxel_count()) {
    return invalid_argument_error("the rest ownership does not match the source grid");
  }
  StageProgress progress(hooks, "warp-prepare");
  TetWarp warp;
  warp.source_ = source;
  warp.output_ = output;
  warp.label_background_ = params.label_background;
  warp.intensity_background_ = params.intensity_background;
  // The shell is an ellipsoid around each uncovered voxel, semi-axes shell[a] mm along the output axes: by default
  // two source voxels along each axis (so a 5 mm slice thickness reaches one slice, not 12 in-plane voxels).
  double shell[3];
  int64_t reach[3];
  for (int a = 0; a < 3; ++a) {
    const double source_spacing = source.spacing[static_cast<size_t>(a)];
    shell[a] = params.shell_mm > 0.0 ? params.shell_mm : 2.0 * source_spacing;
    reach[a] = static_cast<int64_t>(std::min(shell[a] / output.spacing[static_cast<size_t>(a)], 1e6));
    if (reach[a] > kMaxShellVoxels && params.shell_mm > 0.0) {
      return invalid_argument_error("a skin shell of " + std::to_string(params.shell_mm) + " mm spans more than " +
                                    std::to_string(kMaxShellVoxels) + " voxels of the output grid; use a thinner shell");
    }
    reach[a] = std::min(reach[a], kMaxShellVoxels);  // the default on a much finer output grid
  }

  const Status prepared = guarded("preparing the warp onto " + output.describe(), [&]() -> Status {
    const IndexSpace out_space = index_space(output);
    const IndexSpace src_space = index_space(source);
    const int64_t nt = rest.tet_count();
    const int64_t nv = rest.vertex_count();

    // Background: output index -> output physical -> rest physical (inverse rigid) -> source index. Each bone's
    // own map the same way.
    auto rigid_map = [&](const Eigen::Matrix3d& rotation, const Eigen::Vector3d& translation, double* m) {
      const Eigen::Matrix3d a = src_space.to_index * rotation.transpose() * out_space.to_physical;
      const Eigen::Vector3d b =
          src_space.to_index * (rotation.transpose() * (out_space.origin - translation) - src_space.origin);
      for (int r = 0; r < 3; ++r) {
        for (int c = 0; c < 3; ++c) m[3 * r + c] = a(r, c);
        m[9 + r] = b(r);
      }
    };
    rigid_map(background_rotation, background_translation, warp.background_map_);
    // Bone segments: which move off the background, and each moving bone's posed index box in the output.
    const int segment_count = bones ? static_cast<int>(bones->rotation.size()) : 0;
    std::vector<uint8_t> bone_moves(static_cast<size_t>(segment_count), 0);
    std::vector<std::array<double, 6>> bone_box(static_cast<size_t>(segment_count));
    if (bones) {
      warp.bones_ = bones->voxels;
      warp.bone_maps_.assign(static_cast<size_t>(segment_count) * 12, 0.0);
      for (int k = 0; k < segment_count; ++k) {
        const Eigen::Matrix3d& rotation = bones->rotation[static_cast<size_t>(k)];
        const Eigen::Vector3d& translation = bones->translation[static_cast<size_t>(k)];
        rigid_map(rotation, translation, warp.bone_maps_.data() + 12 * k);
        bone_moves[static_cast<size_t>(k)] = (rotation - background_rotation).cwiseAbs().maxCoeff() > 1e-12 ||
                                             (translation - background_translation).cwiseAbs().maxCoeff() > 1e-9;
        const std::array<int64_t, 6>& box = bones->voxels->box[static_cast<size_t>(k)];
        std::array<double, 6>& out_box = bone_box[static_cast<size_t>(k)];
        out_box = {1.0, 1.0, 1.0, 0.0, 0.0, 0.0};  // empty
        if (box[0] > box[3]) {
          bone_moves[static_cast<size_t>(k)] = 0;
          continue;
        }
        for (int a = 0; a < 3; ++a) out_box[static_cast<size_t>(a)] = std::numeric_limits<double>::infinity(),
                                    out_box[static_cast<size_t>(a + 3)] = -std::numeric_limits<double>::infinity();
        for (int corner = 0; corner < 8; ++corner) {
          const Eigen::Vector3d u((corner & 1) ? box[3] + 0.5 : box[0] - 0.5, (corner & 2) ? box[4] + 0.5 : box[1] - 0.5,
                                  (corner & 4) ? box[5] + 0.5 : box[2] - 0.5);
          const Eigen::Vector3d rest_point = src_space.origin + src_space.to_physical * u;
          const Eigen::Vector3d o = out_space.to_index * (rotation * rest_point + translation - out_space.origin);
          for (int a = 0; a < 3; ++a) {
            const double top = static_cast<double>(output.size[static_cast<size_t>(a)]);
            out_box[static_cast<size_t>(a)] = std::min(out_box[static_cast<size_t>(a)], std::clamp(o(a), -2.0, top + 1.0));
            out_box[static_cast<size_t>(a + 3)] = std::max(out_box[static_cast<size_t>(a + 3)], std::clamp(o(a), -2.0, top + 1.0));
          }
        }
      }
    }

    // Vertices into output (posed) and source (rest) index space once, row-major; with a rest owner, which of them
    // follow the background transform (to a millionth of a voxel).
    std::vector<double> posed_index(static_cast<size_t>(nv) * 3), rest_index(static_cast<size_t>(nv) * 3);
    std::vector<uint8_t> follows(static_cast<size_t>(nv), 0);
    const double follow_tolerance = 1e-6 * std::min({output.spacing[0], output.spacing[1], output.spacing[2]});
    parallel_for(0, nv, 8192, [&](int64_t begin, int64_t end) {
      for (int64_t v = begin; v < end; ++v) {
        const Eigen::Vector3d x = posed.row(v).transpose();
        const Eigen::Vector3d p = rest.vertices.row(v).transpose();
        const Eigen::Vector3d u = out_space.to_index * (x - out_space.origin);
        const Eigen::Vector3d s = src_space.to_index * (p - src_space.origin);
        for (int a = 0; a < 3; ++a) {
          posed_index[static_cast<size_t>(3 * v + a)] = u(a);
          rest_index[static_cast<size_t>(3 * v + a)] = s(a);
        }
        if (rest_owner) {
          follows[static_cast<size_t>(v)] =
              (background_rotation * p + background_translation - x).cwiseAbs().maxCoeff() <= follow_tolerance;
        }
      }
    });
    // The tets to rasterize: all of them without a rest owner, else those with a vertex off the background.
    std::vector<uint8_t> moving(static_cast<size_t>(nt), 1);
    if (rest_owner) {
      parallel_for(0, nt, 8192, [&](int64_t begin, int64_t end) {
        for (int64_t t = begin; t < end; ++t) {
          bool all_follow = true;
          for (int c = 0; c < 4; ++c) all_follow = all_follow && follows[static_cast<size_t>(rest.tets(t, c))];
          moving[static_cast<size_t>(t)] = all_follow ? 0 : 1;
        }
      });
    }
    std::vector<int32_t>& tets = warp.tets_;  // rasterized index -> tet
    for (int64_t t = 0; t < nt; ++t) {
      if (moving[static_cast<size_t>(t)]) tets.push_back(static_cast<int32_t>(t));
    }
    // In the order of their lowest posed k (a counting sort on whole k, tet order within one), so that each slab
    // reads its tets' raster data nearly in sequence.
    {
      const int64_t nz = output.size[2];
      std::vector<int32_t> bucket(tets.size());
      std::vector<int64_t> start(static_cast<size_t>(nz) + 1, 0);
      for (size_t c = 0; c < tets.size(); ++c) {
        double z = std::numeric_limits<double>::infinity();
        for (int q = 0; q < 4; ++q) z = std::min(z, posed_index[static_cast<size_t>(rest.tets(tets[c], q)) * 3 + 2]);
        bucket[c] = static_cast<int32_t>(std::clamp<double>(fast_floor(std::clamp(z, -1.0, 1e9)), 0.0, static_cast<double>(nz - 1)));
        ++start[static_cast<size_t>(bucket[c]) + 1];
      }
      for (size_t b = 1; b < start.size(); ++b) start[b] += start[b - 1];
      std::vector<int32_t> sorted(tets.size());
      for (size_t c = 0; c < tets.size(); ++c) sorted[static_cast<size_t>(start[static_cast<size_t>(bucket[c])]++)] = tets[c];
      tets.swap(sorted);
    }
    const int64_t nm = static_cast<int64_t>(tets.size());
    warp.rasterized_tets_ = nm;
    // Per rasterized tet, densely (a pose that moves a few tets touches only theirs): the output-index ->
    // source-index map and the raster data.
    warp.maps_ = std::shared_ptr<double[]>(new double[static_cast<size_t>(std::max<int64_t>(nm, 1)) * 12]);
    // The raster data and slab lists live in buffers this thread keeps between warps: on a 2-core VM, faulting in
    // tens of MB of fresh pages per pose costs as much as the raster itself. A warp started on this thread while
    // another is in flight on it (a task stolen inside a parallel loop), or one larger than kKeptScratchBytes, gets
    // buffers of its own.
    thread_local RasterScratch kept;
    RasterScratch own;
    const bool keep = !kept.busy && static_cast<size_t>(nm) * sizeof(RasterTet) <= kKeptScratchBytes;
    RasterScratch& scratch = keep ? kept : own;
    const ScratchLease lease(scratch);
    if (scratch.raster.size() < static_cast<size_t>(nm)) scratch.raster.resize(static_cast<size_t>(nm));
    RasterTet* raster = scratch.raster.data();
    std::vector<uint8_t> usable(static_cast<size_t>(nm), 0);
    std::vector<std::array<int32_t, 2>> k_range(static_cast<size_t>(nm), {1, 0});  // output k the tet spans
    parallel_for(0, nm, 2048, [&](int64_t begin, int64_t end) {
      for (int64_t c = begin; c < end; ++c) {
        const int64_t t = tets[static_cast<size_t>(c)];
        Eigen::Vector3d u[4], s[4];
        for (int q = 0; q < 4; ++q) {
          const size_t v = static_cast<size_t>(rest.tets(t, q)) * 3;
          u[q] = Eigen::Vector3d(posed_index[v], posed_index[v + 1], posed_index[v + 2]);
          s[q] = Eigen::Vector3d(rest_index[v], rest_index[v + 1], rest_index[v + 2]);
        }
        Eigen::Matrix3d ue, se;
        for (int q = 0; q < 3; ++q) ue.col(q) = u[q + 1] - u[0], se.col(q) = s[q + 1] - s[0];
        const double det = ue.determinant();
        if (!(std::abs(det) > 1e-12) || !std::isfinite(det)) continue;
        const Eigen::Matrix3d inverse = ue.inverse();
        RasterTet& r = raster[static_cast<size_t>(c)];
        const Eigen::Vector3d origin = -(inverse * u[0]);
        r.origin[0] = 1.0 - origin.sum();
        r.di[0] = -inverse.col(0).sum();
        r.dj[0] = -inverse.col(1).sum();
        r.dk[0] = -inverse.col(2).sum();
        for (int m = 1; m < 4; ++m) {
          r.origin[m] = origin(m - 1);
          r.di[m] = inverse(m - 1, 0);
          r.dj[m] = inverse(m - 1, 1);
          r.dk[m] = inverse(m - 1, 2);
        }
        // The index box, clamped in double to just outside the grid so that no later cast can overflow (a root
        // translated by 1e9 mm is finite, and valid).
        for (int a = 0; a < 3; ++a) {
          const double top = static_cast<double>(output.size[static_cast<size_t>(a)]);
          r.lo[a] = std::clamp(std::min({u[0](a), u[1](a), u[2](a), u[3](a)}), -2.0, top + 1.0);
          r.hi[a] = std::clamp(std::max({u[0](a), u[1](a), u[2](a), u[3](a)}), -2.0, top + 1.0);
        }
        const Eigen::Matrix3d a = se * inverse;
        const Eigen::Vector3d b = s[0] - a * u[0];
        double* m = warp.maps_.get() + 12 * c;
        for (int row = 0; row < 3; ++row) {
          for (int q = 0; q < 3; ++q) m[3 * row + q] = a(row, q);
          m[9 + row] = b(row);
        }
        usable[static_cast<size_t>(c)] = 1;
        k_range[static_cast<size_t>(c)] = {
            static_cast<int32_t>(std::max<int64_t>(0, static_cast<int64_t>(fast_ceil(r.lo[2])))),
            static_cast<int32_t>(std::min<int64_t>(output.size[2] - 1, static_cast<int64_t>(fast_floor(r.hi[2]))))};
      }
    });
    for (const uint8_t ok : usable) warp.stats_.degenerate_tets += ok ? 0 : 1;
    POSEWARP_RETURN_IF_ERROR(progress.check_cancel());
    progress.update(0.2);

    // Slabs along output k; each tet goes to every slab its index box meets.
    const Index3& n = output.size;
    const int64_t slab_count = std::clamp<int64_t>(n[2], 1, 16 * static_cast<int64_t>(thread_count()));
    const int64_t slab_depth = (n[2] + slab_count - 1) / slab_count;
    std::vector<std::vector<int32_t>>& interior = scratch.interior;
    if (interior.size() < static_cast<size_t>(slab_count)) interior.resize(static_cast<size_t>(slab_count));
    for (std::vector<int32_t>& list : interior) list.clear();
    for (int64_t c = 0; c < nm; ++c) {
      const auto [k0, k1] = k_range[static_cast<size_t>(c)];
      for (int64_t s = k0 / slab_depth; k0 <= k1 && s <= k1 / slab_depth; ++s) {
        interior[static_cast<size_t>(s)].push_back(static_cast<int32_t>(c));
      }
    }

    warp.owner_ = std::shared_ptr<int32_t[]>(new int32_t[static_cast<size_t>(output.voxel_count())]);
    int32_t* owner = warp.owner_.get();
    const Eigen::VectorXi& tet_class = rest.tet_class;
    auto priority = [&tet_class](int32_t t) { return tet_class(t) >= kFirstBoneClass ? 1 : 0; };
    // Owner codes hold rasterized indices; the fold rule and rest owners speak of tets.
    // Does tet a win voxel (i, j, k) from tet b (bones win, then the lower index)? Counts a fold where they disagree.
    auto wins = [&](const double* map_a, int32_t a, const double* map_b, int32_t b, double i, double j, double k,
                    uint8_t& conflicted) {
      double sa[3], sb[3];
      apply_map(map_a, i, j, k, sa);
      apply_map(map_b, i, j, k, sb);
      if (std::abs(sa[0] - sb[0]) + std::abs(sa[1] - sb[1]) + std::abs(sa[2] - sb[2]) > 0.5) conflicted = 1;
      const int pa = priority(a), pb = priority(b);
      return pa > pb || (pa == pb && a < b);
    };
    // The tet (rest owner code) that holds source index s in the rest pose; -1 when none or outside the grid.
    auto rest_owner_at = [&](const double s[3]) -> int32_t {
      const int64_t x = round_index(s[0]), y = round_index(s[1]), z = round_index(s[2]);
      if (x < 0 || y < 0 || z < 0 || x >= source.size[0] || y >= source.size[1] || z >= source.size[2]) return -1;
      return (*rest_owner)[static_cast<size_t>(source.offset(x, y, z))];
    };

    // Pass 1, rasterize the moving tets, slabs in parallel; where two cover a voxel, resolve the fold. Each row
    // (j, k) remembers the first and last voxel any tet covered, for the skin shell.
    const int64_t row_count = n[1] * n[2];
    std::vector<int32_t> row_first(static_cast<size_t>(row_count)), row_last(static_cast<size_t>(row_count));
    std::vector<std::vector<uint8_t>> conflicts(static_cast<size_t>(slab_count));  // per slab voxel: a fold
    auto slab_range = [&](int64_t s, int64_t& kb, int64_t& ke) {
      kb = s * slab_depth;
      ke = std::min(n[2], kb + slab_depth);
      return kb < ke;
    };
    parallel_for(0, slab_count, 1, [&](int64_t s0, int64_t s1) {
      for (int64_t s = s0; s < s1; ++s) {
        if (progress.cancel_requested()) return;  // per slab: a cancelled or expired call ends within one slab
        int64_t kb = 0, ke = 0;
        if (!slab_range(s, kb, ke)) continue;
        const int64_t slab_begin = kb * n[0] * n[1], slab_voxels = (ke - kb) * n[0] * n[1];
        std::fill(owner + slab_begin, owner + slab_begin + slab_voxels, -1);
        std::fill(row_first.begin() + kb * n[1], row_first.begin() + ke * n[1], static_cast<int32_t>(n[0]));
        std::fill(row_last.begin() + kb * n[1], row_last.begin() + ke * n[1], -1);
        std::vector<uint8_t>& conflict = conflicts[static_cast<size_t>(s)];
        conflict.assign(static_cast<size_t>(slab_voxels), 0);
        for (const int32_t t : interior[static_cast<size_t>(s)]) {
          const RasterTet& r = raster[static_cast<size_t>(t)];
          const int64_t k0 = std::max(kb, static_cast<int64_t>(fast_ceil(r.lo[2])));
          const int64_t k1 = std::min(ke - 1, static_cast<int64_t>(fast_floor(r.hi[2])));
          const int64_t j0 = std::max<int64_t>(0, static_cast<int64_t>(fast_ceil(r.lo[1])));
          const int64_t j1 = std::min<int64_t>(n[1] - 1, static_cast<int64_t>(fast_floor(r.hi[1])));
          const int64_t i0 = std::max<int64_t>(0, static_cast<int64_t>(fast_ceil(r.lo[0])));
          const int64_t i1 = std::min<int64_t>(n[0] - 1, static_cast<int64_t>(fast_floor(r.hi[0])));
          auto claim = [&](int64_t v, int64_t i, int64_t j, int64_t k) {
            int32_t& o = owner[v];
            if (o < 0) {
              o = t;
            } else if (wins(warp.maps_.get() + 12 * t, tets[static_cast<size_t>(t)], warp.maps_.get() + 12 * o,
                            tets[static_cast<size_t>(o)], double(i), double(j), double(k),
                            conflict[static_cast<size_t>(v - slab_begin)])) {
              o = t;
            }
          };
          if (k0 > k1 || j0 > j1 || i0 > i1) continue;
          if ((i1 - i0 + 1) * (j1 - j0 + 1) * (k1 - k0 + 1) <= kSmallBox) {
            // A small tet (most are a few voxels): test every voxel of its box, which costs less than finding
            // each row's interval.
            for (int64_t k = k0; k <= k1; ++k) {
              for (int64_t j = j0; j <= j1; ++j) {
                double alpha[4];
                row_start(r, double(j), double(k), alpha);
                int32_t first = static_cast<int32_t>(n[0]), last = -1;
                int64_t v = output.offset(i0, j, k);
                for (int64_t i = i0; i <= i1; ++i, ++v) {
                  const double di = double(i);
                  const double lambda = std::min(std::min(alpha[0] + di * r.di[0], alpha[1] + di * r.di[1]),
                                                 std::min(alpha[2] + di * r.di[2], alpha[3] + di * r.di[3]));
                  if (lambda < -kInsideTolerance) continue;
                  claim(v, i, j, k);
                  first = std::min(first, static_cast<int32_t>(i));
                  last = static_cast<int32_t>(i);
                }
                if (last < 0) continue;
                const size_t row = static_cast<size_t>(j + n[1] * k);
                row_first[row] = std::min(row_first[row], first);
                row_last[row] = std::max(row_last[row], last);
              }
            }
            continue;
          }
          // A larger tet, row by row: each plane k's cross-section gives the rows, each row its interval.
          double inv_di[4], y[4], z[4];
          for (int m = 0; m < 4; ++m) inv_di[m] = r.di[m] != 0.0 ? 1.0 / r.di[m] : 0.0;
          for (int q = 0; q < 4; ++q) {
            const size_t vertex = static_cast<size_t>(rest.tets(tets[static_cast<size_t>(t)], q)) * 3;
            y[q] = posed_index[vertex + 1];
            z[q] = posed_index[vertex + 2];
          }
          for (int64_t k = k0; k <= k1; ++k) {
            int64_t jb = j0, je = j1;
            if (!slice_rows(y, z, double(k), jb, je)) continue;
            for (int64_t j = jb; j <= je; ++j) {
              double alpha[4];
              row_start(r, double(j), double(k), alpha);
              int64_t first = i0, last = i1;
              if (!row_interval(r, inv_di, alpha, first, last)) continue;
              const size_t row = static_cast<size_t>(j + n[1] * k);
              row_first[row] = std::min(row_first[row], static_cast<int32_t>(first));
              row_last[row] = std::max(row_last[row], static_cast<int32_t>(last));
              int64_t v = output.offset(first, j, k);
              for (int64_t i = first; i <= last; ++i, ++v) claim(v, i, j, k);
            }
          }
        }
        progress.advance(1, 2 * slab_count);
      }
    });
    POSEWARP_RETURN_IF_ERROR(progress.check_cancel());

    // Pass 2, the skin shell: an uncovered voxel whose shell ellipsoid holds a covered voxel's centre takes the
    // map of the nearest such voxel's tet. Neighbour offsets in order of distance; rows far from any covered voxel
    // are skipped by the rows' covered extents.
    struct Offset {
      int64_t di, dj, dk;
      double distance;
    };
    std::vector<Offset> offsets;
    for (int64_t dk = -reach[2]; dk <= reach[2]; ++dk) {
      for (int64_t dj = -reach[1]; dj <= reach[1]; ++dj) {
        for (int64_t di = -reach[0]; di <= reach[0]; ++di) {
          const double x = double(di) * output.spacing[0], y = double(dj) * output.spacing[1], z = double(dk) * output.spacing[2];
          const double inside = (x / shell[0]) * (x / shell[0]) + (y / shell[1]) * (y / shell[1]) + (z / shell[2]) * (z / shell[2]);
          if ((di || dj || dk) && inside <= 1.0 + 1e-12) offsets.push_back({di, dj, dk, std::sqrt(x * x + y * y + z * z)});
        }
      }
    }
    std::stable_sort(offsets.begin(), offsets.end(), [](const Offset& a, const Offset& b) { return a.distance < b.distance; });
    std::vector<std::vector<std::pair<int64_t, int32_t>>> shells(static_cast<size_t>(slab_count));  // (slab voxel, owner)
    parallel_for(0, slab_count, 1, [&](int64_t s0, int64_t s1) {
      for (int64_t s = s0; s < s1; ++s) {
        if (progress.cancel_requested()) return;  // per slab: a cancelled or expired call ends within one slab
        int64_t kb = 0, ke = 0;
        if (!slab_range(s, kb, ke) || offsets.empty()) continue;
        const int64_t slab_begin = kb * n[0] * n[1];
        std::vector<std::pair<int64_t, int32_t>>& found = shells[static_cast<size_t>(s)];
        for (int64_t k = kb; k < ke; ++k) {
          for (int64_t j = 0; j < n[1]; ++j) {
            int64_t lo = n[0], hi = -1;  // the hull of the neighbour rows' covered extents, grown by the reach
            for (int64_t dk = std::max<int64_t>(-reach[2], -k); dk <= reach[2] && k + dk < n[2]; ++dk) {
              for (int64_t dj = std::max<int64_t>(-reach[1], -j); dj <= reach[1] && j + dj < n[1]; ++dj) {
                const size_t row = static_cast<size_t>(j + dj + n[1] * (k + dk));
                if (row_first[row] > row_last[row]) continue;
                lo = std::min<int64_t>(lo, row_first[row] - reach[0]);
                hi = std::max<int64_t>(hi, row_last[row] + reach[0]);
              }
            }
            lo = std::max<int64_t>(lo, 0);
            hi = std::min<int64_t>(hi, n[0] - 1);
            for (int64_t i = lo; i <= hi; ++i) {
              const int64_t v = output.offset(i, j, k);
              if (owner[v] >= 0) continue;
              for (const Offset& o : offsets) {
                const int64_t x = i + o.di, y = j + o.dj, z = k + o.dk;
                if (x < 0 || y < 0 || z < 0 || x >= n[0] || y >= n[1] || z >= n[2]) continue;
                const int32_t near = owner[output.offset(x, y, z)];
                if (near >= 0) {
                  found.emplace_back(v - slab_begin, near);
                  break;
                }
              }
            }
          }
        }
      }
    });

    // Pass 3, classify every voxel. Without a rest owner: covered, shell or background. With one, a voxel the
    // moving tets left alone maps through the background transform to a source voxel whose rest owner says what it
    // is: a tet that follows the background (covered, or its shell), nothing (background), or a moving tet (the
    // body moved away from there: the shell of a moving tet, or nothing to sample).
    // Then the bones claim their voxels, ahead of any tet: a moving bone where its own rigid inverse lands on one of
    // its source voxels; a bone that follows the background where a moving tet or the shell would sample it.
    std::vector<WarpStats> slab_stats(static_cast<size_t>(slab_count));
    const int16_t* bone_of = bones ? bones->voxels->segment.data() : nullptr;
    const bool guard_contacts = bones && bones->region && bones->tet_region && bones->separated;
    auto bone_at = [&](const double* map, double i, double j, double k) -> int {
      double src[3];
      apply_map(map, i, j, k, src);
      const int64_t x = round_index(src[0]), y = round_index(src[1]), z = round_index(src[2]);
      if (x < 0 || y < 0 || z < 0 || x >= source.size[0] || y >= source.size[1] || z >= source.size[2]) return -1;
      return bone_of[source.offset(x, y, z)];
    };
    parallel_for(0, slab_count, 1, [&](int64_t s0, int64_t s1) {
      for (int64_t s = s0; s < s1; ++s) {
        if (progress.cancel_requested()) return;  // per slab: a cancelled or expired call ends within one slab
        int64_t kb = 0, ke = 0;
        if (!slab_range(s, kb, ke)) continue;
        const int64_t slab_begin = kb * n[0] * n[1];
        std::vector<uint8_t>& conflict = conflicts[static_cast<size_t>(s)];
        WarpStats& bone_stats = slab_stats[static_cast<size_t>(s)];
        std::vector<std::array<int64_t, 3>> row_bones;  // (segment, i0, i1) of the moving bones on a row
        // Drops a tet's (or its shell's) sample of tissue from a body part separated from the tet's own.
        auto guard_contact = [&](int32_t& o, int64_t i, int64_t j, int64_t k) {
          const bool tet_owned = o >= 0, shell_owned = o <= -2 && o != kNoSample && !is_bone_owner(o);
          if (!tet_owned && !shell_owned) return;
          const int32_t c = tet_owned ? o : -2 - o;
          const int rt = (*bones->tet_region)[static_cast<size_t>(tets[static_cast<size_t>(c)])];
          double src[3];
          apply_map(warp.maps_.get() + 12 * c, double(i), double(j), double(k), src);
          const int64_t x = round_index(src[0]), y = round_index(src[1]), z = round_index(src[2]);
          if (rt < 0 || x < 0 || y < 0 || z < 0 || x >= source.size[0] || y >= source.size[1] || z >= source.size[2]) return;
          const int rs = (*bones->region)[static_cast<size_t>(source.offset(x, y, z))];
          if (rs < 0 || rs == rt || !(*bones->separated)[static_cast<size_t>(rt) * segment_count + static_cast<size_t>(rs)]) return;
          o = kNoSample;
          ++bone_stats.contact_guarded_voxels;
        };
        // Claims voxel (i, j, k) for a bone, given its owner after classification.
        auto claim_bone = [&](int32_t& o, int64_t i, int64_t j, int64_t k) {
          int claimed = -1;
          for (const auto& [segment, i0, i1] : row_bones) {
            if (i < i0 || i > i1) continue;
            const int k_seg = static_cast<int>(segment);
            if (bone_at(warp.bone_maps_.data() + 12 * k_seg, double(i), double(j), double(k)) != k_seg) continue;
            if (claimed < 0) {
              claimed = k_seg;
            } else {
              ++bone_stats.bone_overlap_voxels[{std::min(claimed, k_seg), std::max(claimed, k_seg)}];
              claimed = std::min(claimed, k_seg);
            }
          }
          if (o >= 0 || (o <= -2 && o != kNoSample)) {
            const int still = bone_at(warp.background_map_, double(i), double(j), double(k));
            if (still >= 0 && !bone_moves[static_cast<size_t>(still)]) {
              if (claimed < 0) {
                claimed = still;
              } else if (claimed != still) {
                ++bone_stats.bone_overlap_voxels[{std::min(claimed, still), std::max(claimed, still)}];
                claimed = std::min(claimed, still);
              }
            }
          }
          if (claimed >= 0) {
            o = kBoneOwner + claimed;
            ++bone_stats.bone_voxels;
          }
        };
        const std::vector<std::pair<int64_t, int32_t>>& found = shells[static_cast<size_t>(s)];
        size_t next_shell = 0;
        int64_t covered = 0, extrapolated = 0, background = 0, conflicted = 0;
        const double* bg = warp.background_map_;
        // Where the background map steps one source voxel along x per output voxel from a whole source index (the
        // root does not move and the grid is the input's), a row's rest owners are one row of rest_owner.
        const bool bg_steps_x = steps_one_x(bg[0], bg[3], bg[6]);
        for (int64_t k = kb; k < ke; ++k) {
          for (int64_t j = 0; j < n[1]; ++j) {
            row_bones.clear();
            for (int seg = 0; seg < segment_count; ++seg) {
              const std::array<double, 6>& box = bone_box[static_cast<size_t>(seg)];
              if (!bone_moves[static_cast<size_t>(seg)] || double(j) < box[1] || double(j) > box[4] ||
                  double(k) < box[2] || double(k) > box[5]) {
                continue;
              }
              row_bones.push_back({seg, std::max<int64_t>(0, static_cast<int64_t>(fast_ceil(box[0]))),
                                   std::min<int64_t>(n[0] - 1, static_cast<int64_t>(fast_floor(box[3])))});
            }
            const int64_t row_begin = output.offset(0, j, k);
            const int64_t local_begin = row_begin - slab_begin;
            double row[3];
            apply_map(bg, 0.0, double(j), double(k), row);
            const int32_t* rest_row = nullptr;  // rest_owner at source x = i + x0 for this output row
            int64_t x0 = 0, y = 0, z = 0;
            const bool fast = rest_owner && bg_steps_x && integral(row[0], x0) && integral(row[1], y) && integral(row[2], z);
            if (fast && y >= 0 && z >= 0 && y < source.size[1] && z < source.size[2]) {
              rest_row = rest_owner->data() + source.offset(0, y, z);
            }
            for (int64_t i = 0; i < n[0]; ++i) {
              const int64_t local = local_begin + i;
              int32_t& o = owner[row_begin + i];
              int32_t shell_owner = -1;
              if (next_shell < found.size() && found[next_shell].first == local) shell_owner = found[next_shell++].second;
              if (!rest_owner) {
                if (o >= 0) {
                  ++covered;
                } else if (shell_owner >= 0) {
                  o = -2 - shell_owner;
                  ++extrapolated;
                } else {
                  ++background;
                }
                conflicted += conflict[static_cast<size_t>(local)];
                if (guard_contacts) guard_contact(o, i, j, k);
                if (segment_count > 0) claim_bone(o, i, j, k);
                continue;
              }
              const double di = double(i);
              int32_t ro = -1;
              if (fast) {
                const int64_t x = x0 + i;
                if (rest_row && x >= 0 && x < source.size[0]) ro = rest_row[x];
              } else {
                const double sb[3] = {row[0] + di * bg[0], row[1] + di * bg[3], row[2] + di * bg[6]};
                ro = rest_owner_at(sb);
              }
              if (ro == kNoSample) ro = -1;
              int32_t rt = ro >= 0 ? ro : ro <= -2 ? -2 - ro : -1;  // the rest tet behind that code
              if (rt >= nt) ro = rt = -1;  // not a tet of this mesh: as if nothing held the voxel
              const bool still = rt >= 0 && !moving[static_cast<size_t>(rt)];
              if (o >= 0) {
                // A moving tet covers it; a tet that follows the background may cover it too (a fold).
                if (ro >= 0 && still &&
                    wins(bg, ro, warp.maps_.get() + 12 * o, tets[static_cast<size_t>(o)], di, double(j), double(k),
                         conflict[static_cast<size_t>(local)])) {
                  o = -1;
                }
                ++covered;
              } else if (still) {
                o = -1;
                ++(ro >= 0 ? covered : extrapolated);
              } else if (shell_owner >= 0) {
                o = -2 - shell_owner;
                ++extrapolated;
              } else {
                o = rt < 0 ? -1 : kNoSample;
                ++background;
              }
              conflicted += conflict[static_cast<size_t>(local)];
              if (guard_contacts) guard_contact(o, i, j, k);
              if (segment_count > 0) claim_bone(o, i, j, k);
            }
          }
        }
        WarpStats& st = slab_stats[static_cast<size_t>(s)];
        st.covered_voxels = covered;
        st.extrapolated_voxels = extrapolated;
        st.background_voxels = background;
        st.conflicted_voxels = conflicted;
        std::vector<uint8_t>().swap(conflict);
        progress.advance(1, 2 * slab_count);
      }
    });
    POSEWARP_RETURN_IF_ERROR(progress.check_cancel());
    for (const WarpStats& st : slab_stats) {
      warp.stats_.covered_voxels += st.covered_voxels;
      warp.stats_.extrapolated_voxels += st.extrapolated_voxels;
      warp.stats_.background_voxels += st.background_voxels;
      warp.stats_.conflicted_voxels += st.conflicted_voxels;
      warp.stats_.bone_voxels += st.bone_voxels;
      warp.stats_.contact_guarded_voxels += st.contact_guarded_voxels;
      for (const auto& [pair, count] : st.bone_overlap_voxels) warp.stats_.bone_overlap_voxels[pair] += count;
    }
    return ok_status();
  });
  if (!prepared.ok()) return prepared;
  progress.finish();
  return warp;
}

const double* TetWarp::map_of(int32_t o) const {
  if (o >= 0) return maps_.get() + 12 * o;
  if (is_bone_owner(o)) return bone_maps_.data() + 12 * (o - kBoneOwner);
  if (o <= -2 && o != kNoSample) return maps_.get() + 12 * (-2 - o);
  return background_map_;
}

template <typename Sample>
void TetWarp::for_each_mapped_run(const Sample& sample) const {
  const Index3& n = output_.size;
  const int32_t* owner = owner_.get();
  parallel_for(0, n[2], 1, [&](int64_t k0, int64_t k1) {
    for (int64_t k = k0; k < k1; ++k) {
      for (int64_t j = 0; j < n[1]; ++j) {
        const int64_t row = output_.offset(0, j, k);
        for (int64_t i = 0; i < n[0];) {
          const int32_t o = owner[row + i];
          int64_t end = i + 1;
          while (end < n[0] && owner[row + end] == o) ++end;
          if (o != kNoSample) {
            const double* m = map_of(o);
            double s[3];
            apply_map(m, double(i), double(j), double(k), s);
            const double ds[3] = {m[0], m[3], m[6]};
            const bool soft = o >= 0 || (o <= -2 && !is_bone_owner(o));
            sample(row + i, end - i, s, ds, soft);
          }
          i = end;
        }
      }
    }
  });
}

Result<LabelVolume> TetWarp::warp_labels(const LabelVolume& labels) const {
  if (!labels.geometry().same_grid(source_, 1e-3)) {
    return invalid_argument_error("the label volume is not on the grid the rig was built from");
  }
  POSEWARP_ASSIGN_OR_RETURN(LabelVolume out, guarded("for the output labels (" + output_.describe() + ")",
                                                       [&]() -> Result<LabelVolume> {
                                                         return LabelVolume(output_, label_background_);
                                                       }));
  out.set_source_type(labels.source_type());
  const Index3& m = source_.size;
  const Label* in = labels.data();
  Label* dst = out.data();
  const int16_t* bone_of = bones_ ? bones_->segment.data() : nullptr;
  const int32_t* substitute = bones_ ? bones_->substitute.data() : nullptr;
  for_each_mapped_run([&](int64_t v, int64_t count, const double s0[3], const double ds[3], bool soft) {
    const bool keep_bones_out = soft && bone_of;
    if (!keep_bones_out && steps_one_x(ds[0], ds[1], ds[2])) {  // a run along a source row: copy it
      copy_source_row(in, m, round_index(s0[0]), round_index(s0[1]), round_index(s0[2]), count, dst + v);
      return;
    }
    for (int64_t c = 0; c < count; ++c) {
      const double dc = double(c);
      const int64_t x = round_index(s0[0] + dc * ds[0]), y = round_index(s0[1] + dc * ds[1]),
                    z = round_index(s0[2] + dc * ds[2]);
      if (x < 0 || y < 0 || z < 0 || x >= m[0] || y >= m[1] || z >= m[2]) continue;
      int64_t at = x + m[0] * (y + m[1] * z);
      if (keep_bones_out && bone_of[at] >= 0) at = substitute[at];
      dst[v + c] = in[at];
    }
  });
  return out;
}

Result<IntensityVolume> TetWarp::warp_intensities(const IntensityVolume& source, Interpolation interpolation) const {
  if (!source.geometry().same_grid(source_, 1e-3)) {
    return invalid_argument_error("the intensity volume is not on the grid the rig was built from");
  }
  POSEWARP_ASSIGN_OR_RETURN(IntensityVolume out, guarded("for the output intensities (" + output_.describe() + ")",
                                                           [&]() -> Result<IntensityVolume> {
                                                             return IntensityVolume(output_, intensity_background_);
                                                           }));
  out.set_source_type(source.source_type());
  const Index3& m = source_.size;
  const float* in = source.data();
  float* dst = out.data();
  const int64_t sy = m[0], sz = m[0] * m[1];
  const int64_t dx = m[0] > 1 ? 1 : 0, dy = m[1] > 1 ? sy : 0, dz = m[2] > 1 ? sz : 0;
  const double hi[3] = {static_cast<double>(m[0]) - 0.5, static_cast<double>(m[1]) - 0.5, static_cast<double>(m[2]) - 0.5};
  const double top[3] = {static_cast<double>(m[0] - 1), static_cast<double>(m[1] - 1), static_cast<double>(m[2] - 1)};
  const int64_t base_max[3] = {std::max<int64_t>(0, m[0] - 2), std::max<int64_t>(0, m[1] - 2), std::max<int64_t>(0, m[2] - 2)};
  const int16_t* bone_of = bones_ ? bones_->segment.data() : nullptr;
  const int32_t* substitute = bones_ ? bones_->substitute.data() : nullptr;
  for_each_mapped_run([&](int64_t v, int64_t count, const double s0[3], const double ds[3], bool soft) {
    const bool keep_bones_out = soft && bone_of;
    int64_t x0 = 0, y = 0, z = 0;
    if (!keep_bones_out && steps_one_x(ds[0], ds[1], ds[2]) && integral(s0[0], x0) && integral(s0[1], y) &&
        integral(s0[2], z)) {
      // A run along a source row through voxel centres: either interpolation gives the voxels themselves.
      copy_source_row(in, m, x0, y, z, count, dst + v);
      return;
    }
    for (int64_t c = 0; c < count; ++c) {
      const double dc = double(c);
      const double s[3] = {s0[0] + dc * ds[0], s0[1] + dc * ds[1], s0[2] + dc * ds[2]};
      if (s[0] < -0.5 || s[1] < -0.5 || s[2] < -0.5 || s[0] > hi[0] || s[1] > hi[1] || s[2] > hi[2]) continue;
      if (keep_bones_out) {
        const int64_t nearest = round_index(s[0]) + sy * round_index(s[1]) + sz * round_index(s[2]);
        if (bone_of[nearest] >= 0) {
          dst[v + c] = in[substitute[nearest]];
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
      const float* p = in + base[0] + base[1] * sy + base[2] * sz;
      const double c00 = p[0] + f[0] * (p[dx] - p[0]);
      const double c10 = p[dy] + f[0] * (p[dy + dx] - p[dy]);
      const double c01 = p[dz] + f[0] * (p[dz + dx] - p[dz]);
      const double c11 = p[dz + dy] + f[0] * (p[dz + dy + dx] - p[dz + dy]);
      const double e0 = c00 + f[1] * (c10 - c00);
      const double e1 = c01 + f[1] * (c11 - c01);
      dst[v + c] = static_cast<float>(e0 + f[2] * (e1 - e0));
    }
  });
  return out;
}

std::vector<int32_t> TetWarp::owner() const {
  std::vector<int32_t> tet_owner(owner_.get(), owner_.get() + output_.voxel_count());
  for (int32_t& o : tet_owner) {
    if (o >= 0) {
      o = tets_[static_cast<size_t>(o)];
    } else if (o <= -2 && o != kNoSample && !is_bone_owner(o)) {
      o = -2 - tets_[static_cast<size_t>(-2 - o)];
    }
  }
  return tet_owner;
}

std::vector<std::pair<double, double>> TetWarp::bone_deviation_mm() const {
  if (!bones_) return {};
  const int segment_count = static_cast<int>(bone_maps_.size() / 12);
  const Index3& n = output_.size;
  const Index3& m = source_.size;
  Eigen::Matrix3d to_mm;  // source index step -> mm
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) to_mm(r, c) = source_.direction[static_cast<size_t>(3 * r + c)] * source_.spacing[static_cast<size_t>(c)];
  // Per slice, the deviations of the voxels holding a bone value, by segment; then max and 99th percentile.
  std::vector<std::vector<std::vector<float>>> found(static_cast<size_t>(n[2]));
  parallel_for(0, n[2], 1, [&](int64_t k0, int64_t k1) {
    for (int64_t k = k0; k < k1; ++k) {
      std::vector<std::vector<float>>& slice = found[static_cast<size_t>(k)];
      slice.assign(static_cast<size_t>(segment_count), {});
      for (int64_t j = 0; j < n[1]; ++j) {
        for (int64_t i = 0; i < n[0]; ++i) {
          const int32_t o = owner_[output_.offset(i, j, k)];
          if (o == kNoSample) continue;
          double s[3];
          apply_map(map_of(o), double(i), double(j), double(k), s);
          const int64_t x = round_index(s[0]), y = round_index(s[1]), z = round_index(s[2]);
          if (x < 0 || y < 0 || z < 0 || x >= m[0] || y >= m[1] || z >= m[2]) continue;
          const int segment = bones_->segment[static_cast<size_t>(x + m[0] * (y + m[1] * z))];
          const bool soft = o >= 0 || (o <= -2 && !is_bone_owner(o));
          if (segment < 0 || soft) continue;  // no bone value here (a soft map takes the substitute)
          double b[3];
          apply_map(bone_maps_.data() + 12 * segment, double(i), double(j), double(k), b);
          const Eigen::Vector3d d(s[0] - b[0], s[1] - b[1], s[2] - b[2]);
          slice[static_cast<size_t>(segment)].push_back(static_cast<float>((to_mm * d).norm()));
        }
      }
    }
  });
  std::vector<std::pair<double, double>> result(static_cast<size_t>(segment_count), {0.0, 0.0});
  for (int segment = 0; segment < segment_count; ++segment) {
    std::vector<float> all;
    for (const auto& slice : found) all.insert(all.end(), slice[static_cast<size_t>(segment)].begin(), slice[static_cast<size_t>(segment)].end());
    if (all.empty()) continue;
    const size_t p99 = std::min(all.size() - 1, static_cast<size_t>(0.99 * static_cast<double>(all.size())));
    std::nth_element(all.begin(), all.begin() + static_cast<std::ptrdiff_t>(p99), all.end());
    const double percentile = all[p99];
    result[static_cast<size_t>(segment)] = {*std::max_element(all.begin(), all.end()), percentile};
  }
  return result;
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
          apply_map(map_of(owner_[v]), double(i), double(j), double(k), s);
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
