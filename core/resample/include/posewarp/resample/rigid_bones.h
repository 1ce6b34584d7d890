// Bones rigid at voxel level: which source voxel belongs to which bone segment, and where soft tissue sampled
// inside a bone is taken from instead. The warp rasterizes each bone through its own rigid inverse, ahead of the tets,
// so a bone never bends whatever the mesh does near its surface.
#pragma once

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <vector>

#include "posewarp/common/bone_substitutes.h"
#include "posewarp/common/result.h"
#include "posewarp/common/row_packed.h"
#include "posewarp/common/volume.h"

namespace posewarp::resample {

// Bits set in x. std::popcount calls libgcc where the popcnt instruction is not in the target (x86-64's baseline):
// this is a dozen inline operations instead.
inline int count_bits(uint64_t x) {
  x = x - ((x >> 1) & 0x5555555555555555ULL);
  x = (x & 0x3333333333333333ULL) + ((x >> 2) & 0x3333333333333333ULL);
  x = (x + (x >> 4)) & 0x0F0F0F0F0F0F0F0FULL;
  return static_cast<int>((x * 0x0101010101010101ULL) >> 56);
}

// What a source grid holds of the bones, computed once per rig: kept per bone voxel (a body's are a tenth of its
// voxels) behind a rank index.
struct BoneVoxels {
  static constexpr int16_t kNone = -1;
  int64_t voxel_count = 0;  // of the source grid
  // Per 64 source voxels, a bit per bone voxel and how many bone voxels come before: a bone voxel's rank, its entry
  // in the per-bone-voxel arrays below.
  std::vector<uint64_t> bone_bits;
  std::vector<int32_t> bones_before;
  std::vector<int16_t> bone_segment;  // per bone voxel, in voxel order: its bone segment
  // Per bone voxel, in voxel order: the index of a nearby non-bone voxel (the nearest along a 26-neighbour
  // breadth-first search from the bone's surface). A soft-tissue map that lands inside a bone samples this voxel
  // instead, so bone values appear in the output only where a bone's own rigid map puts them.
  std::vector<int32_t> substitute;
  std::vector<std::array<int64_t, 6>> box;  // per segment: source index box (i0, j0, k0, i1, j1, k1), empty: i0 > i1
  int64_t bone_voxels = 0;

  // Whether source voxel v is a bone voxel, from its bit (one bit per voxel stays in cache).
  bool is_bone(int64_t v) const { return (bone_bits[static_cast<size_t>(v >> 6)] >> (v & 63)) & 1; }
  // Bone voxel v's rank: its entry of bone_segment and substitute.
  size_t rank_of(int64_t v) const {
    const auto word = static_cast<size_t>(v >> 6);
    const uint64_t below = bone_bits[word] & ((uint64_t{1} << (v & 63)) - 1);
    return static_cast<size_t>(bones_before[word] + count_bits(below));
  }
  // Source voxel v's bone segment, or kNone.
  int16_t segment_of(int64_t v) const { return is_bone(v) ? bone_segment[rank_of(v)] : kNone; }
  int32_t substitute_of(int64_t v) const { return substitute[rank_of(v)]; }
  // The substitutes as a rig file keeps them: only those of another voxel than their own.
  BoneSubstitutes sparse() const;
};

// `segment_labels[k]` holds the label values of bone segment k. `substitutes`, when given, are those an earlier call
// made for the same labels and segments (a rig file keeps them): taken as they are instead of the search, which costs
// a whole body 0.2 s; DATA_LOSS where they name a voxel that is no bone. INVALID_ARGUMENT over 32767 segments;
// RESOURCE_EXHAUSTED when out of memory.
Result<BoneVoxels> bone_voxels(const LabelVolume& labels, const std::vector<std::vector<Label>>& segment_labels,
                               const BoneSubstitutes* substitutes = nullptr);

// The bones of one pose for the warp: the source's bone voxels and each segment's rest -> posed rigid transform.
struct RigidBones {
  const BoneVoxels* voxels = nullptr;
  std::vector<Eigen::Matrix3d> rotation;     // per segment, LPS
  std::vector<Eigen::Vector3d> translation;  // per segment, mm
  // Optional, body parts cut apart at skin contacts (rig/skin_contacts.h): a tet, or the skin shell it extends over,
  // never shows tissue of a region separated from its own (the thigh's skin under a hand that rises with the arm).
  const RowPacked<int16_t>* region = nullptr;        // per source voxel: nearest-bone region, -1 outside the body
  const std::vector<int16_t>* tet_region = nullptr;  // per tet
  const std::vector<uint8_t>* separated = nullptr;   // segment_count x segment_count
};

}  // namespace posewarp::resample
