// Each joint's gap cut along its middle, so that its two sides slide (see soft_tissue.h).
#include <algorithm>
#include <utility>
#include <vector>

#include "posewarp/fem/soft_tissue.h"

namespace posewarp::fem {
namespace {

constexpr int32_t kNoBone = -1, kTwoBones = -2;

// (side, tets) pairs of one vertex: a few at most, so a flat list.
using SideCounts = std::vector<std::pair<int32_t, int>>;

void count(SideCounts& counts, int32_t side) {
  for (auto& [s, k] : counts) {
    if (s == side) {
      ++k;
      return;
    }
  }
  counts.emplace_back(side, 1);
}

// The side with the most entries, the lower segment on a tie.
int32_t most(const SideCounts& counts) {
  int32_t best = kNoBone;
  int best_count = 0;
  for (const auto& [s, k] : counts) {
    if (k > best_count || (k == best_count && s < best)) best = s, best_count = k;
  }
  return best;
}

}  // namespace

int64_t cut_joint_gaps(TetMesh& mesh, SkinWeights& weights, RotationCentres& centres) {
  const int64_t n = mesh.vertex_count();
  if (mesh.tet_class.size() != mesh.tet_count() || weights.vertex_count() != n || centres.centre.rows() != n ||
      static_cast<int64_t>(centres.rigid.size()) != n) {
    return 0;
  }
  const std::vector<uint8_t> skin = skin_vertices(mesh);
  // The bone segment whose tets each vertex is a corner of.
  std::vector<int32_t> bone_of(static_cast<size_t>(n), kNoBone);
  for (int64_t t = 0; t < mesh.tet_count(); ++t) {
    if (mesh.tet_class(t) < kFirstBoneClass) continue;
    const int32_t s = mesh.tet_class(t) - kFirstBoneClass;
    for (int c = 0; c < 4; ++c) {
      int32_t& b = bone_of[static_cast<size_t>(mesh.tets(t, c))];
      b = b == kNoBone || b == s ? s : kTwoBones;
    }
  }
  // Each soft tet's side: the bone most of its bone corners are on; none without a bone corner or with a corner on
  // two bones. Each vertex's soft tets, by side.
  std::vector<int32_t> side(static_cast<size_t>(mesh.tet_count()), kNoBone);
  std::vector<int64_t> start(static_cast<size_t>(n) + 1, 0);
  for (int64_t t = 0; t < mesh.tet_count(); ++t) {
    if (mesh.tet_class(t) != kSoftTissueClass) continue;
    SideCounts corners;
    bool two = false;
    for (int c = 0; c < 4; ++c) {
      const int32_t b = bone_of[static_cast<size_t>(mesh.tets(t, c))];
      two = two || b == kTwoBones;
      if (b >= 0) count(corners, b);
      ++start[static_cast<size_t>(mesh.tets(t, c)) + 1];
    }
    if (!two) side[static_cast<size_t>(t)] = most(corners);
  }
  for (size_t v = 1; v < start.size(); ++v) start[v] += start[v - 1];
  std::vector<int32_t> soft_tets(static_cast<size_t>(start.back()));
  {
    std::vector<int64_t> at(start.begin(), start.end() - 1);
    for (int64_t t = 0; t < mesh.tet_count(); ++t) {
      if (mesh.tet_class(t) != kSoftTissueClass) continue;
      for (int c = 0; c < 4; ++c)
        soft_tets[static_cast<size_t>(at[static_cast<size_t>(mesh.tets(t, c))]++)] = static_cast<int32_t>(t);
    }
  }
  // Per vertex: the tets of each side but its own get a copy of it. A bone vertex's own side is its bone's; a soft
  // vertex's, the side most of its tets are on, and a soft vertex is cut only where every tet around it has a side
  // (it lies between bones, not in tissue open to the rest of the body) and it is not on the skin.
  std::vector<int32_t> original;
  for (int64_t v = 0; v < n; ++v) {
    const int32_t b = bone_of[static_cast<size_t>(v)];
    if (b == kTwoBones) continue;
    SideCounts sides;
    bool open = false;
    for (int64_t e = start[static_cast<size_t>(v)]; e < start[static_cast<size_t>(v) + 1]; ++e) {
      const int32_t s = side[static_cast<size_t>(soft_tets[static_cast<size_t>(e)])];
      if (s < 0) {
        open = true;
      } else {
        count(sides, s);
      }
    }
    int32_t own = b;
    if (b == kNoBone) {
      if (open || skin[static_cast<size_t>(v)] || sides.size() < 2) continue;
      own = most(sides);
    }
    for (const auto& [s, k] : sides) {
      if (s == own) continue;
      const auto copy = static_cast<int32_t>(n + static_cast<int64_t>(original.size()));
      original.push_back(static_cast<int32_t>(v));
      for (int64_t e = start[static_cast<size_t>(v)]; e < start[static_cast<size_t>(v) + 1]; ++e) {
        const int32_t t = soft_tets[static_cast<size_t>(e)];
        if (side[static_cast<size_t>(t)] != s) continue;
        for (int c = 0; c < 4; ++c) {
          if (mesh.tets(t, c) == v) mesh.tets(t, c) = copy;
        }
      }
    }
  }
  // The copies: where their vertex is at rest, with its weights and centre, so that every skinning method moves them
  // with it.
  const auto added = static_cast<Eigen::Index>(original.size());
  mesh.vertices.conservativeResize(n + added, Eigen::NoChange);
  weights.segment.conservativeResize(n + added, Eigen::NoChange);
  weights.weight.conservativeResize(n + added, Eigen::NoChange);
  centres.centre.conservativeResize(n + added, Eigen::NoChange);
  centres.rigid.resize(static_cast<size_t>(n + added));
  for (Eigen::Index i = 0; i < added; ++i) {
    const int32_t v = original[static_cast<size_t>(i)];
    mesh.vertices.row(n + i) = mesh.vertices.row(v);
    weights.segment.row(n + i) = weights.segment.row(v);
    weights.weight.row(n + i) = weights.weight.row(v);
    centres.centre.row(n + i) = centres.centre.row(v);
    centres.rigid[static_cast<size_t>(n + i)] = centres.rigid[static_cast<size_t>(v)];
  }
  return added;
}

}  // namespace posewarp::fem
