// TetWarp::build: the maps, the tets to rasterize and their raster data, then three passes over output slabs
// (rasterize the moving tets and resolve folds, find the skin shell, classify every voxel and let the bones claim
// theirs), each thread owning whole slabs as ITK threads over output regions.
#include <Eigen/Dense>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>
#include <optional>
#include <string>
#include <utility>

#include "avx2.h"
#include "posewarp/common/exception_wall.h"
#include "posewarp/common/parallel.h"
#include "posewarp/common/voxel_memory.h"
#include "posewarp/resample/tet_warp.h"
#include "raster.h"

namespace posewarp::resample {

using namespace internal;

// build()'s steps, split the way ITK splits a filter: the maps (background and bones), the tets to rasterize and
// their raster data, then three passes over output slabs in parallel (each thread owns whole slabs): rasterize the
// moving tets and resolve folds, find the skin shell, classify every voxel and let the bones claim theirs. Each step
// reads what the ones before it left in the members.
class TetWarp::Builder {
 public:
  Builder(const WarpInputs& in, const ProgressHooks& hooks) : in_(in), hooks_(hooks), n_(in.output.size) {}

  Result<TetWarp> run() {
    POSEWARP_RETURN_IF_ERROR(check(in_));
    progress_.emplace(hooks_, "warp-prepare");
    POSEWARP_RETURN_IF_ERROR(size_shell());
    warp_.source_ = in_.source;
    warp_.output_ = in_.output;
    warp_.label_background_ = in_.params.label_background;
    warp_.intensity_background_ = in_.params.intensity_background;
    const Status prepared = guarded("preparing the warp onto " + in_.output.describe(), [&]() -> Status {
      out_space_ = index_space(in_.output);
      src_space_ = index_space(in_.source);
      prepare_maps();
      select_tets();
      // The raster data and slab lists live in buffers this thread keeps between warps: on a 2-core VM, faulting in
      // tens of MB of fresh pages per pose costs as much as the raster itself. A warp started on this thread while
      // another is in flight on it (a task stolen inside a parallel loop), or one larger than kKeptScratchBytes,
      // gets buffers of its own.
      thread_local RasterScratch kept;
      RasterScratch own;
      const bool keep = !kept.busy && warp_.tets_.size() * sizeof(RasterTet) <= kKeptScratchBytes;
      scratch_ = keep ? &kept : &own;
      const ScratchLease lease(*scratch_);
      prepare_raster();
      POSEWARP_RETURN_IF_ERROR(progress_->check_cancel());
      progress_->update(0.2);
      split_into_slabs();
      in_slabs([this](int64_t s) { rasterize_slab(s); });  // pass 1
      POSEWARP_RETURN_IF_ERROR(progress_->check_cancel());
      offsets_ = shell_offsets(in_.output, shell_, reach_);
      in_slabs([this](int64_t s) { find_shell(s); });     // pass 2
      in_slabs([this](int64_t s) { classify_slab(s); });  // pass 3
      POSEWARP_RETURN_IF_ERROR(progress_->check_cancel());
      for (const WarpStats& slab : slab_stats_) warp_.stats_ += slab;
      return ok_status();
    });
    if (!prepared.ok()) return prepared;
    progress_->finish();
    return std::move(warp_);
  }

 private:
  // The shell is an ellipsoid around each uncovered voxel, semi-axes shell_[a] mm along the output axes: by default
  // two source voxels along each axis (so a 5 mm slice thickness reaches one slice, not 12 in-plane voxels).
  Status size_shell() {
    for (int a = 0; a < 3; ++a) {
      const double source_spacing = in_.source.spacing[static_cast<size_t>(a)];
      shell_[a] = in_.params.shell_mm > 0.0 ? in_.params.shell_mm : 2.0 * source_spacing;
      reach_[a] = static_cast<int64_t>(std::min(shell_[a] / in_.output.spacing[static_cast<size_t>(a)], 1e6));
      if (reach_[a] > kMaxShellVoxels && in_.params.shell_mm > 0.0) {
        return invalid_argument_error("a skin shell of " + std::to_string(in_.params.shell_mm) +
                                      " mm spans more than " + std::to_string(kMaxShellVoxels) +
                                      " voxels of the output grid; use a thinner shell");
      }
      reach_[a] = std::min(reach_[a], kMaxShellVoxels);  // the default on a much finer output grid
    }
    return ok_status();
  }

  // Output index -> output physical -> rest physical (inverse rigid) -> source index.
  void rigid_map(const Eigen::Matrix3d& rotation, const Eigen::Vector3d& translation, double* m) const {
    const Eigen::Matrix3d a = src_space_.to_index * rotation.transpose() * out_space_.to_physical;
    const Eigen::Vector3d b =
        src_space_.to_index * (rotation.transpose() * (out_space_.origin - translation) - src_space_.origin);
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) m[3 * r + c] = a(r, c);
      m[9 + r] = b(r);
    }
  }

  // Step 1: the background's map, each bone's, which bones move off the background, and each moving bone's posed
  // index box in the output.
  void prepare_maps() {
    rigid_map(in_.background_rotation, in_.background_translation, warp_.background_map_);
    if (!in_.bones) return;
    const RigidBones& bones = *in_.bones;
    segment_count_ = static_cast<int>(bones.rotation.size());
    bone_moves_.assign(static_cast<size_t>(segment_count_), 0);
    bone_box_.resize(static_cast<size_t>(segment_count_));
    warp_.bones_ = bones.voxels;
    warp_.bone_maps_.assign(static_cast<size_t>(segment_count_) * 12, 0.0);
    for (int k = 0; k < segment_count_; ++k) {
      const Eigen::Matrix3d& rotation = bones.rotation[static_cast<size_t>(k)];
      const Eigen::Vector3d& translation = bones.translation[static_cast<size_t>(k)];
      rigid_map(rotation, translation, warp_.bone_maps_.data() + 12 * k);
      bone_moves_[static_cast<size_t>(k)] = (rotation - in_.background_rotation).cwiseAbs().maxCoeff() > 1e-12 ||
                                            (translation - in_.background_translation).cwiseAbs().maxCoeff() > 1e-9;
      const std::array<int64_t, 6>& box = bones.voxels->box[static_cast<size_t>(k)];
      std::array<double, 6>& out_box = bone_box_[static_cast<size_t>(k)];
      out_box = {1.0, 1.0, 1.0, 0.0, 0.0, 0.0};  // empty
      if (box[0] > box[3]) {
        bone_moves_[static_cast<size_t>(k)] = 0;
        continue;
      }
      out_box = posed_index_box(box, rotation, translation, src_space_, out_space_, n_);
    }
    // claim_bone claims a moving bone's voxels through the bone's map, a still one's through the background's.
    warp_.claimed_by_own_map_.assign(static_cast<size_t>(segment_count_), 0);
    for (int k = 0; k < segment_count_; ++k) {
      warp_.claimed_by_own_map_[static_cast<size_t>(k)] =
          bone_moves_[static_cast<size_t>(k)] ||
          std::equal(warp_.background_map_, warp_.background_map_ + 12, warp_.bone_maps_.data() + 12 * k);
    }
  }

  // Step 2: the vertices in output (posed) and source (rest) index space once, row-major; the tets to rasterize (all
  // of them without a rest owner, else those with a vertex off the background, to a millionth of a voxel), in the
  // order of their lowest posed k (a counting sort on whole k, tet order within one), so that each slab reads its
  // tets' raster data nearly in sequence.
  void select_tets() {
    const TetMesh& rest = in_.rest;
    const int64_t nt = rest.tet_count(), nv = rest.vertex_count();
    posed_index_.resize(static_cast<size_t>(nv) * 3);
    rest_index_.resize(static_cast<size_t>(nv) * 3);
    std::vector<uint8_t> follows(static_cast<size_t>(nv), 0);
    const ImageGeometry& output = in_.output;
    const double follow_tolerance = 1e-6 * std::min({output.spacing[0], output.spacing[1], output.spacing[2]});
    parallel_for(0, nv, 8192, [&](int64_t begin, int64_t end) {
      for (int64_t v = begin; v < end; ++v) {
        const Eigen::Vector3d x = in_.posed.row(v).transpose();
        const Eigen::Vector3d p = rest.vertices.row(v).transpose();
        const Eigen::Vector3d u = out_space_.to_index * (x - out_space_.origin);
        const Eigen::Vector3d s = src_space_.to_index * (p - src_space_.origin);
        for (int a = 0; a < 3; ++a) {
          posed_index_[static_cast<size_t>(3 * v + a)] = u(a);
          rest_index_[static_cast<size_t>(3 * v + a)] = s(a);
        }
        if (in_.rest_owner) {
          follows[static_cast<size_t>(v)] =
              (in_.background_rotation * p + in_.background_translation - x).cwiseAbs().maxCoeff() <= follow_tolerance;
        }
      }
    });
    moving_.assign(static_cast<size_t>(nt), 1);
    if (in_.rest_owner) {
      parallel_for(0, nt, 8192, [&](int64_t begin, int64_t end) {
        for (int64_t t = begin; t < end; ++t) {
          bool all_follow = true;
          for (int c = 0; c < 4; ++c) all_follow = all_follow && follows[static_cast<size_t>(rest.tets(t, c))];
          moving_[static_cast<size_t>(t)] = all_follow ? 0 : 1;
        }
      });
    }
    std::vector<int32_t>& tets = warp_.tets_;  // rasterized index -> tet
    for (int64_t t = 0; t < nt; ++t) {
      if (moving_[static_cast<size_t>(t)]) tets.push_back(static_cast<int32_t>(t));
    }
    const int64_t nz = n_[2];
    std::vector<int32_t> bucket(tets.size());
    std::vector<int64_t> start(static_cast<size_t>(nz) + 1, 0);
    for (size_t c = 0; c < tets.size(); ++c) {
      double z = std::numeric_limits<double>::infinity();
      for (int q = 0; q < 4; ++q) z = std::min(z, posed_index_[static_cast<size_t>(rest.tets(tets[c], q)) * 3 + 2]);
      bucket[c] = static_cast<int32_t>(
          std::clamp<double>(fast_floor(std::clamp(z, -1.0, 1e9)), 0.0, static_cast<double>(nz - 1)));
      ++start[static_cast<size_t>(bucket[c]) + 1];
    }
    for (size_t b = 1; b < start.size(); ++b) start[b] += start[b - 1];
    std::vector<int32_t> sorted(tets.size());
    for (size_t c = 0; c < tets.size(); ++c)
      sorted[static_cast<size_t>(start[static_cast<size_t>(bucket[c])]++)] = tets[c];
    tets.swap(sorted);
    warp_.rasterized_tets_ = static_cast<int64_t>(tets.size());
  }

  // Step 3: per rasterized tet, densely (a pose that moves a few tets touches only theirs), the output-index ->
  // source-index map, the raster data and the output k it spans; a tet with no volume once posed is skipped.
  void prepare_raster() {
    const int64_t nm = warp_.rasterized_tets_;
    warp_.maps_ = std::shared_ptr<double[]>(new double[static_cast<size_t>(std::max<int64_t>(nm, 1)) * 12]);
    if (scratch_->raster.size() < static_cast<size_t>(nm)) scratch_->raster.resize(static_cast<size_t>(nm));
    raster_ = scratch_->raster.data();
    std::vector<uint8_t> usable(static_cast<size_t>(nm), 0);
    k_range_.assign(static_cast<size_t>(nm), {1, 0});
    parallel_for(0, nm, 2048, [&](int64_t begin, int64_t end) {
      for (int64_t c = begin; c < end; ++c) usable[static_cast<size_t>(c)] = prepare_tet(c);
    });
    for (const uint8_t ok : usable) warp_.stats_.degenerate_tets += ok ? 0 : 1;
  }

  // Rasterized tet c's raster data and map; false for a tet with no volume once posed.
  bool prepare_tet(int64_t c) {
    const int64_t t = warp_.tets_[static_cast<size_t>(c)];
    Eigen::Vector3d u[4], s[4];
    for (int q = 0; q < 4; ++q) {
      const size_t v = static_cast<size_t>(in_.rest.tets(t, q)) * 3;
      u[q] = Eigen::Vector3d(posed_index_[v], posed_index_[v + 1], posed_index_[v + 2]);
      s[q] = Eigen::Vector3d(rest_index_[v], rest_index_[v + 1], rest_index_[v + 2]);
    }
    Eigen::Matrix3d ue, se;
    for (int q = 0; q < 3; ++q) ue.col(q) = u[q + 1] - u[0], se.col(q) = s[q + 1] - s[0];
    const double det = ue.determinant();
    if (!(std::abs(det) > 1e-12) || !std::isfinite(det)) return false;
    const Eigen::Matrix3d inverse = ue.inverse();
    RasterTet& r = raster_[static_cast<size_t>(c)];
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
      const double top = static_cast<double>(n_[static_cast<size_t>(a)]);
      r.lo[a] = std::clamp(std::min({u[0](a), u[1](a), u[2](a), u[3](a)}), -2.0, top + 1.0);
      r.hi[a] = std::clamp(std::max({u[0](a), u[1](a), u[2](a), u[3](a)}), -2.0, top + 1.0);
    }
    const Eigen::Matrix3d a = se * inverse;
    const Eigen::Vector3d b = s[0] - a * u[0];
    double* m = warp_.maps_.get() + 12 * c;
    for (int row = 0; row < 3; ++row) {
      for (int q = 0; q < 3; ++q) m[3 * row + q] = a(row, q);
      m[9 + row] = b(row);
    }
    k_range_[static_cast<size_t>(c)] = {
        static_cast<int32_t>(std::max<int64_t>(0, static_cast<int64_t>(fast_ceil(r.lo[2])))),
        static_cast<int32_t>(std::min<int64_t>(n_[2] - 1, static_cast<int64_t>(fast_floor(r.hi[2]))))};
    return true;
  }

  // Slabs along output k; each tet goes to every slab its index box meets. The owner map and the rows' covered
  // extents for the passes.
  void split_into_slabs() {
    slab_count_ = std::clamp<int64_t>(n_[2], 1, 16 * static_cast<int64_t>(thread_count()));
    slab_depth_ = (n_[2] + slab_count_ - 1) / slab_count_;
    std::vector<std::vector<int32_t>>& interior = scratch_->interior;
    if (interior.size() < static_cast<size_t>(slab_count_)) interior.resize(static_cast<size_t>(slab_count_));
    for (std::vector<int32_t>& list : interior) list.clear();
    for (int64_t c = 0; c < warp_.rasterized_tets_; ++c) {
      const auto [k0, k1] = k_range_[static_cast<size_t>(c)];
      for (int64_t s = k0 / slab_depth_; k0 <= k1 && s <= k1 / slab_depth_; ++s) {
        interior[static_cast<size_t>(s)].push_back(static_cast<int32_t>(c));
      }
    }
    const size_t owner_bytes = static_cast<size_t>(in_.output.voxel_count()) * sizeof(int32_t);
    warp_.owner_ = std::shared_ptr<int32_t[]>(static_cast<int32_t*>(allocate_voxels(owner_bytes)),
                                              [owner_bytes](int32_t* p) { free_voxels(p, owner_bytes); });
    owner_ = warp_.owner_.get();
    const int64_t row_count = n_[1] * n_[2];
    row_first_.resize(static_cast<size_t>(row_count));
    row_last_.resize(static_cast<size_t>(row_count));
    row_words_ = (n_[0] + 63) / 64;
    covered_bits_.resize(static_cast<size_t>(row_count * row_words_));
    conflicts_.resize(static_cast<size_t>(slab_count_));
    shells_.resize(static_cast<size_t>(slab_count_));
    slab_stats_.resize(static_cast<size_t>(slab_count_));
  }

  // Runs `pass` on every slab, slabs in parallel; a cancelled or expired call ends within one slab.
  template <typename Pass>
  void in_slabs(const Pass& pass) {
    parallel_for(0, slab_count_, 1, [&](int64_t s0, int64_t s1) {
      for (int64_t s = s0; s < s1; ++s) {
        if (progress_->cancel_requested()) return;
        pass(s);
      }
    });
  }

  bool slab_range(int64_t s, int64_t& kb, int64_t& ke) const {
    kb = s * slab_depth_;
    ke = std::min(n_[2], kb + slab_depth_);
    return kb < ke;
  }

  // Does rasterized tet a win voxel (i, j, k) from rasterized tet b (bones win, then the lower tet index; owner codes
  // hold rasterized indices, the fold rule speaks of tets)? Marks a fold where their maps disagree.
  bool wins(const double* map_a, int32_t a, const double* map_b, int32_t b, double i, double j, double k,
            uint8_t& conflicted) const {
    double sa[3], sb[3];
    apply_map(map_a, i, j, k, sa);
    apply_map(map_b, i, j, k, sb);
    if (std::abs(sa[0] - sb[0]) + std::abs(sa[1] - sb[1]) + std::abs(sa[2] - sb[2]) > 0.5) conflicted = 1;
    const Eigen::VectorXi& tet_class = in_.rest.tet_class;
    const int pa = tet_class(a) >= kFirstBoneClass ? 1 : 0, pb = tet_class(b) >= kFirstBoneClass ? 1 : 0;
    return pa > pb || (pa == pb && a < b);
  }

  // Pass 1 over slab s: rasterize its moving tets; where two cover a voxel, resolve the fold. Each row (j, k)
  // remembers the first and last voxel any tet covered and which voxels, for the skin shell.
  void rasterize_slab(int64_t s) {
    int64_t kb = 0, ke = 0;
    if (!slab_range(s, kb, ke)) return;
    const int64_t slab_begin = kb * n_[0] * n_[1], slab_voxels = (ke - kb) * n_[0] * n_[1];
    std::fill(owner_ + slab_begin, owner_ + slab_begin + slab_voxels, -1);
    std::fill(row_first_.begin() + kb * n_[1], row_first_.begin() + ke * n_[1], static_cast<int32_t>(n_[0]));
    std::fill(row_last_.begin() + kb * n_[1], row_last_.begin() + ke * n_[1], -1);
    std::fill(covered_bits_.begin() + kb * n_[1] * row_words_, covered_bits_.begin() + ke * n_[1] * row_words_, 0);
    std::vector<int64_t>& conflicts = conflicts_[static_cast<size_t>(s)];
    for (const int32_t t : scratch_->interior[static_cast<size_t>(s)]) {
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
  void rasterize_small(const RasterTet& r, const Index3& lo, const Index3& hi, const Claim& claim) {
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
  void rasterize_large(int32_t t, const RasterTet& r, const Index3& lo, const Index3& hi, const Claim& claim) {
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
  void find_shell(int64_t s) {
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
            for (int64_t w = row_first_[row] >> 6; w <= row_last_[row] >> 6; ++w)
              near[static_cast<size_t>(w)] |= bits[w];
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
  static void widen_by_one(std::vector<uint64_t>& bits, std::vector<uint64_t>& scratch) {
    const size_t words = bits.size();
    for (size_t w = 0; w < words; ++w) {
      const uint64_t below = w > 0 ? bits[w - 1] >> 63 : 0, above = w + 1 < words ? bits[w + 1] << 63 : 0;
      scratch[w] = bits[w] | (bits[w] << 1) | (bits[w] >> 1) | below | above;
    }
    bits.swap(scratch);
  }

  // The source voxel at source index s, or -1 outside the source grid.
  int64_t source_voxel(const double s[3]) const {
    const int64_t x = round_index(s[0]), y = round_index(s[1]), z = round_index(s[2]);
    const Index3& m = in_.source.size;
    if (x < 0 || y < 0 || z < 0 || x >= m[0] || y >= m[1] || z >= m[2]) return -1;
    return in_.source.offset(x, y, z);
  }

  // The tet (rest owner code) that holds source index s in the rest pose; -1 when none or outside the grid.
  int32_t rest_owner_at(const double s[3]) const {
    const int64_t v = source_voxel(s);
    return v < 0 ? -1 : (*in_.rest_owner)[static_cast<size_t>(v)];
  }

  // The bone segment of the source voxel `map` takes output voxel (i, j, k) to; -1 for none or outside the grid.
  int bone_at(const double* map, double i, double j, double k) const {
    double src[3];
    apply_map(map, i, j, k, src);
    const int64_t v = source_voxel(src);
    return v < 0 ? -1 : in_.bones->voxels->segment_of(v);
  }

  // Drops a tet's (or its shell's) sample of tissue from a body part separated from the tet's own.
  void guard_contact(int32_t& o, int64_t i, int64_t j, int64_t k, WarpStats& stats) const {
    const bool tet_owned = o >= 0, shell_owned = o <= -2 && o != kNoSample && !is_bone_owner(o);
    if (!tet_owned && !shell_owned) return;
    const int32_t c = tet_owned ? o : -2 - o;
    const int rt = (*in_.bones->tet_region)[static_cast<size_t>(warp_.tets_[static_cast<size_t>(c)])];
    double src[3];
    apply_map(warp_.maps_.get() + 12 * c, double(i), double(j), double(k), src);
    const int64_t v = source_voxel(src);
    if (rt < 0 || v < 0) return;
    const int rs = (*in_.bones->region)[static_cast<size_t>(v)];
    if (rs < 0 || rs == rt ||
        !(*in_.bones->separated)[static_cast<size_t>(rt) * segment_count_ + static_cast<size_t>(rs)])
      return;
    o = kNoSample;
    ++stats.contact_guarded_voxels;
  }

  // Claims voxel (i, j, k) for a bone, given its owner after classification: a moving bone on the row (segment, i0,
  // i1) whose rigid inverse lands on its own source voxel, or a bone that follows the background where a tet or the
  // shell would sample it. Two claims are an overlap; the lower segment keeps the voxel.
  void claim_bone(int32_t& o, int64_t i, int64_t j, int64_t k, const std::vector<std::array<int64_t, 3>>& row_bones,
                  WarpStats& stats) const {
    int claimed = -1;
    auto overlap = [&](int other) {
      if (claimed < 0) {
        claimed = other;
      } else if (claimed != other) {
        ++stats.bone_overlap_voxels[{std::min(claimed, other), std::max(claimed, other)}];
        claimed = std::min(claimed, other);
      }
    };
    for (const auto& [segment, i0, i1] : row_bones) {
      if (i < i0 || i > i1) continue;
      const int k_seg = static_cast<int>(segment);
      if (bone_at(warp_.bone_maps_.data() + 12 * k_seg, double(i), double(j), double(k)) == k_seg) overlap(k_seg);
    }
    if (o >= 0 || (o <= -2 && o != kNoSample)) {
      const int still = bone_at(warp_.background_map_, double(i), double(j), double(k));
      if (still >= 0 && !bone_moves_[static_cast<size_t>(still)]) overlap(still);
    }
    if (claimed >= 0) {
      o = kBoneOwner + claimed;
      ++stats.bone_voxels;
    }
  }

  // The moving bones whose posed box meets row (j, k): (segment, first i, last i), the i narrowed to where the bone's
  // map takes the row into the bone's source box (a thin bone turned fills little of its posed box).
  void bones_on_row(int64_t j, int64_t k, std::vector<std::array<int64_t, 3>>& row_bones) const {
    row_bones.clear();
    for (int seg = 0; seg < segment_count_; ++seg) {
      const std::array<double, 6>& box = bone_box_[static_cast<size_t>(seg)];
      if (!bone_moves_[static_cast<size_t>(seg)] || double(j) < box[1] || double(j) > box[4] || double(k) < box[2] ||
          double(k) > box[5]) {
        continue;
      }
      double lo = std::max(0.0, fast_ceil(box[0])), hi = std::min(double(n_[0] - 1), fast_floor(box[3]));
      if (!row_in_source_box(warp_.bone_maps_.data() + 12 * seg, j, k, in_.bones->voxels->box[static_cast<size_t>(seg)],
                             lo, hi)) {
        continue;
      }
      row_bones.push_back({seg, static_cast<int64_t>(lo), static_cast<int64_t>(hi)});
    }
  }

  // Narrows [lo, hi] (whole i) to the voxels of output row (j, k) that `map` may take into the source index box
  // (i0, j0, k0, i1, j1, k1): those whose source index rounds into it, give or take a voxel, so that no voxel
  // bone_at() would find in the box is dropped. False when none is left.
  static bool row_in_source_box(const double* map, int64_t j, int64_t k, const std::array<int64_t, 6>& box, double& lo,
                                double& hi) {
    double start[3];
    apply_map(map, 0.0, double(j), double(k), start);
    for (int a = 0; a < 3; ++a) {
      const double step = map[3 * a];
      const double low = double(box[static_cast<size_t>(a)]) - 1.5,
                   high = double(box[static_cast<size_t>(a + 3)]) + 1.5;
      if (std::abs(step) < 1e-9) {
        if (!(start[a] >= low && start[a] <= high)) return false;  // the whole row is off the box along a
        continue;
      }
      const double at_low = (low - start[a]) / step, at_high = (high - start[a]) / step;
      lo = std::max(lo, fast_floor(std::max(std::min(at_low, at_high), -1e9)) - 1.0);
      hi = std::min(hi, fast_ceil(std::min(std::max(at_low, at_high), 1e9)) + 1.0);
    }
    return lo <= hi;
  }

  // Pass 3 over slab s, classify every voxel. Without a rest owner: covered, shell or background. With one, a voxel
  // the moving tets left alone maps through the background transform to a source voxel whose rest owner says what it
  // is: a tet that follows the background (covered, or its shell), nothing (background), or a moving tet (the body
  // moved away from there: the shell of a moving tet, or nothing to sample). Then the bones claim their voxels, ahead
  // of any tet.
  void classify_slab(int64_t s) {
    int64_t kb = 0, ke = 0;
    if (!slab_range(s, kb, ke)) return;
    const int64_t slab_begin = kb * n_[0] * n_[1];
    // The voxels pass 1 found folded, in order (a voxel is listed once per pair of tets that disagree on it).
    std::vector<int64_t>& conflicts = conflicts_[static_cast<size_t>(s)];
    std::sort(conflicts.begin(), conflicts.end());
    conflicts.erase(std::unique(conflicts.begin(), conflicts.end()), conflicts.end());
    size_t next_conflict = 0;
    WarpStats& stats = slab_stats_[static_cast<size_t>(s)];
    const bool guard_contacts = in_.bones && in_.bones->region && in_.bones->tet_region && in_.bones->separated;
    std::vector<std::array<int64_t, 3>> row_bones;
    const std::vector<std::pair<int64_t, int32_t>>& found = shells_[static_cast<size_t>(s)];
    size_t next_shell = 0;
    const double* bg = warp_.background_map_;
    for (int64_t k = kb; k < ke; ++k) {
      for (int64_t j = 0; j < n_[1]; ++j) {
        bones_on_row(j, k, row_bones);
        const int64_t row_begin = in_.output.offset(0, j, k);
        const int64_t local_begin = row_begin - slab_begin;
        // Where the background map runs along one source row (the root does not move and the grid is the input's),
        // a row's rest owners are one row of rest_owner.
        double row[3];
        const int32_t* rest_row = nullptr;  // rest_owner at source x = i + x0 for this output row
        int64_t x0 = 0, y = 0, z = 0;
        const bool fast = along_source_row(bg, double(j), double(k), row, x0, y, z) && in_.rest_owner;
        if (fast && y >= 0 && z >= 0 && y < in_.source.size[1] && z < in_.source.size[2]) {
          rest_row = in_.rest_owner->data() + in_.source.offset(0, y, z);
        }
        // The moving bones' reach on this row: outside it, and off the shell, a voxel no moving tet covers is
        // classified by its rest owner alone (no fold, no contact to guard, no bone to claim).
        int64_t bones_lo = n_[0], bones_hi = -1;
        for (const auto& [segment, i0, i1] : row_bones)
          bones_lo = std::min(bones_lo, i0), bones_hi = std::max(bones_hi, i1);
        for (int64_t i = 0; i < n_[0]; ++i) {
          const int64_t local = local_begin + i;
          int32_t& o = owner_[row_begin + i];
          if (o == -1 && in_.rest_owner && (i < bones_lo || i > bones_hi) &&
              (next_shell >= found.size() || found[next_shell].first != local)) {
            // This voxel and those after it up to the next that needs more than its rest owner (a moving tet covers
            // it, a moving bone reaches it, or it is in the shell), in one loop.
            const int64_t shell_at = next_shell < found.size() ? found[next_shell].first - local_begin : n_[0];
            const int64_t stop = std::min({n_[0], shell_at, i < bones_lo ? bones_lo : n_[0]});
            i = (fast ? classify_uncovered_run(owner_ + row_begin, i, stop, x0, rest_row, stats)
                      : classify_uncovered_mapped(owner_ + row_begin, i, stop, row, stats)) -
                1;
            continue;
          }
          int32_t shell_owner = -1;
          if (next_shell < found.size() && found[next_shell].first == local) shell_owner = found[next_shell++].second;
          // Folded voxels are covered by a moving tet, never on the fast path: every one is reached here.
          uint8_t conflicted = 0;
          if (next_conflict < conflicts.size() && conflicts[next_conflict] == local) {
            conflicted = 1;
            ++next_conflict;
          }
          if (!in_.rest_owner) {
            classify_alone(o, shell_owner, stats);
          } else {
            int32_t ro = -1;
            if (fast) {
              const int64_t x = x0 + i;
              if (rest_row && x >= 0 && x < in_.source.size[0]) ro = rest_row[x];
            } else {
              const double di = double(i);
              const double sb[3] = {row[0] + di * bg[0], row[1] + di * bg[3], row[2] + di * bg[6]};
              ro = rest_owner_at(sb);
            }
            classify_by_rest_owner(o, ro, shell_owner, i, j, k, conflicted, stats);
          }
          stats.conflicted_voxels += conflicted;
          if (guard_contacts) guard_contact(o, i, j, k, stats);
          if (segment_count_ > 0) claim_bone(o, i, j, k, row_bones, stats);
        }
      }
    }
    std::vector<int64_t>().swap(conflicts);
    progress_->advance(1, 2 * slab_count_);
  }

  // classify_uncovered for voxels i.. of an output row (`row`: their owners) up to `stop` or the first that a moving
  // tet covers, whose rest owners are rest_row[x0 + i] (none where rest_row is null or x is off the source grid).
  // Returns where it stopped.
  int64_t classify_uncovered_run(int32_t* row, int64_t i, int64_t stop, int64_t x0, const int32_t* rest_row,
                                 WarpStats& stats) const {
    const int64_t width = in_.source.size[0];
    for (; i < stop && row[i] == -1; ++i) {
      const int64_t x = x0 + i;
      classify_uncovered(row[i], rest_row && x >= 0 && x < width ? rest_row[x] : -1, stats);
    }
    return i;
  }

  // The same where the background map does not run along a source row (the root moved): each voxel's rest owner is
  // looked up where the map takes it, `start` being the map at i = 0.
  int64_t classify_uncovered_mapped(int32_t* row, int64_t i, int64_t stop, const double start[3],
                                    WarpStats& stats) const {
    const double* bg = warp_.background_map_;
    const double step[3] = {bg[0], bg[3], bg[6]};
    const int32_t* rest_owner = in_.rest_owner->data();
    // A turned map crosses a source row every few voxels, and each crossing may miss the cache: the voxels are taken
    // a batch at a time, their rest owners fetched in a loop of independent loads, so that the misses overlap.
    constexpr int64_t kBatch = 32;
    int32_t ro[kBatch];
    while (i < stop) {
      const int64_t n = std::min(kBatch, stop - i);
      int64_t c = 0;
#if defined(__x86_64__)
      if (wide_source_lookup_) c = rest_owners_avx2(rest_owner, in_.source.size, start, step, i, n, ro);
#endif
      for (; c < n; ++c) {
        const double di = double(i + c);
        const double sb[3] = {start[0] + di * step[0], start[1] + di * step[1], start[2] + di * step[2]};
        const int64_t at = source_voxel(sb);
        ro[c] = at < 0 ? -1 : rest_owner[at];
      }
      for (c = 0; c < n; ++c, ++i) {
        if (row[i] != -1) return i;
        classify_uncovered(row[i], ro[c], stats);
      }
    }
    return i;
  }

  // classify_by_rest_owner for a voxel that no moving tet covers and no shell reaches.
  void classify_uncovered(int32_t& o, int32_t ro, WarpStats& stats) const {
    int32_t rt = ro >= 0 ? ro : (ro <= -2 && ro != kNoSample) ? -2 - ro : -1;
    if (rt >= in_.rest.tet_count()) ro = rt = -1;
    if (rt >= 0 && !moving_[static_cast<size_t>(rt)]) {
      ++(ro >= 0 ? stats.covered_voxels : stats.extrapolated_voxels);  // o stays -1
    } else {
      o = rt < 0 ? -1 : kNoSample;
      ++stats.background_voxels;
    }
  }

  // A voxel whose background map lands on a source voxel with rest owner code `ro`.
  void classify_by_rest_owner(int32_t& o, int32_t ro, int32_t shell_owner, int64_t i, int64_t j, int64_t k,
                              uint8_t& conflicted, WarpStats& stats) const {
    if (ro == kNoSample) ro = -1;
    int32_t rt = ro >= 0 ? ro : ro <= -2 ? -2 - ro : -1;  // the rest tet behind that code
    if (rt >= in_.rest.tet_count()) ro = rt = -1;         // not a tet of this mesh: as if nothing held the voxel
    const bool still = rt >= 0 && !moving_[static_cast<size_t>(rt)];
    if (o >= 0) {
      // A moving tet covers it; a tet that follows the background may cover it too (a fold).
      if (ro >= 0 && still &&
          wins(warp_.background_map_, ro, warp_.maps_.get() + 12 * o, warp_.tets_[static_cast<size_t>(o)], double(i),
               double(j), double(k), conflicted)) {
        o = -1;
      }
      ++stats.covered_voxels;
    } else if (still) {
      o = -1;
      ++(ro >= 0 ? stats.covered_voxels : stats.extrapolated_voxels);
    } else if (shell_owner >= 0) {
      o = -2 - shell_owner;
      ++stats.extrapolated_voxels;
    } else {
      o = rt < 0 ? -1 : kNoSample;
      ++stats.background_voxels;
    }
  }

  const WarpInputs& in_;
  const ProgressHooks& hooks_;
  const Index3& n_;                        // the output grid's size
  std::optional<StageProgress> progress_;  // from the checks on
#if defined(__x86_64__)
  // Rest owners along a turned background looked up four at a time (AVX2, a source grid under 2^31 voxels).
  const bool wide_source_lookup_ = avx2_gathers(in_.source.size);
#endif
  TetWarp warp_;
  IndexSpace out_space_, src_space_;
  double shell_[3] = {};
  int64_t reach_[3] = {};
  // Bones (RigidBones): how many, which move off the background, each moving bone's posed box (lo, hi per axis).
  int segment_count_ = 0;
  std::vector<uint8_t> bone_moves_;
  std::vector<std::array<double, 6>> bone_box_;
  // Vertices in output (posed) and source (rest) index space, 3 per vertex; which tets move off the background.
  std::vector<double> posed_index_, rest_index_;
  std::vector<uint8_t> moving_;
  // Per rasterized tet: raster data (in the scratch buffers) and the output k it spans.
  RasterScratch* scratch_ = nullptr;
  RasterTet* raster_ = nullptr;
  std::vector<std::array<int32_t, 2>> k_range_;
  // The slabs, and what the passes leave per slab: folded voxels, shell voxels found, statistics.
  int64_t slab_count_ = 0, slab_depth_ = 0;
  int32_t* owner_ = nullptr;
  std::vector<int32_t> row_first_, row_last_;
  int64_t row_words_ = 0;                        // 64-bit words per output row in covered_bits_
  std::vector<uint64_t> covered_bits_;           // per output row, a bit per voxel a moving tet covers (pass 1)
  std::vector<std::vector<int64_t>> conflicts_;  // per slab: its folded voxels (slab-local indices)
  std::vector<ShellOffset> offsets_;
  std::vector<std::vector<std::pair<int64_t, int32_t>>> shells_;  // (slab voxel, owner)
  std::vector<WarpStats> slab_stats_;
};

Result<TetWarp> TetWarp::build(const WarpInputs& inputs, const ProgressHooks& hooks) {
  return Builder(inputs, hooks).run();
}

}  // namespace posewarp::resample
