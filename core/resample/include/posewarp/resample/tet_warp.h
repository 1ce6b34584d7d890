// The hole-free volume warp (Sujar et al. 2018 section 5, Fig. 11): every output voxel inside a posed tet is
// mapped back to rest position through that tet's affine map and sampled there; labels by nearest neighbour
// (never a new value), intensities trilinearly.
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <map>
#include <memory>
#include <utility>
#include <vector>

#include "posewarp/common/progress.h"
#include "posewarp/common/result.h"
#include "posewarp/common/row_packed.h"
#include "posewarp/common/tet_mesh.h"
#include "posewarp/common/volume.h"
#include "posewarp/resample/rigid_bones.h"
#include "posewarp/resample/row_spans.h"

namespace posewarp::resample {

enum class Interpolation { kNearest, kLinear };

enum class GridPolicy {
  kInput,  // the source grid
  kGrow,   // the source grid grown (same spacing and direction) to hold the posed body
  kGiven,  // a grid the caller gives
};

struct ResampleParams {
  // Voxels just outside the mesh surface (the mesh approximates the skin) take the map of the tet under the nearest
  // covered voxel whose centre lies within this distance of theirs, mm (at most 8 output voxels along an axis).
  // 0 = two source voxels along each axis (the mesher keeps the surface within facet_distance of the label
  // boundary, 1.5 mm by default, and covered voxel centres lie up to half a voxel inside the surface).
  double shell_mm = 0.0;
  Label label_background = 0;           // label where nothing maps back into the body
  float intensity_background = -1024.f; // intensity where nothing maps back (air in HU)
  int64_t max_output_voxels = int64_t{1} << 29;
  // Bytes a pose may allocate for its output (the warp's owner map, labels, CT, displacement fields), estimated
  // before anything is allocated; 0 = half the machine's physical memory.
  int64_t max_output_bytes = 0;
  double grow_margin_mm = 10.0;         // extra room around the posed body for kGrow
};

Status validate(const ResampleParams& params);

// The output grid for a policy. posed: #V x 3 posed vertices (LPS mm); given: the grid for kGiven.
// An output grid over max_output_voxels or 65536 voxels along an axis is RESOURCE_EXHAUSTED / INVALID_ARGUMENT.
Result<ImageGeometry> output_geometry(GridPolicy policy, const ImageGeometry& source, const Eigen::MatrixXd& posed,
                                      const ImageGeometry* given, const ResampleParams& params);

struct WarpStats {
  int64_t covered_voxels = 0;      // inside a posed tet
  int64_t conflicted_voxels = 0;   // inside posed tets that map back to different places (folds); bones win
  int64_t extrapolated_voxels = 0; // in the skin shell, mapped by the tet of the nearest covered voxel
  int64_t background_voxels = 0;   // outside mesh and shell: moved with the background (root) transform
  int64_t degenerate_tets = 0;     // rasterized tets with no volume once posed, skipped
  int64_t bone_voxels = 0;         // mapped by a bone's own rigid transform (RigidBones), ahead of any tet
  int64_t contact_guarded_voxels = 0;  // would have shown tissue of a body part separated from their tet's
  // Output voxels two bones claim (each would put its own voxel there): bones passing through each other. Keyed by
  // the segment pair (lower index first); the lower index keeps the voxel.
  std::map<std::pair<int, int>, int64_t> bone_overlap_voxels;

  // Adds another part's counts (the warp's slabs, each counted on its own thread).
  WarpStats& operator+=(const WarpStats& other) {
    covered_voxels += other.covered_voxels;
    conflicted_voxels += other.conflicted_voxels;
    extrapolated_voxels += other.extrapolated_voxels;
    background_voxels += other.background_voxels;
    degenerate_tets += other.degenerate_tets;
    bone_voxels += other.bone_voxels;
    contact_guarded_voxels += other.contact_guarded_voxels;
    for (const auto& [pair, count] : other.bone_overlap_voxels) bone_overlap_voxels[pair] += count;
    return *this;
  }
};

// What a warp is built from.
struct WarpInputs {
  const TetMesh& rest;         // the rig's tet mesh
  const Eigen::MatrixXd& posed;  // its posed vertices, #V x 3 (LPS mm)
  const ImageGeometry& source;
  const ImageGeometry& output;
  // The rigid transform (rest -> posed) of everything outside the mesh, normally the root segment's.
  Eigen::Matrix3d background_rotation = Eigen::Matrix3d::Identity();
  Eigen::Vector3d background_translation = Eigen::Vector3d::Zero();
  // owner() of the identity warp on the source grid (built without one, which rasterizes every tet), packed around
  // -1 (RowPacked<int32_t>::pack(owner, size, -1)). With it, tets that follow the background are not rasterized, and
  // source voxels owned by moving tets are never copied by the background transform (so a moved limb leaves no
  // ghost); the lookups along a turned background skip the rows' air. Null: every tet is rasterized.
  const RowPacked<int32_t>* rest_owner = nullptr;
  ResampleParams params = {};
  // Bones rigid at voxel level (may be null). An output voxel that bone segment k's rigid inverse maps onto a source
  // voxel of segment k takes that map, whatever tet covers it; a voxel a moving tet or the skin shell maps onto a
  // bone that does not move takes the bone's (the background) map; and a tet map that lands inside a bone samples the
  // bone voxel's soft-tissue substitute (BoneVoxels::substitute), so no bone value appears where its bone did not put
  // it. `bones->voxels` must outlive the warp.
  const RigidBones* bones = nullptr;
};

// The map from an output grid back to the source grid for one posed mesh.
//
// Only tets that move differently from the background are rasterized: a tet whose four vertices follow the
// background (root) transform maps its voxels exactly as the background map does, so those voxels are found
// through the rest ownership of the source voxel they map to (a lookup instead of a raster). A pose that bends one
// knee rasterizes the lower leg only.
class TetWarp {
 public:
  // Owner code of an output voxel that nothing maps back to (the place a moved limb left): background value.
  static constexpr int32_t kNoSample = -2147483647 - 1;
  // Owner code of an output voxel mapped by bone segment k's rigid transform: kBoneOwner + k.
  static constexpr int32_t kBoneOwner = kNoSample + 1;
  static constexpr int32_t kMaxBoneSegments = 32767;
  static bool is_bone_owner(int32_t o) { return o >= kBoneOwner && o < kBoneOwner + kMaxBoneSegments; }

  // Builds the warp of `inputs` (WarpInputs says what each is). INVALID_ARGUMENT for posed vertices that do not fit
  // the mesh, a rest ownership of another grid, or a skin shell wider than 8 output voxels; RESOURCE_EXHAUSTED for an
  // output grid over max_output_voxels or out of memory.
  static Result<TetWarp> build(const WarpInputs& inputs, const ProgressHooks& hooks = {});

  const ImageGeometry& output() const { return output_; }
  // The label of output voxels that nothing maps back into the body.
  Label label_background() const { return label_background_; }
  const WarpStats& stats() const { return stats_; }
  // Tets rasterized (those that move differently from the background; all of them without a rest owner).
  int64_t rasterized_tets() const { return rasterized_tets_; }

  // Labels by nearest neighbour: every output value is a value of the source. With `bone_deviation_mm` (filled with
  // RigidBones, left empty without), found in the same walk: per bone segment, how far (mm) the output voxels that
  // end up holding a value of that bone sample from where the bone's own rigid inverse would (0 for every voxel a bone
  // owns), {max, 99th percentile}. With `spans` (row_spans of `source`'s voxels, computed once per source), the lookups
  // along a turned background skip the voxels off them; spans of other values than source's give wrong labels.
  Result<LabelVolume> warp_labels(const LabelVolume& source,
                                  std::vector<std::pair<double, double>>* bone_deviation_mm = nullptr,
                                  const RowSpans* spans = nullptr) const;
  // Intensities, trilinear or nearest; the result keeps the source's type on disk. From int16 samples (a CT as
  // CompactIntensities holds it) the result is that of the float volume of the same values, bit for bit.
  Result<IntensityVolume> warp_intensities(const IntensityVolume& source, Interpolation interpolation) const;
  Result<IntensityVolume> warp_intensities(const Volume<int16_t>& source, Interpolation interpolation) const;
  // Per output voxel: the covering rasterized tet (>= 0), -2 - tet for a skin-shell voxel, -1 for a voxel mapped by
  // the background transform (inside a tet that follows it, or outside the body), kBoneOwner + k for a voxel of bone
  // segment k (with RigidBones), kNoSample where nothing maps.
  std::vector<int32_t> owner() const;
  // x_source - x_output in mm for every output voxel (3 floats each, x fastest): the field ITK's
  // DisplacementFieldTransform takes to resample the source onto the output grid.
  std::vector<float> inverse_displacement() const;

 private:
  class Builder;    // build()'s steps (warp_builder.cpp)
  class BoneTally;  // warp_labels' count of where bone values land (tet_warp.cpp)
  TetWarp() = default;
  // Calls sample(v, n, s, ds, soft) for every run of n output voxels from v along a row that map to source index s,
  // s + ds, ..., output slices in parallel.
  // `soft` tells whether the run is mapped by a tet or the skin shell (its bone samples take substitutes).
  template <typename Sample>
  void for_each_mapped_run(const Sample& sample) const;
  template <typename T>
  Result<IntensityVolume> warp_intensities_from(const Volume<T>& source, Interpolation interpolation) const;
  const double* map_of(int32_t owner) const;

  ImageGeometry source_;
  ImageGeometry output_;
  // Per output voxel, as owner() but holding rasterized indices, kept on its rows' spans: off them every voxel holds
  // -1 (the background's map), most of a grid whose root did not move.
  std::shared_ptr<const RowPacked<int32_t>> owner_;
  std::vector<int32_t> tets_;              // rasterized index -> tet
  std::shared_ptr<double[]> maps_;         // 12 per rasterized tet: output index -> source index, s = A u + b
  double background_map_[12] = {};         // the same for the background transform
  std::vector<double> bone_maps_;          // 12 per bone segment (RigidBones)
  // Per bone segment: its voxels were claimed through its own map (it moves off the background, or its map is the
  // background's bit for bit), so each lands on its own bone exactly.
  std::vector<uint8_t> claimed_by_own_map_;
  const BoneVoxels* bones_ = nullptr;
  Label label_background_ = 0;
  float intensity_background_ = 0.0f;
  int64_t rasterized_tets_ = 0;
  WarpStats stats_;
};

}  // namespace posewarp::resample
