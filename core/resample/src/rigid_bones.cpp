// Bone voxels of a source grid: segment per voxel, index boxes, soft-tissue substitutes for bone voxels.
#include "posewarp/common/exception_wall.h"
#include "posewarp/resample/rigid_bones.h"

#include <algorithm>
#include <limits>
#include <new>
#include <unordered_map>

namespace posewarp::resample {

Result<BoneVoxels> bone_voxels(const LabelVolume& labels, const std::vector<std::vector<Label>>& segment_labels) {
  if (segment_labels.size() > static_cast<size_t>(std::numeric_limits<int16_t>::max())) {
    return invalid_argument_error("too many bone segments for the voxel map (" + std::to_string(segment_labels.size()) +
                                  ")");
  }
  return guarded("mapping the bone voxels of " + labels.geometry().describe(), [&]() -> Result<BoneVoxels> {
    BoneVoxels bones;
    std::unordered_map<Label, int16_t> segment_of;
    for (size_t k = 0; k < segment_labels.size(); ++k) {
      for (const Label value : segment_labels[k]) segment_of[value] = static_cast<int16_t>(k);
    }
    const ImageGeometry& g = labels.geometry();
    const int64_t n = labels.voxel_count();
    bones.segment.assign(static_cast<size_t>(n), BoneVoxels::kNone);
    bones.substitute.assign(static_cast<size_t>(n), -1);
    bones.box.assign(segment_labels.size(), {std::numeric_limits<int64_t>::max(), std::numeric_limits<int64_t>::max(),
                                             std::numeric_limits<int64_t>::max(), -1, -1, -1});
    const Label* data = labels.data();
    for (int64_t k = 0, v = 0; k < g.size[2]; ++k) {
      for (int64_t j = 0; j < g.size[1]; ++j) {
        for (int64_t i = 0; i < g.size[0]; ++i, ++v) {
          const auto it = segment_of.find(data[v]);
          if (it == segment_of.end()) continue;
          bones.segment[static_cast<size_t>(v)] = it->second;
          ++bones.bone_voxels;
          std::array<int64_t, 6>& box = bones.box[static_cast<size_t>(it->second)];
          box[0] = std::min(box[0], i), box[1] = std::min(box[1], j), box[2] = std::min(box[2], k);
          box[3] = std::max(box[3], i), box[4] = std::max(box[4], j), box[5] = std::max(box[5], k);
        }
      }
    }
    // Breadth first from the non-bone voxels next to a bone inward: each bone voxel inherits the substitute of the
    // neighbour that reached it first.
    std::vector<int64_t> front, next;
    auto for_neighbours = [&](int64_t v, auto&& visit) {
      const int64_t i = v % g.size[0], j = (v / g.size[0]) % g.size[1], k = v / (g.size[0] * g.size[1]);
      for (int64_t dk = -1; dk <= 1; ++dk) {
        for (int64_t dj = -1; dj <= 1; ++dj) {
          for (int64_t di = -1; di <= 1; ++di) {
            if (!(di || dj || dk) || !labels.contains(i + di, j + dj, k + dk)) continue;
            visit(g.offset(i + di, j + dj, k + dk));
          }
        }
      }
    };
    for (int64_t v = 0; v < n; ++v) {
      if (bones.segment[static_cast<size_t>(v)] == BoneVoxels::kNone) continue;
      for_neighbours(v, [&](int64_t w) {
        if (bones.substitute[static_cast<size_t>(v)] < 0 && bones.segment[static_cast<size_t>(w)] == BoneVoxels::kNone) {
          bones.substitute[static_cast<size_t>(v)] = static_cast<int32_t>(w);
        }
      });
      if (bones.substitute[static_cast<size_t>(v)] >= 0) front.push_back(v);
    }
    while (!front.empty()) {
      next.clear();
      for (const int64_t v : front) {
        for_neighbours(v, [&](int64_t w) {
          if (bones.segment[static_cast<size_t>(w)] != BoneVoxels::kNone && bones.substitute[static_cast<size_t>(w)] < 0) {
            bones.substitute[static_cast<size_t>(w)] = bones.substitute[static_cast<size_t>(v)];
            next.push_back(w);
          }
        });
      }
      front.swap(next);
    }
    // A bone that fills the whole grid has no soft voxel to offer: it keeps its own values.
    for (int64_t v = 0; v < n; ++v) {
      if (bones.substitute[static_cast<size_t>(v)] < 0) bones.substitute[static_cast<size_t>(v)] = static_cast<int32_t>(v);
    }
    return bones;
  });
}

}  // namespace posewarp::resample
