// Bones rigid at voxel level: which source voxel belongs to which bone segment, and where soft tissue sampled
// inside a bone is taken from instead. The warp rasterizes each bone through its own rigid inverse, ahead of the tets,
// so a bone never bends whatever the mesh does near its surface.
#pragma once

#include <Eigen/Core>

#include <array>
#include <bit>
#include <cstdint>
#include <vector>

#include "posewarp/common/bone_substitutes.h"
#include "posewarp/common/result.h"
#include "posewarp/common/volume.h"

namespace posewarp::resample {

// What a source grid holds of the bones, computed once per rig.
struct BoneVoxels {
  static constexpr int16_t kNone = -1;
  std::vector<int16_t> segment;      // per source voxel: its bone segment, or kNone
  // Per bone voxel, in voxel order: the index of a nearby non-bone voxel (the nearest along a 26-neighbour
  // breadth-first search from the bone's surface). A soft-tissue map that lands inside a bone samples this voxel
  // instead, so bone values appear in the output only where a bone's own rigid map puts them.
  std::vector<int32_t> substitute;
  // A bone voxel's entry of `substitute`: per 64 voxels, a bit per bone voxel and how many bone voxels come before.
  std::vector<uint64_t> bone_bits;
  std::vector<int32_t> bones_before;
  std::vector<std::array<int64_t, 6>> box;  // per segment: source index box (i0, j0, k0, i1, j1, k1), empty: i0 > i1
  int64_t bone_voxels = 0;

  // Whether source voxel v is a bone voxel (segment[v] != kNone), from its bit: a lookup in 1/16 of the segment
  // table's bytes, which stays in cache where the table would not.
  bool is_bone(int64_t v) const { return (bone_bits[static_cast<size_t>(v >> 6)] >> (v & 63)) & 1; }
  // Bone voxel v's entry of `substitute` (segment[v] != kNone), and its substitute.
  size_t rank_of(int64_t v) const {
    const auto word = static_cast<size_t>(v >> 6);
    const uint64_t below = bone_bits[word] & ((uint64_t{1} << (v & 63)) - 1);
    return static_cast<size_t>(bones_before[word] + std::popcount(below));
  }
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
  const std::vector<int16_t>* region = nullptr;      // per source voxel: nearest-bone region, -1 outside the body
  const std::vector<int16_t>* tet_region = nullptr;  // per tet
  const std::vector<uint8_t>* separated = nullptr;   // segment_count x segment_count
};

}  // namespace posewarp::resample
