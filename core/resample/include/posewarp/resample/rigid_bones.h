// Bones rigid at voxel level: which source voxel belongs to which bone segment, and where soft tissue sampled
// inside a bone is taken from instead. The warp rasterizes each bone through its own rigid inverse, ahead of the tets,
// so a bone never bends whatever the mesh does near its surface.
#pragma once

#include <Eigen/Core>

#include <array>
#include <cstdint>
#include <vector>

#include "posewarp/common/result.h"
#include "posewarp/common/volume.h"

namespace posewarp::resample {

// What a source grid holds of the bones, computed once per rig.
struct BoneVoxels {
  static constexpr int16_t kNone = -1;
  std::vector<int16_t> segment;      // per source voxel: its bone segment, or kNone
  // Per source voxel, for bone voxels: the offset of a nearby non-bone voxel (the nearest along a 26-neighbour
  // breadth-first search from the bone's surface). A soft-tissue map that lands inside a bone samples this voxel
  // instead, so bone values appear in the output only where a bone's own rigid map puts them.
  std::vector<int32_t> substitute;
  std::vector<std::array<int64_t, 6>> box;  // per segment: source index box (i0, j0, k0, i1, j1, k1), empty: i0 > i1
  int64_t bone_voxels = 0;
};

// `segment_labels[k]` holds the label values of bone segment k. `substitute`, when not empty, is the substitute
// table an earlier call made for the same labels and segments (a rig file keeps it): taken as it is instead of the
// search, which costs a whole body 0.2 s. INVALID_ARGUMENT over 32767 segments; RESOURCE_EXHAUSTED when out of
// memory.
Result<BoneVoxels> bone_voxels(const LabelVolume& labels, const std::vector<std::vector<Label>>& segment_labels,
                               std::vector<int32_t> substitute = {});

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
