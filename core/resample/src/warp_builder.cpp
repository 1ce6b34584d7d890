// TetWarp::build: the maps, the tets to rasterize and their raster data, then three passes over output slabs
// (rasterize the moving tets and resolve folds, find the skin shell, classify every voxel and let the bones claim
// theirs), each thread owning whole slabs as ITK threads over output regions. The passes are in warp_raster.cpp and
// warp_classify.cpp.
#include "warp_builder.h"

#include <algorithm>
#include <bit>
#include <cmath>
#include <limits>
#include <string>

#include "posewarp/common/exception_wall.h"
#include "posewarp/common/voxel_memory.h"

namespace posewarp::resample {

using namespace internal;

Result<TetWarp> TetWarp::Builder::run() {
  POSEWARP_RETURN_IF_ERROR(check(in_));
  progress_.emplace(hooks_, "warp-prepare");
  POSEWARP_RETURN_IF_ERROR(size_shell());
  warp_.source_ = in_.source;
  warp_.output_ = in_.output;
  warp_.label_background_ = in_.params.label_background;
  warp_.intensity_background_ = in_.params.intensity_background;
  const Status prepared = guarded("preparing the warp onto " + in_.output.describe(), [&]() -> Status {
    PhaseClock phases(hooks_, "warp-prepare");
    out_space_ = index_space(in_.output);
    src_space_ = index_space(in_.source);
    prepare_maps();
    phases.mark("maps");
    select_tets();
    phases.mark("select");
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
    phases.mark("prepare");
    POSEWARP_RETURN_IF_ERROR(progress_->check_cancel());
    progress_->update(0.2);
    split_into_slabs();
    phases.mark("split");
    in_slabs([this](int64_t s) { rasterize_slab(s); });  // pass 1
    phases.mark("raster");
    POSEWARP_RETURN_IF_ERROR(progress_->check_cancel());
    offsets_ = shell_offsets(in_.output, shell_, reach_);
    in_slabs([this](int64_t s) { find_shell(s); });  // pass 2
    phases.mark("shell");
    in_slabs([this](int64_t s) { classify_slab(s); });  // pass 3
    phases.mark("classify");
    POSEWARP_RETURN_IF_ERROR(progress_->check_cancel());
    // The owners kept on their rows' spans, the grid's block given back (the voxel memory hands it to the labels).
    warp_.owner_ = std::make_shared<const RowPacked<int32_t>>(
        RowPacked<int32_t>::pack(owner_, n_, -1, false, owner_spans_.empty() ? nullptr : owner_spans_.data()));
    owner_ = nullptr;
    dense_owner_.reset();
    phases.mark("pack");
    for (const WarpStats& slab : slab_stats_) warp_.stats_ += slab;
    return ok_status();
  });
  if (!prepared.ok()) return prepared;
  progress_->finish();
  return std::move(warp_);
}

// The shell is an ellipsoid around each uncovered voxel, semi-axes shell_[a] mm along the output axes: by default
// two source voxels along each axis (so a 5 mm slice thickness reaches one slice, not 12 in-plane voxels).
Status TetWarp::Builder::size_shell() {
  for (int a = 0; a < 3; ++a) {
    const double source_spacing = in_.source.spacing[static_cast<size_t>(a)];
    shell_[a] = in_.params.shell_mm > 0.0 ? in_.params.shell_mm : 2.0 * source_spacing;
    reach_[a] = static_cast<int64_t>(std::min(shell_[a] / in_.output.spacing[static_cast<size_t>(a)], 1e6));
    if (reach_[a] > kMaxShellVoxels && in_.params.shell_mm > 0.0) {
      return invalid_argument_error("a skin shell of " + std::to_string(in_.params.shell_mm) + " mm spans more than " +
                                    std::to_string(kMaxShellVoxels) +
                                    " voxels of the output grid; use a thinner shell");
    }
    reach_[a] = std::min(reach_[a], kMaxShellVoxels);  // the default on a much finer output grid
  }
  return ok_status();
}

// Output index -> output physical -> rest physical (inverse rigid) -> source index.
inline void TetWarp::Builder::rigid_map(const Eigen::Matrix3d& rotation, const Eigen::Vector3d& translation,
                                        double* m) const {
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
void TetWarp::Builder::prepare_maps() {
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
void TetWarp::Builder::select_tets() {
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
  // Which tets move (counted per block of tets), then the moving ones in tet order with their lowest posed k, each
  // block writing its own from where the blocks before it end.
  const int64_t nz = n_[2];
  constexpr int64_t kBlock = 8192;
  const int64_t blocks = (nt + kBlock - 1) / kBlock;
  moving_.resize(static_cast<size_t>(nt));
  std::vector<int64_t> block_at(static_cast<size_t>(blocks) + 1, 0);
  parallel_for(0, blocks, 1, [&](int64_t b0, int64_t b1) {
    for (int64_t b = b0; b < b1; ++b) {
      int64_t n = 0;
      for (int64_t t = b * kBlock; t < std::min(nt, (b + 1) * kBlock); ++t) {
        bool all_follow = in_.rest_owner != nullptr;
        for (int c = 0; c < 4 && all_follow; ++c) all_follow = follows[static_cast<size_t>(rest.tets(t, c))];
        moving_[static_cast<size_t>(t)] = all_follow ? 0 : 1;
        n += all_follow ? 0 : 1;
      }
      block_at[static_cast<size_t>(b) + 1] = n;
    }
  });
  for (int64_t b = 0; b < blocks; ++b) block_at[static_cast<size_t>(b) + 1] += block_at[static_cast<size_t>(b)];
  const int64_t nm = block_at[static_cast<size_t>(blocks)];
  std::vector<int32_t> list(static_cast<size_t>(nm)), list_k(static_cast<size_t>(nm));
  parallel_for(0, blocks, 1, [&](int64_t b0, int64_t b1) {
    for (int64_t b = b0; b < b1; ++b) {
      int64_t n = block_at[static_cast<size_t>(b)];
      for (int64_t t = b * kBlock; t < std::min(nt, (b + 1) * kBlock); ++t) {
        if (!moving_[static_cast<size_t>(t)]) continue;
        double z = std::numeric_limits<double>::infinity();
        for (int q = 0; q < 4; ++q) z = std::min(z, posed_index_[static_cast<size_t>(rest.tets(t, q)) * 3 + 2]);
        list[static_cast<size_t>(n)] = static_cast<int32_t>(t);
        list_k[static_cast<size_t>(n++)] = static_cast<int32_t>(
            std::clamp<double>(fast_floor(std::clamp(z, -1.0, 1e9)), 0.0, static_cast<double>(nz - 1)));
      }
    }
  });
  // In order of their lowest k (rasterized index -> tet).
  std::vector<int64_t> first;
  sort_by_keys(
      nm, nz, [&](int64_t c, const auto& emit) { emit(list_k[static_cast<size_t>(c)]); }, warp_.tets_, first);
  parallel_for(0, nm, 16384, [&](int64_t begin, int64_t end) {
    for (int64_t c = begin; c < end; ++c)
      warp_.tets_[static_cast<size_t>(c)] = list[static_cast<size_t>(warp_.tets_[static_cast<size_t>(c)])];
  });
  warp_.rasterized_tets_ = static_cast<int64_t>(warp_.tets_.size());
}

// Step 3: per rasterized tet, densely (a pose that moves a few tets touches only theirs), the output-index ->
// source-index map, the raster data and the output k it spans; a tet with no volume once posed is skipped, and one
// whose index box holds no voxel centre gets none of them.
void TetWarp::Builder::prepare_raster() {
  const int64_t nm = warp_.rasterized_tets_;
  // The maps' block comes from the voxel memory, its size rounded up to an eighth of the next power of two: a pose
  // like the last one takes the pages its maps had (a first touch of fresh pages costs as much as the maps' making).
  const size_t map_bytes = static_cast<size_t>(std::max<int64_t>(nm, 1)) * 12 * sizeof(double);
  const size_t step = std::max<size_t>(std::bit_ceil(map_bytes) / 8, 1);
  const size_t kept_bytes = (map_bytes + step - 1) / step * step;
  warp_.maps_ = std::shared_ptr<double[]>(static_cast<double*>(allocate_voxels(kept_bytes)),
                                          [kept_bytes](double* p) { free_voxels(p, kept_bytes); });
  if (scratch_->raster.size() < static_cast<size_t>(nm)) scratch_->raster.resize(static_cast<size_t>(nm));
  raster_ = scratch_->raster.data();
  std::vector<uint8_t> usable(static_cast<size_t>(nm), 0);
  k_range_.assign(static_cast<size_t>(nm), {1, 0});
  // Rasterized tets are in the order of their lowest k, so their corners and vertices are scattered through the
  // mesh: each tet's corners are asked for 2 kAhead tets before it, their vertices kAhead before it (a tet waited on
  // both in turn, and the loads of several tets did not overlap).
  constexpr int64_t kAhead = 8;
  const TetMesh& rest = in_.rest;
  parallel_for(0, nm, 2048, [&](int64_t begin, int64_t end) {
    for (int64_t c = begin; c < end; ++c) {
      if (c + 2 * kAhead < end) {
        const int64_t t = warp_.tets_[static_cast<size_t>(c + 2 * kAhead)];
        for (int q = 0; q < 4; ++q) __builtin_prefetch(&rest.tets(t, q));
      }
      if (c + kAhead < end) {
        const int64_t t = warp_.tets_[static_cast<size_t>(c + kAhead)];
        for (int q = 0; q < 4; ++q) {
          const size_t v = static_cast<size_t>(rest.tets(t, q)) * 3;
          __builtin_prefetch(posed_index_.data() + v);
          __builtin_prefetch(rest_index_.data() + v);
        }
      }
      usable[static_cast<size_t>(c)] = prepare_tet(c);
    }
  });
  for (const uint8_t ok : usable) warp_.stats_.degenerate_tets += ok ? 0 : 1;
}

// Rasterized tet c's raster data and map; false for a tet with no volume once posed.
inline bool TetWarp::Builder::prepare_tet(int64_t c) {
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
  // The index box, clamped in double to just outside the grid so that no later cast can overflow (a root
  // translated by 1e9 mm is finite, and valid). A box with no voxel centre of the grid inside (a tet smaller than a
  // voxel, between centres; the mesh is finer than the image) covers nothing: the tet goes to no slab, and its raster
  // data and map, which nothing would read, are not made.
  double lo[3], hi[3];
  for (int a = 0; a < 3; ++a) {
    const double top = static_cast<double>(n_[static_cast<size_t>(a)]);
    lo[a] = std::clamp(std::min({u[0](a), u[1](a), u[2](a), u[3](a)}), -2.0, top + 1.0);
    hi[a] = std::clamp(std::max({u[0](a), u[1](a), u[2](a), u[3](a)}), -2.0, top + 1.0);
    if (std::max<int64_t>(0, static_cast<int64_t>(fast_ceil(lo[a]))) >
        std::min<int64_t>(n_[static_cast<size_t>(a)] - 1, static_cast<int64_t>(fast_floor(hi[a])))) {
      return true;
    }
  }
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
  for (int a = 0; a < 3; ++a) r.lo[a] = lo[a], r.hi[a] = hi[a];
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
void TetWarp::Builder::split_into_slabs() {
  slab_count_ = std::clamp<int64_t>(n_[2], 1, 16 * static_cast<int64_t>(thread_count()));
  slab_depth_ = (n_[2] + slab_count_ - 1) / slab_count_;
  std::vector<int32_t> slab_of(static_cast<size_t>(n_[2]));  // each output k's slab, without a division per tet
  for (int64_t k = 0; k < n_[2]; ++k) slab_of[static_cast<size_t>(k)] = static_cast<int32_t>(k / slab_depth_);
  sort_by_keys(
      warp_.rasterized_tets_, slab_count_,
      [&](int64_t c, const auto& emit) {
        const auto [k0, k1] = k_range_[static_cast<size_t>(c)];
        if (k0 > k1) return;
        for (int32_t s = slab_of[static_cast<size_t>(k0)]; s <= slab_of[static_cast<size_t>(k1)]; ++s) emit(s);
      },
      scratch_->interior, scratch_->interior_first);
  const size_t owner_bytes = static_cast<size_t>(in_.output.voxel_count()) * sizeof(int32_t);
  dense_owner_ = std::shared_ptr<int32_t[]>(static_cast<int32_t*>(allocate_voxels(owner_bytes)),
                                            [owner_bytes](int32_t* p) { free_voxels(p, owner_bytes); });
  owner_ = dense_owner_.get();
  const int64_t row_count = n_[1] * n_[2];
  row_first_.resize(static_cast<size_t>(row_count));
  row_last_.resize(static_cast<size_t>(row_count));
  row_words_ = (n_[0] + 63) / 64;
  if (n_[0] <= RowPacked<int32_t>::kMaxRow) owner_spans_.assign(static_cast<size_t>(row_count), 0);
  covered_bits_.resize(static_cast<size_t>(row_count * row_words_));
  conflicts_.resize(static_cast<size_t>(slab_count_));
  shells_.resize(static_cast<size_t>(slab_count_));
  slab_stats_.resize(static_cast<size_t>(slab_count_));
}

Result<TetWarp> TetWarp::build(const WarpInputs& inputs, const ProgressHooks& hooks) {
  return Builder(inputs, hooks).run();
}

}  // namespace posewarp::resample
