// TetWarp::Builder, private to the warp: build()'s steps as members, defined by what they do in warp_builder.cpp
// (the maps, the tets to rasterize, their raster data, the slabs), warp_raster.cpp (passes 1 and 2: the raster and
// the skin shell) and warp_classify.cpp (pass 3: every voxel classified, the bones' claims).
#pragma once

#include <Eigen/Dense>

#include <array>
#include <cstdint>
#include <optional>
#include <utility>
#include <vector>

#include "avx2.h"
#include "posewarp/common/parallel.h"
#include "posewarp/resample/tet_warp.h"
#include "raster.h"

namespace posewarp::resample {

// build()'s steps, split the way ITK splits a filter: the maps (background and bones), the tets to rasterize and
// their raster data, then three passes over output slabs in parallel (each thread owns whole slabs): rasterize the
// moving tets and resolve folds, find the skin shell, classify every voxel and let the bones claim theirs. Each step
// reads what the ones before it left in the members.
class TetWarp::Builder {
 public:
  Builder(const WarpInputs& in, const ProgressHooks& hooks) : in_(in), hooks_(hooks), n_(in.output.size) {}

  Result<TetWarp> run();

 private:
  // The maps, the tets to rasterize and their raster data, the slabs (warp_builder.cpp).
  Status size_shell();
  void rigid_map(const Eigen::Matrix3d& rotation, const Eigen::Vector3d& translation, double* m) const;
  void prepare_maps();
  void select_tets();
  void prepare_raster();
  bool prepare_tet(int64_t c);
  void split_into_slabs();

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
    internal::apply_map(map_a, i, j, k, sa);
    internal::apply_map(map_b, i, j, k, sb);
    if (std::abs(sa[0] - sb[0]) + std::abs(sa[1] - sb[1]) + std::abs(sa[2] - sb[2]) > 0.5) conflicted = 1;
    const Eigen::VectorXi& tet_class = in_.rest.tet_class;
    const int pa = tet_class(a) >= kFirstBoneClass ? 1 : 0, pb = tet_class(b) >= kFirstBoneClass ? 1 : 0;
    return pa > pb || (pa == pb && a < b);
  }

  // Passes 1 and 2, the raster and the skin shell (warp_raster.cpp).
  void rasterize_slab(int64_t s);
  template <typename Claim>
  void rasterize_small(const internal::RasterTet& r, const Index3& lo, const Index3& hi, const Claim& claim);
  template <typename Claim>
  void rasterize_large(int32_t t, const internal::RasterTet& r, const Index3& lo, const Index3& hi, const Claim& claim);
  void find_shell(int64_t s);
  static void widen_by_one(std::vector<uint64_t>& bits, std::vector<uint64_t>& scratch);

  // Pass 3, every voxel classified and the bones' claims (warp_classify.cpp).
  bool source_index(const double s[3], int64_t& x, int64_t& y, int64_t& z) const;
  int64_t source_voxel(const double s[3]) const;
  int32_t rest_owner_at(const double s[3]) const;
  int bone_at(const double* map, double i, double j, double k) const;
  void guard_contact(int32_t& o, int64_t i, int64_t j, int64_t k, WarpStats& stats) const;
  void claim_bone(int32_t& o, int64_t i, int64_t j, int64_t k, const std::vector<std::array<int64_t, 3>>& row_bones,
                  WarpStats& stats) const;
  void bones_on_row(int64_t j, int64_t k, std::vector<std::array<int64_t, 3>>& row_bones) const;
  static bool row_in_source_box(const double* map, int64_t j, int64_t k, const std::array<int64_t, 6>& box, double& lo,
                                double& hi);
  void classify_slab(int64_t s);
  int64_t classify_uncovered_run(int32_t* row, int64_t i, int64_t stop, int64_t x0, const int32_t* span, int64_t lo,
                                 int64_t hi, WarpStats& stats) const;
  int64_t classify_uncovered_mapped(int32_t* row, int64_t i, int64_t stop, const double start[3],
                                    WarpStats& stats) const;
  void classify_uncovered(int32_t& o, int32_t ro, WarpStats& stats) const;
  void classify_by_rest_owner(int32_t& o, int32_t ro, int32_t shell_owner, int64_t i, int64_t j, int64_t k,
                              uint8_t& conflicted, WarpStats& stats) const;

  const WarpInputs& in_;
  const ProgressHooks& hooks_;
  const Index3& n_;                        // the output grid's size
  std::optional<StageProgress> progress_;  // from the checks on
#if defined(__x86_64__)
  // Rest owners along a turned background looked up four at a time (AVX2, a source grid under 2^31 voxels).
  const bool wide_source_lookup_ = internal::avx2_gathers(in_.source.size);
#endif
  TetWarp warp_;
  internal::IndexSpace out_space_, src_space_;
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
  internal::RasterScratch* scratch_ = nullptr;
  internal::RasterTet* raster_ = nullptr;
  std::vector<std::array<int32_t, 2>> k_range_;
  // The slabs, and what the passes leave per slab: folded voxels, shell voxels found, statistics.
  int64_t slab_count_ = 0, slab_depth_ = 0;
  std::shared_ptr<int32_t[]> dense_owner_;  // the owner map as the passes write it, every voxel (then packed)
  std::vector<uint32_t> owner_spans_;       // per output row, lo | hi << 16 of its owners other than -1 (pass 3)
  int32_t* owner_ = nullptr;
  std::vector<int32_t> row_first_, row_last_;
  int64_t row_words_ = 0;                        // 64-bit words per output row in covered_bits_
  std::vector<uint64_t> covered_bits_;           // per output row, a bit per voxel a moving tet covers (pass 1)
  std::vector<std::vector<int64_t>> conflicts_;  // per slab: its folded voxels (slab-local indices)
  std::vector<internal::ShellOffset> offsets_;
  std::vector<std::vector<std::pair<int64_t, int32_t>>> shells_;  // (slab voxel, owner)
  std::vector<WarpStats> slab_stats_;
};

}  // namespace posewarp::resample
