// Where soft tissue that maps onto a bone takes its value from: each bone voxel's substitute, a nearby voxel outside
// the bones. Kept sparse: the voxels whose substitute is another voxel (ascending) with their substitutes; every
// other voxel is its own. The bones are a tenth of a body's grid, so this holds a tenth of a table per voxel.
#pragma once

#include <cstdint>
#include <vector>

namespace posewarp {

struct BoneSubstitutes {
  std::vector<int32_t> voxel;       // ascending voxel indices
  std::vector<int32_t> substitute;  // per entry of `voxel`, the voxel whose value it takes

  bool operator==(const BoneSubstitutes&) const = default;
};

}  // namespace posewarp
