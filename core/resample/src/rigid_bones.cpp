// Bone voxels of a source grid: segment per bone voxel, index boxes, soft-tissue substitutes for bone voxels.
#include "posewarp/common/exception_wall.h"
#include "posewarp/common/parallel.h"
#include "posewarp/resample/rigid_bones.h"

#include <algorithm>
#include <atomic>
#include <bit>
#include <limits>
#include <mutex>
#include <new>
#include <unordered_map>

namespace posewarp::resample {

namespace {

// Calls visit(v, rank) for each bone voxel v in voxel order, rank its entry of `substitute`.
template <typename Visit>
void for_each_bone_voxel(const BoneVoxels& bones, Visit&& visit) {
  int32_t rank = 0;
  for (size_t w = 0; w < bones.bone_bits.size(); ++w) {
    for (uint64_t bits = bones.bone_bits[w]; bits != 0; bits &= bits - 1) {
      visit(static_cast<int64_t>(64 * w) + std::countr_zero(bits), rank++);
    }
  }
}

// The substitutes a rig file kept: each voxel its own but those listed.
Status take_substitutes(const BoneSubstitutes& given, BoneVoxels& bones) {
  if (given.voxel.size() != given.substitute.size()) {
    return data_loss_error("a substitute table of " + std::to_string(given.voxel.size()) + " voxels and " +
                           std::to_string(given.substitute.size()) + " substitutes; rebuild the rig that kept it");
  }
  size_t next = 0;
  for_each_bone_voxel(bones, [&](int64_t v, int32_t rank) {
    const bool listed = next < given.voxel.size() && given.voxel[next] == v;
    bones.substitute[static_cast<size_t>(rank)] = listed ? given.substitute[next++] : static_cast<int32_t>(v);
  });
  if (next != given.voxel.size()) {
    return data_loss_error("the substitute table (rig section SUBS) names voxel " + std::to_string(given.voxel[next]) +
                           ", which is no bone voxel of the rig's labels; the file is damaged. Rebuild the rig");
  }
  return ok_status();
}

}  // namespace

BoneSubstitutes BoneVoxels::sparse() const {
  BoneSubstitutes out;
  for_each_bone_voxel(*this, [&](int64_t v, int32_t rank) {
    const int32_t s = substitute[static_cast<size_t>(rank)];
    if (s == v) return;
    out.voxel.push_back(static_cast<int32_t>(v));
    out.substitute.push_back(s);
  });
  return out;
}

Result<BoneVoxels> bone_voxels(const LabelVolume& labels, const std::vector<std::vector<Label>>& segment_labels,
                               const BoneSubstitutes* substitutes) {
  if (segment_labels.size() > static_cast<size_t>(std::numeric_limits<int16_t>::max())) {
    return invalid_argument_error("too many bone segments for the voxel map (" + std::to_string(segment_labels.size()) +
                                  ")");
  }
  return guarded("mapping the bone voxels of " + labels.geometry().describe(), [&]() -> Result<BoneVoxels> {
    BoneVoxels bones;
    // Each label's segment from a table over the labels' range (a hash lookup per voxel cost a whole body 0.2 s).
    Label lowest = std::numeric_limits<Label>::max(), highest = std::numeric_limits<Label>::lowest();
    for (const std::vector<Label>& values : segment_labels) {
      for (const Label value : values) lowest = std::min(lowest, value), highest = std::max(highest, value);
    }
    // Label values spread wider than 4M (no real label map) take a hash map instead.
    const bool tabled = lowest <= highest && int64_t{highest} - lowest < (int64_t{1} << 22);
    std::vector<int16_t> table;
    std::unordered_map<Label, int16_t> hashed;
    if (tabled) table.assign(static_cast<size_t>(int64_t{highest} - lowest + 1), BoneVoxels::kNone);
    for (size_t k = 0; k < segment_labels.size(); ++k) {
      for (const Label value : segment_labels[k]) {
        (tabled ? table[static_cast<size_t>(int64_t{value} - lowest)] : hashed[value]) = static_cast<int16_t>(k);
      }
    }
    auto segment_of = [&](Label value) -> int16_t {
      if (value < lowest || value > highest) return BoneVoxels::kNone;
      if (tabled) return table[static_cast<size_t>(int64_t{value} - lowest)];
      const auto it = hashed.find(value);
      return it == hashed.end() ? BoneVoxels::kNone : it->second;
    };
    const ImageGeometry& g = labels.geometry();
    const int64_t n = labels.voxel_count(), words = (n + 63) / 64;
    // The rank index first (a bit per bone voxel; no table per voxel), with each segment's box: slabs of slices in
    // parallel, each with its own boxes and count, merged after. A slab's first and last words may be shared with the
    // next slab's, so words are or-ed in.
    bones.voxel_count = n;
    bones.bone_bits.assign(static_cast<size_t>(words), 0);
    using Box = std::array<int64_t, 6>;
    const Box empty{std::numeric_limits<int64_t>::max(), std::numeric_limits<int64_t>::max(),
                    std::numeric_limits<int64_t>::max(), -1, -1, -1};
    bones.box.assign(segment_labels.size(), empty);
    const Label* data = labels.data();
    std::mutex merge;
    parallel_for(0, g.size[2], 1, [&](int64_t k0, int64_t k1) {
      std::vector<Box> boxes(segment_labels.size(), empty);
      int64_t count = 0;
      uint64_t bits = 0;
      int64_t word = g.offset(0, 0, k0) >> 6;
      auto flush = [&] {
        if (bits != 0) std::atomic_ref<uint64_t>(bones.bone_bits[static_cast<size_t>(word)]).fetch_or(bits);
        bits = 0;
      };
      for (int64_t k = k0; k < k1; ++k) {
        for (int64_t j = 0; j < g.size[1]; ++j) {
          for (int64_t i = 0, v = g.offset(0, j, k); i < g.size[0]; ++i, ++v) {
            const int16_t segment = segment_of(data[v]);
            if (segment == BoneVoxels::kNone) continue;
            if ((v >> 6) != word) {
              flush();
              word = v >> 6;
            }
            bits |= uint64_t{1} << (v & 63);
            ++count;
            Box& box = boxes[static_cast<size_t>(segment)];
            box[0] = std::min(box[0], i), box[1] = std::min(box[1], j), box[2] = std::min(box[2], k);
            box[3] = std::max(box[3], i), box[4] = std::max(box[4], j), box[5] = std::max(box[5], k);
          }
        }
      }
      flush();
      const std::lock_guard<std::mutex> lock(merge);
      bones.bone_voxels += count;
      for (size_t s = 0; s < boxes.size(); ++s) {
        for (int a = 0; a < 3; ++a) {
          const auto lo = static_cast<size_t>(a), hi = static_cast<size_t>(a + 3);
          Box& box = bones.box[s];
          box[lo] = std::min(box[lo], boxes[s][lo]);
          box[hi] = std::max(box[hi], boxes[s][hi]);
        }
      }
    });
    bones.bones_before.resize(static_cast<size_t>(words));
    int32_t before = 0;
    for (int64_t w = 0; w < words; ++w) {
      bones.bones_before[static_cast<size_t>(w)] = before;
      before += count_bits(bones.bone_bits[static_cast<size_t>(w)]);
    }
    // Then each bone voxel's segment, in rank order, and room for its substitute.
    bones.substitute.assign(static_cast<size_t>(before), -1);
    bones.bone_segment.resize(static_cast<size_t>(before));
    parallel_for(0, words, 4096, [&](int64_t w0, int64_t w1) {
      for (int64_t w = w0; w < w1; ++w) {
        auto rank = static_cast<size_t>(bones.bones_before[static_cast<size_t>(w)]);
        for (uint64_t bits = bones.bone_bits[static_cast<size_t>(w)]; bits != 0; bits &= bits - 1) {
          bones.bone_segment[rank++] = segment_of(data[64 * w + std::countr_zero(bits)]);
        }
      }
    });
    if (substitutes) {
      POSEWARP_RETURN_IF_ERROR(take_substitutes(*substitutes, bones));
      return bones;
    }
    // Breadth first from the non-bone voxels next to a bone inward: each bone voxel inherits the substitute of the
    // neighbour that reached it first.
    auto substitute = [&bones](int64_t v) -> int32_t& { return bones.substitute[bones.rank_of(v)]; };
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
    for_each_bone_voxel(bones, [&](int64_t v, int32_t rank) {
      int32_t& mine = bones.substitute[static_cast<size_t>(rank)];
      for_neighbours(v, [&](int64_t w) {
        if (mine < 0 && !bones.is_bone(w)) mine = static_cast<int32_t>(w);
      });
      if (mine >= 0) front.push_back(v);
    });
    while (!front.empty()) {
      next.clear();
      for (const int64_t v : front) {
        const int32_t mine = substitute(v);
        for_neighbours(v, [&](int64_t w) {
          if (bones.is_bone(w) && substitute(w) < 0) {
            substitute(w) = mine;
            next.push_back(w);
          }
        });
      }
      front.swap(next);
    }
    // A bone that fills the whole grid has no soft voxel to offer: it keeps its own values.
    for_each_bone_voxel(bones, [&](int64_t v, int32_t rank) {
      int32_t& mine = bones.substitute[static_cast<size_t>(rank)];
      if (mine < 0) mine = static_cast<int32_t>(v);
    });
    return bones;
  });
}

}  // namespace posewarp::resample
