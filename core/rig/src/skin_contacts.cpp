// Skin contacts: nearest-bone regions of the body, their depth below the skin, and the cut between regions that
// must move apart.
#include "posewarp/common/exception_wall.h"
#include "posewarp/rig/skin_contacts.h"

#include "posewarp/common/tet_mesh.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <new>
#include <set>
#include <unordered_map>

namespace posewarp::rig {
namespace {

struct Step {
  int64_t di, dj, dk;
  float length;
};

// The 13 neighbours that come before a voxel in memory order, with their lengths in mm.
std::vector<Step> backward_steps(const ImageGeometry& g) {
  std::vector<Step> steps;
  for (int64_t dk = -1; dk <= 0; ++dk)
    for (int64_t dj = -1; dj <= 1; ++dj)
      for (int64_t di = -1; di <= 1; ++di) {
        if (dk == 0 && (dj > 0 || (dj == 0 && di >= 0))) continue;
        const double x = double(di) * g.spacing[0], y = double(dj) * g.spacing[1], z = double(dk) * g.spacing[2];
        steps.push_back({di, dj, dk, static_cast<float>(std::sqrt(x * x + y * y + z * z))});
      }
  return steps;
}

// Two-pass chamfer: distance[v] = min over neighbours w (distance + step) for voxels where `open(v)` and
// `allow(v, w)`; `carry` copies what travels with the distance (the nearest segment). Whether any distance fell.
template <typename Open, typename Allow, typename Carry>
bool chamfer(const ImageGeometry& g, std::vector<float>& distance, const Open& open, const Allow& allow,
             const Carry& carry) {
  const std::vector<Step> steps = backward_steps(g);
  const Index3 n = g.size;
  bool changed = false;
  for (int pass = 0; pass < 2; ++pass) {
    const int sign = pass == 0 ? 1 : -1;
    for (int64_t kk = 0; kk < n[2]; ++kk) {
      const int64_t k = pass == 0 ? kk : n[2] - 1 - kk;
      for (int64_t jj = 0; jj < n[1]; ++jj) {
        const int64_t j = pass == 0 ? jj : n[1] - 1 - jj;
        for (int64_t ii = 0; ii < n[0]; ++ii) {
          const int64_t i = pass == 0 ? ii : n[0] - 1 - ii;
          const int64_t v = g.offset(i, j, k);
          if (!open(v)) continue;
          for (const Step& s : steps) {
            const int64_t x = i + sign * s.di, y = j + sign * s.dj, z = k + sign * s.dk;
            if (x < 0 || y < 0 || z < 0 || x >= n[0] || y >= n[1] || z >= n[2]) continue;
            const int64_t w = g.offset(x, y, z);
            const float through = distance[static_cast<size_t>(w)] + s.length;
            if (through < distance[static_cast<size_t>(v)] && allow(v, w)) {
              distance[static_cast<size_t>(v)] = through;
              carry(v, w);
              changed = true;
            }
          }
        }
      }
    }
  }
  return changed;
}

}  // namespace

Status validate(const SkinContactParams& params) {
  if (!(params.depth_mm >= 0.0) || !std::isfinite(params.depth_mm) || params.depth_mm > 200.0) {
    return invalid_argument_error("skin contact depth_mm must lie in 0..200 mm (0: no cut)");
  }
  return ok_status();
}

Result<BodyRegions> body_regions(const Skeleton& skeleton, const LabelVolume& labels, const LabelVolume& body) {
  if (!labels.geometry().same_grid(body.geometry())) {
    return invalid_argument_error("the body mask is not on the labels' grid");
  }
  return guarded("finding the body regions of " + labels.geometry().describe(), [&]() -> Result<BodyRegions> {
    BodyRegions regions;
    const ImageGeometry& g = labels.geometry();
    const int64_t nv = labels.voxel_count();
    std::unordered_map<Label, int16_t> segment_of;
    for (size_t k = 0; k < skeleton.segments.size(); ++k) {
      for (const Label v : skeleton.segments[k].labels) segment_of[v] = static_cast<int16_t>(k);
    }
    constexpr float kFar = std::numeric_limits<float>::max() / 4;
    regions.segment.assign(static_cast<size_t>(nv), -1);
    std::vector<float> to_bone(static_cast<size_t>(nv), kFar);
    regions.depth_mm.assign(static_cast<size_t>(nv), 0.0f);
    for (int64_t v = 0; v < nv; ++v) {
      if (body.data()[v] == 0) continue;
      regions.depth_mm[static_cast<size_t>(v)] = kFar;
      const auto it = segment_of.find(labels.data()[v]);
      if (it != segment_of.end()) {
        regions.segment[static_cast<size_t>(v)] = it->second;
        to_bone[static_cast<size_t>(v)] = 0.0f;
      }
    }
    auto inside = [&](int64_t v) { return body.data()[v] != 0; };
    auto always = [](int64_t, int64_t) { return true; };
    chamfer(g, regions.depth_mm, inside, always, [](int64_t, int64_t) {});
    // A body touching the grid's edge: those voxels are at the skin too (the scan cut through the body there).
    for (int64_t v = 0; v < nv; ++v) {
      if (regions.depth_mm[static_cast<size_t>(v)] >= kFar) regions.depth_mm[static_cast<size_t>(v)] = 0.0f;
    }
    // A limb's tissue lies between its bones and its own skin: from the bone outwards it only gets nearer the skin.
    // Where a limb rests against the trunk, its region would otherwise go on through the contact into the trunk and
    // take whatever lies nearer the limb's bone than the trunk's (the flank of the liver, nearer the elbow than the
    // ribs, moved with the forearm): a limb's region enters no voxel deeper below the skin than the bone voxel it
    // comes from, give or take half a voxel. Paths then bend, which one forward and one backward sweep do not
    // follow: the sweeps repeat until nothing changes, at most kSweeps (on body_check's 16M-voxel rig they settle
    // after 9; after 3, 3 voxels differ from that, after 2, 16, after 1, 1868).
    const std::vector<uint8_t> limb = limb_segments(skeleton);
    std::vector<float> source_depth = regions.depth_mm;
    const float slack = static_cast<float>(0.5 * std::max({g.spacing[0], g.spacing[1], g.spacing[2]}));
    auto within_own_skin = [&](int64_t v, int64_t w) {
      const int16_t s = regions.segment[static_cast<size_t>(w)];
      return s < 0 || !limb[static_cast<size_t>(s)] ||
             regions.depth_mm[static_cast<size_t>(v)] <= source_depth[static_cast<size_t>(w)] + slack;
    };
    auto carry = [&](int64_t v, int64_t w) {
      regions.segment[static_cast<size_t>(v)] = regions.segment[static_cast<size_t>(w)];
      source_depth[static_cast<size_t>(v)] = source_depth[static_cast<size_t>(w)];
    };
    constexpr int kSweeps = 3;
    for (int sweep = 0; sweep < kSweeps && chamfer(g, to_bone, inside, within_own_skin, carry); ++sweep) {
    }
    return regions;
  });
}

namespace {

// limb[s]: the limb-root joint above segment s (-1 in the trunk), and per limb root the trunk bones it hangs from.
struct Limbs {
  std::vector<int> limb;
  std::vector<std::vector<int>> attached;
};

Limbs find_limbs(const Skeleton& skeleton) {
  const size_t n = skeleton.segments.size();
  bool any_ball = false;
  for (const Joint& joint : skeleton.joints) any_ball = any_ball || joint.kind == labels::JointKind::kBall;
  auto limb_root = [&](const Joint& joint) {
    const bool ball = any_ball ? joint.kind == labels::JointKind::kBall : joint.method == "sphere-fit";
    return ball && joint.side != BodySide::kMidline;
  };
  // Joints come parents first.
  Limbs limbs;
  std::vector<int>& limb = limbs.limb;
  std::vector<std::vector<int>>& attached = limbs.attached;
  limb.assign(n, -1);
  attached.resize(skeleton.joints.size());
  for (size_t j = 0; j < skeleton.joints.size(); ++j) {
    const Joint& joint = skeleton.joints[j];
    const int from_parent = limb[static_cast<size_t>(joint.parent)];
    if (from_parent >= 0) {
      limb[static_cast<size_t>(joint.child)] = from_parent;
    } else if (limb_root(joint)) {
      limb[static_cast<size_t>(joint.child)] = static_cast<int>(j);
      // The bone it hangs from and its lateral ancestors: the shoulder girdle moves with the arm's tissue.
      int s = joint.parent;
      attached[j].push_back(s);
      // A segment is lateral when the joint above it is (the scapula under the clavicle under the thorax).
      for (int up = skeleton.segments[static_cast<size_t>(s)].parent_joint;
           up >= 0 && skeleton.joints[static_cast<size_t>(up)].side != BodySide::kMidline;
           up = skeleton.segments[static_cast<size_t>(s)].parent_joint) {
        s = skeleton.joints[static_cast<size_t>(up)].parent;
        const int above = skeleton.segments[static_cast<size_t>(s)].parent_joint;
        if (above < 0 || skeleton.joints[static_cast<size_t>(above)].side == BodySide::kMidline) break;
        attached[j].push_back(s);
      }
    }
  }
  return limbs;
}

}  // namespace

std::vector<uint8_t> limb_segments(const Skeleton& skeleton) {
  const Limbs limbs = find_limbs(skeleton);
  std::vector<uint8_t> in_limb(limbs.limb.size(), 0);
  for (size_t s = 0; s < limbs.limb.size(); ++s) in_limb[s] = limbs.limb[s] >= 0;
  return in_limb;
}

std::vector<uint8_t> separated_segments(const Skeleton& skeleton) {
  const size_t n = skeleton.segments.size();
  std::vector<uint8_t> separated(n * n, 0);
  const Limbs limbs = find_limbs(skeleton);
  const std::vector<int>& limb = limbs.limb;
  const std::vector<std::vector<int>>& attached = limbs.attached;
  for (size_t a = 0; a < n; ++a) {
    for (size_t b = 0; b < n; ++b) {
      if (a == b) continue;
      const int la = limb[a], lb = limb[b];
      bool cut = false;
      if (la >= 0 && lb >= 0) {
        cut = la != lb;
      } else if (la >= 0 || lb >= 0) {
        const int l = la >= 0 ? la : lb;
        const int trunk = static_cast<int>(la >= 0 ? b : a);
        const std::vector<int>& hangs = attached[static_cast<size_t>(l)];
        cut = std::find(hangs.begin(), hangs.end(), trunk) == hangs.end();
      }
      separated[a * n + b] = cut;
    }
  }
  return separated;
}

SkinContactCut cut_skin_contacts(LabelVolume& classes, const Skeleton& skeleton, const BodyRegions& regions,
                                 const SkinContactParams& params) {
  SkinContactCut cut;
  if (params.depth_mm <= 0.0) return cut;
  const ImageGeometry& g = classes.geometry();
  const size_t n = skeleton.segments.size();
  const std::vector<uint8_t> separated = separated_segments(skeleton);
  std::vector<int64_t> marked;
  std::set<std::pair<int, int>> pairs;
  for (int64_t k = 0; k < g.size[2]; ++k) {
    for (int64_t j = 0; j < g.size[1]; ++j) {
      for (int64_t i = 0; i < g.size[0]; ++i) {
        const int64_t v = g.offset(i, j, k);
        if (classes.data()[v] != kSoftTissueClass || regions.depth_mm[static_cast<size_t>(v)] > params.depth_mm) continue;
        const int a = regions.segment[static_cast<size_t>(v)];
        if (a < 0) continue;
        bool touches = false;
        for (int64_t dk = -1; dk <= 1 && !touches; ++dk) {
          for (int64_t dj = -1; dj <= 1 && !touches; ++dj) {
            for (int64_t di = -1; di <= 1 && !touches; ++di) {
              if (!classes.contains(i + di, j + dj, k + dk)) continue;
              const int b = regions.segment[static_cast<size_t>(g.offset(i + di, j + dj, k + dk))];
              if (b < 0 || b == a || !separated[static_cast<size_t>(a) * n + static_cast<size_t>(b)]) continue;
              touches = true;
              pairs.insert({std::min(a, b), std::max(a, b)});
            }
          }
        }
        if (touches) marked.push_back(v);
      }
    }
  }
  for (const int64_t v : marked) classes.data()[v] = 0;
  cut.voxels = static_cast<int64_t>(marked.size());
  cut.segment_pairs.assign(pairs.begin(), pairs.end());
  return cut;
}

std::vector<int> vertex_regions(const TetMesh& mesh, const BodyRegions& regions, const ImageGeometry& grid) {
  std::vector<int> region(static_cast<size_t>(mesh.vertex_count()), -1);
  const PhysicalToIndex to_index(grid);
  for (int64_t v = 0; v < mesh.vertex_count(); ++v) {
    const Vec3 u = to_index({mesh.vertices(v, 0), mesh.vertices(v, 1), mesh.vertices(v, 2)});
    const int64_t ci = std::llround(u[0]), cj = std::llround(u[1]), ck = std::llround(u[2]);
    double best = std::numeric_limits<double>::infinity();
    for (int64_t dk = -2; dk <= 2; ++dk) {
      for (int64_t dj = -2; dj <= 2; ++dj) {
        for (int64_t di = -2; di <= 2; ++di) {
          const int64_t i = ci + di, j = cj + dj, k = ck + dk;
          if (i < 0 || j < 0 || k < 0 || i >= grid.size[0] || j >= grid.size[1] || k >= grid.size[2]) continue;
          const int r = regions.segment[static_cast<size_t>(grid.offset(i, j, k))];
          if (r < 0) continue;
          const double d = std::pow((i - u[0]) * grid.spacing[0], 2) + std::pow((j - u[1]) * grid.spacing[1], 2) +
                           std::pow((k - u[2]) * grid.spacing[2], 2);
          if (d < best) best = d, region[static_cast<size_t>(v)] = r;
        }
      }
    }
  }
  return region;
}

int64_t keep_weights_within_regions(SkinWeights& weights, const std::vector<int>& vertex_region,
                                    const Skeleton& skeleton) {
  const size_t n = skeleton.segments.size();
  const std::vector<uint8_t> separated = separated_segments(skeleton);
  int64_t changed = 0;
  for (int64_t v = 0; v < weights.vertex_count(); ++v) {
    const int r = vertex_region[static_cast<size_t>(v)];
    if (r < 0) continue;
    float kept = 0.0f;
    bool dropped = false;
    for (int c = 0; c < weights.influences; ++c) {
      const int s = weights.segment(v, c);
      if (s < 0) continue;
      if (s != r && separated[static_cast<size_t>(r) * n + static_cast<size_t>(s)]) {
        weights.weight(v, c) = 0.0f;
        weights.segment(v, c) = -1;
        dropped = true;
      } else {
        kept += weights.weight(v, c);
      }
    }
    if (!dropped) continue;
    ++changed;
    if (kept <= 0.0f) {
      weights.segment(v, 0) = r;
      weights.weight(v, 0) = 1.0f;
      for (int c = 1; c < weights.influences; ++c) weights.segment(v, c) = -1, weights.weight(v, c) = 0.0f;
      continue;
    }
    // Renormalize and keep the slots in descending order, unused ones last.
    std::vector<std::pair<float, int>> slots;
    for (int c = 0; c < weights.influences; ++c) {
      if (weights.segment(v, c) >= 0) slots.emplace_back(weights.weight(v, c) / kept, weights.segment(v, c));
    }
    std::sort(slots.begin(), slots.end(), [](const auto& a, const auto& b) { return a.first > b.first; });
    for (int c = 0; c < weights.influences; ++c) {
      const bool used = c < static_cast<int>(slots.size());
      weights.weight(v, c) = used ? slots[static_cast<size_t>(c)].first : 0.0f;
      weights.segment(v, c) = used ? slots[static_cast<size_t>(c)].second : -1;
    }
  }
  return changed;
}

int64_t tear_skin_contacts(TetMesh& mesh, const Skeleton& skeleton, const BodyRegions& regions, const ImageGeometry& grid) {
  const size_t n = skeleton.segments.size();
  const std::vector<uint8_t> separated = separated_segments(skeleton);
  const std::vector<int> region = vertex_regions(mesh, regions, grid);
  std::vector<uint8_t> keep(static_cast<size_t>(mesh.tet_count()), 1);
  int64_t torn = 0;
  for (int64_t t = 0; t < mesh.tet_count(); ++t) {
    if (mesh.tet_class(t) != kSoftTissueClass) continue;
    for (int a = 0; a < 4 && keep[static_cast<size_t>(t)]; ++a) {
      for (int b = a + 1; b < 4; ++b) {
        const int ra = region[static_cast<size_t>(mesh.tets(t, a))], rb = region[static_cast<size_t>(mesh.tets(t, b))];
        if (ra >= 0 && rb >= 0 && ra != rb && separated[static_cast<size_t>(ra) * n + static_cast<size_t>(rb)]) {
          keep[static_cast<size_t>(t)] = 0;
          ++torn;
          break;
        }
      }
    }
  }
  if (torn == 0) return 0;
  std::vector<int> new_index(static_cast<size_t>(mesh.vertex_count()), -1);
  int64_t kept_tets = 0;
  for (int64_t t = 0; t < mesh.tet_count(); ++t) {
    if (!keep[static_cast<size_t>(t)]) continue;
    for (int c = 0; c < 4; ++c) new_index[static_cast<size_t>(mesh.tets(t, c))] = 0;
    ++kept_tets;
  }
  int next = 0;
  for (int& index : new_index) index = index < 0 ? -1 : next++;
  TetMesh torn_mesh;
  torn_mesh.segment_count = mesh.segment_count;
  torn_mesh.vertices.resize(next, 3);
  for (int64_t v = 0; v < mesh.vertex_count(); ++v) {
    if (new_index[static_cast<size_t>(v)] >= 0) torn_mesh.vertices.row(new_index[static_cast<size_t>(v)]) = mesh.vertices.row(v);
  }
  torn_mesh.tets.resize(kept_tets, 4);
  torn_mesh.tet_class.resize(kept_tets);
  for (int64_t t = 0, out = 0; t < mesh.tet_count(); ++t) {
    if (!keep[static_cast<size_t>(t)]) continue;
    for (int c = 0; c < 4; ++c) torn_mesh.tets(out, c) = new_index[static_cast<size_t>(mesh.tets(t, c))];
    torn_mesh.tet_class(out) = mesh.tet_class(t);
    ++out;
  }
  mesh = std::move(torn_mesh);
  return torn;
}

}  // namespace posewarp::rig
