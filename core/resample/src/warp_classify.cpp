// TetWarp::Builder's pass 3 over output slabs: every voxel classified (covered, shell, background or nothing to
// sample), folds and contacts resolved, and the bones' claims.
#include "warp_builder.h"

#include <algorithm>
#include <cmath>

namespace posewarp::resample {

using namespace internal;

// The nearest source voxel (x, y, z) to source index s; false outside the source grid.
inline bool TetWarp::Builder::source_index(const double s[3], int64_t& x, int64_t& y, int64_t& z) const {
  x = round_index(s[0]), y = round_index(s[1]), z = round_index(s[2]);
  const Index3& m = in_.source.size;
  return x >= 0 && y >= 0 && z >= 0 && x < m[0] && y < m[1] && z < m[2];
}

// The source voxel at source index s, or -1 outside the source grid.
inline int64_t TetWarp::Builder::source_voxel(const double s[3]) const {
  int64_t x = 0, y = 0, z = 0;
  return source_index(s, x, y, z) ? in_.source.offset(x, y, z) : -1;
}

// The tet (rest owner code) that holds source index s in the rest pose; -1 when none or outside the grid.
inline int32_t TetWarp::Builder::rest_owner_at(const double s[3]) const {
  int64_t x = 0, y = 0, z = 0;
  return source_index(s, x, y, z) ? in_.rest_owner->at(x, y, z) : -1;
}

// The bone segment of the source voxel `map` takes output voxel (i, j, k) to; -1 for none or outside the grid.
inline int TetWarp::Builder::bone_at(const double* map, double i, double j, double k) const {
  double src[3];
  apply_map(map, i, j, k, src);
  const int64_t v = source_voxel(src);
  return v < 0 ? -1 : in_.bones->voxels->segment_of(v);
}

// Drops a tet's (or its shell's) sample of tissue from a body part separated from the tet's own.
inline void TetWarp::Builder::guard_contact(int32_t& o, int64_t i, int64_t j, int64_t k, WarpStats& stats) const {
  const bool tet_owned = o >= 0, shell_owned = o <= -2 && o != kNoSample && !is_bone_owner(o);
  if (!tet_owned && !shell_owned) return;
  const int32_t c = tet_owned ? o : -2 - o;
  const int rt = (*in_.bones->tet_region)[static_cast<size_t>(warp_.tets_[static_cast<size_t>(c)])];
  double src[3];
  apply_map(warp_.maps_.get() + 12 * c, double(i), double(j), double(k), src);
  int64_t x = 0, y = 0, z = 0;
  if (rt < 0 || !source_index(src, x, y, z)) return;
  const int rs = in_.bones->region->at(x, y, z);
  if (rs < 0 || rs == rt ||
      !(*in_.bones->separated)[static_cast<size_t>(rt) * segment_count_ + static_cast<size_t>(rs)])
    return;
  o = kNoSample;
  ++stats.contact_guarded_voxels;
}

// Claims voxel (i, j, k) for a bone, given its owner after classification: a moving bone on the row (segment, i0,
// i1) whose rigid inverse lands on its own source voxel, or a bone that follows the background where a tet or the
// shell would sample it. Two claims are an overlap; the lower segment keeps the voxel.
inline void TetWarp::Builder::claim_bone(int32_t& o, int64_t i, int64_t j, int64_t k,
                                         const std::vector<std::array<int64_t, 3>>& row_bones, WarpStats& stats) const {
  int claimed = -1;
  auto overlap = [&](int other) {
    if (claimed < 0) {
      claimed = other;
    } else if (claimed != other) {
      ++stats.bone_overlap_voxels[{std::min(claimed, other), std::max(claimed, other)}];
      claimed = std::min(claimed, other);
    }
  };
  for (const auto& [segment, i0, i1] : row_bones) {
    if (i < i0 || i > i1) continue;
    const int k_seg = static_cast<int>(segment);
    if (bone_at(warp_.bone_maps_.data() + 12 * k_seg, double(i), double(j), double(k)) == k_seg) overlap(k_seg);
  }
  if (o >= 0 || (o <= -2 && o != kNoSample)) {
    const int still = bone_at(warp_.background_map_, double(i), double(j), double(k));
    if (still >= 0 && !bone_moves_[static_cast<size_t>(still)]) overlap(still);
  }
  if (claimed >= 0) {
    o = kBoneOwner + claimed;
    ++stats.bone_voxels;
  }
}

// The moving bones whose posed box meets row (j, k): (segment, first i, last i), the i narrowed to where the bone's
// map takes the row into the bone's source box (a thin bone turned fills little of its posed box).
inline void TetWarp::Builder::bones_on_row(int64_t j, int64_t k, std::vector<std::array<int64_t, 3>>& row_bones) const {
  row_bones.clear();
  for (int seg = 0; seg < segment_count_; ++seg) {
    const std::array<double, 6>& box = bone_box_[static_cast<size_t>(seg)];
    if (!bone_moves_[static_cast<size_t>(seg)] || double(j) < box[1] || double(j) > box[4] || double(k) < box[2] ||
        double(k) > box[5]) {
      continue;
    }
    double lo = std::max(0.0, fast_ceil(box[0])), hi = std::min(double(n_[0] - 1), fast_floor(box[3]));
    if (!row_in_source_box(warp_.bone_maps_.data() + 12 * seg, j, k, in_.bones->voxels->box[static_cast<size_t>(seg)],
                           lo, hi)) {
      continue;
    }
    row_bones.push_back({seg, static_cast<int64_t>(lo), static_cast<int64_t>(hi)});
  }
}

// Narrows [lo, hi] (whole i) to the voxels of output row (j, k) that `map` may take into the source index box
// (i0, j0, k0, i1, j1, k1): those whose source index rounds into it, give or take a voxel, so that no voxel
// bone_at() would find in the box is dropped. False when none is left.
inline bool TetWarp::Builder::row_in_source_box(const double* map, int64_t j, int64_t k,
                                                const std::array<int64_t, 6>& box, double& lo, double& hi) {
  double start[3];
  apply_map(map, 0.0, double(j), double(k), start);
  for (int a = 0; a < 3; ++a) {
    const double step = map[3 * a];
    const double low = double(box[static_cast<size_t>(a)]) - 1.5, high = double(box[static_cast<size_t>(a + 3)]) + 1.5;
    if (std::abs(step) < 1e-9) {
      if (!(start[a] >= low && start[a] <= high)) return false;  // the whole row is off the box along a
      continue;
    }
    const double at_low = (low - start[a]) / step, at_high = (high - start[a]) / step;
    lo = std::max(lo, fast_floor(std::max(std::min(at_low, at_high), -1e9)) - 1.0);
    hi = std::min(hi, fast_ceil(std::min(std::max(at_low, at_high), 1e9)) + 1.0);
  }
  return lo <= hi;
}

// Pass 3 over slab s, classify every voxel. Without a rest owner: covered, shell or background. With one, a voxel
// the moving tets left alone maps through the background transform to a source voxel whose rest owner says what it
// is: a tet that follows the background (covered, or its shell), nothing (background), or a moving tet (the body
// moved away from there: the shell of a moving tet, or nothing to sample). Then the bones claim their voxels, ahead
// of any tet.
void TetWarp::Builder::classify_slab(int64_t s) {
  int64_t kb = 0, ke = 0;
  if (!slab_range(s, kb, ke)) return;
  const int64_t slab_begin = kb * n_[0] * n_[1];
  // The voxels pass 1 found folded, in order (a voxel is listed once per pair of tets that disagree on it).
  std::vector<int64_t>& conflicts = conflicts_[static_cast<size_t>(s)];
  std::sort(conflicts.begin(), conflicts.end());
  conflicts.erase(std::unique(conflicts.begin(), conflicts.end()), conflicts.end());
  size_t next_conflict = 0;
  WarpStats& stats = slab_stats_[static_cast<size_t>(s)];
  const bool guard_contacts = in_.bones && in_.bones->region && in_.bones->tet_region && in_.bones->separated;
  std::vector<std::array<int64_t, 3>> row_bones;
  const std::vector<std::pair<int64_t, int32_t>>& found = shells_[static_cast<size_t>(s)];
  size_t next_shell = 0;
  const double* bg = warp_.background_map_;
  for (int64_t k = kb; k < ke; ++k) {
    for (int64_t j = 0; j < n_[1]; ++j) {
      bones_on_row(j, k, row_bones);
      const int64_t row_begin = in_.output.offset(0, j, k);
      const int64_t local_begin = row_begin - slab_begin;
      // Where the background map runs along one source row (the root does not move and the grid is the input's),
      // a row's rest owners are one row of rest_owner.
      double row[3];
      // The rest owners at source x = i + x0 for this output row: rest_span[x - span_lo] for x in [span_lo,
      // span_hi), -1 elsewhere.
      const int32_t* rest_span = nullptr;
      int64_t x0 = 0, y = 0, z = 0, span_lo = 0, span_hi = 0;
      const bool fast = along_source_row(bg, double(j), double(k), row, x0, y, z) && in_.rest_owner;
      if (fast && y >= 0 && z >= 0 && y < in_.source.size[1] && z < in_.source.size[2]) {
        rest_span = in_.rest_owner->row(y, z, span_lo, span_hi);
      }
      // The moving bones' reach on this row: outside it, and off the shell, a voxel no moving tet covers is
      // classified by its rest owner alone (no fold, no contact to guard, no bone to claim).
      int64_t bones_lo = n_[0], bones_hi = -1;
      for (const auto& [segment, i0, i1] : row_bones)
        bones_lo = std::min(bones_lo, i0), bones_hi = std::max(bones_hi, i1);
      for (int64_t i = 0; i < n_[0]; ++i) {
        const int64_t local = local_begin + i;
        int32_t& o = owner_[row_begin + i];
        if (o == -1 && in_.rest_owner && (i < bones_lo || i > bones_hi) &&
            (next_shell >= found.size() || found[next_shell].first != local)) {
          // This voxel and those after it up to the next that needs more than its rest owner (a moving tet covers
          // it, a moving bone reaches it, or it is in the shell), in one loop.
          const int64_t shell_at = next_shell < found.size() ? found[next_shell].first - local_begin : n_[0];
          const int64_t stop = std::min({n_[0], shell_at, i < bones_lo ? bones_lo : n_[0]});
          i = (fast ? classify_uncovered_run(owner_ + row_begin, i, stop, x0, rest_span, span_lo, span_hi, stats)
                    : classify_uncovered_mapped(owner_ + row_begin, i, stop, row, stats)) -
              1;
          continue;
        }
        int32_t shell_owner = -1;
        if (next_shell < found.size() && found[next_shell].first == local) shell_owner = found[next_shell++].second;
        // Folded voxels are covered by a moving tet, never on the fast path: every one is reached here.
        uint8_t conflicted = 0;
        if (next_conflict < conflicts.size() && conflicts[next_conflict] == local) {
          conflicted = 1;
          ++next_conflict;
        }
        if (!in_.rest_owner) {
          classify_alone(o, shell_owner, stats);
        } else {
          int32_t ro = -1;
          if (fast) {
            const int64_t x = x0 + i;
            if (x >= span_lo && x < span_hi) ro = rest_span[x - span_lo];
          } else {
            const double di = double(i);
            const double sb[3] = {row[0] + di * bg[0], row[1] + di * bg[3], row[2] + di * bg[6]};
            ro = rest_owner_at(sb);
          }
          classify_by_rest_owner(o, ro, shell_owner, i, j, k, conflicted, stats);
        }
        stats.conflicted_voxels += conflicted;
        if (guard_contacts) guard_contact(o, i, j, k, stats);
        if (segment_count_ > 0) claim_bone(o, i, j, k, row_bones, stats);
      }
      // The row's span for the packed owners, while the row is in the cache: where its owners differ from -1.
      if (!owner_spans_.empty()) {
        int64_t lo = 0, hi = 0;
        row_span(owner_ + row_begin, n_[0], -1, lo, hi);
        owner_spans_[static_cast<size_t>(j + n_[1] * k)] = static_cast<uint32_t>(lo) | static_cast<uint32_t>(hi) << 16;
      }
    }
  }
  std::vector<int64_t>().swap(conflicts);
  progress_->advance(1, 2 * slab_count_);
}

// classify_uncovered for voxels i.. of an output row (`row`: their owners) up to `stop` or the first that a moving
// tet covers, whose rest owners are span[x0 + i - lo] where x0 + i is in [lo, hi) (a source row's span), -1 elsewhere.
// Returns where it stopped.
inline int64_t TetWarp::Builder::classify_uncovered_run(int32_t* row, int64_t i, int64_t stop, int64_t x0,
                                                        const int32_t* span, int64_t lo, int64_t hi,
                                                        WarpStats& stats) const {
  for (; i < stop && row[i] == -1; ++i) {
    const int64_t x = x0 + i;
    classify_uncovered(row[i], x >= lo && x < hi ? span[x - lo] : -1, stats);
  }
  return i;
}

// The same where the background map does not run along a source row (the root moved): each voxel's rest owner is
// looked up where the map takes it, `start` being the map at i = 0.
inline int64_t TetWarp::Builder::classify_uncovered_mapped(int32_t* row, int64_t i, int64_t stop, const double start[3],
                                                           WarpStats& stats) const {
  const double* bg = warp_.background_map_;
  const double step[3] = {bg[0], bg[3], bg[6]};
  const RowPacked<int32_t>& rest_owner = *in_.rest_owner;  // filled with "no tet", as the source's voxels off the grid
  // A turned map crosses a source row every few voxels, and each crossing may miss the cache: the voxels are taken
  // a batch at a time, their rest owners fetched in a loop of independent loads, so that the misses overlap.
  constexpr int64_t kBatch = 32;
  int32_t ro[kBatch];
  while (i < stop) {
    const int64_t n = std::min(kBatch, stop - i);
    int64_t lo[3], hi[3];
    if (lookup_box(start, step, i, i + n - 1, lo, hi), rest_owner.only_fill(lo, hi)) {
      // The batch lands off the body (its source rows' spans): no tet there, nothing to load.
      for (const int64_t batch_end = i + n; i < batch_end; ++i) {
        if (row[i] != -1) return i;
        classify_uncovered(row[i], -1, stats);
      }
      continue;
    }
    int64_t c = 0;
#if defined(__x86_64__)
    if (wide_source_lookup_ && !rest_owner.rows().empty()) c = rest_owners_avx2(rest_owner, start, step, i, n, ro);
#endif
    for (; c < n; ++c) {
      const double di = double(i + c);
      const double sb[3] = {start[0] + di * step[0], start[1] + di * step[1], start[2] + di * step[2]};
      ro[c] = rest_owner_at(sb);
    }
    for (c = 0; c < n; ++c, ++i) {
      if (row[i] != -1) return i;
      classify_uncovered(row[i], ro[c], stats);
    }
  }
  return i;
}

// classify_by_rest_owner for a voxel that no moving tet covers and no shell reaches.
inline void TetWarp::Builder::classify_uncovered(int32_t& o, int32_t ro, WarpStats& stats) const {
  int32_t rt = ro >= 0 ? ro : (ro <= -2 && ro != kNoSample) ? -2 - ro : -1;
  if (rt >= in_.rest.tet_count()) ro = rt = -1;
  if (rt >= 0 && !moving_[static_cast<size_t>(rt)]) {
    ++(ro >= 0 ? stats.covered_voxels : stats.extrapolated_voxels);  // o stays -1
  } else {
    o = rt < 0 ? -1 : kNoSample;
    ++stats.background_voxels;
  }
}

// A voxel whose background map lands on a source voxel with rest owner code `ro`.
inline void TetWarp::Builder::classify_by_rest_owner(int32_t& o, int32_t ro, int32_t shell_owner, int64_t i, int64_t j,
                                                     int64_t k, uint8_t& conflicted, WarpStats& stats) const {
  if (ro == kNoSample) ro = -1;
  int32_t rt = ro >= 0 ? ro : ro <= -2 ? -2 - ro : -1;  // the rest tet behind that code
  if (rt >= in_.rest.tet_count()) ro = rt = -1;         // not a tet of this mesh: as if nothing held the voxel
  const bool still = rt >= 0 && !moving_[static_cast<size_t>(rt)];
  if (o >= 0) {
    // A moving tet covers it; a tet that follows the background may cover it too (a fold).
    if (ro >= 0 && still &&
        wins(warp_.background_map_, ro, warp_.maps_.get() + 12 * o, warp_.tets_[static_cast<size_t>(o)], double(i),
             double(j), double(k), conflicted)) {
      o = -1;
    }
    ++stats.covered_voxels;
  } else if (still) {
    o = -1;
    ++(ro >= 0 ? stats.covered_voxels : stats.extrapolated_voxels);
  } else if (shell_owner >= 0) {
    o = -2 - shell_owner;
    ++stats.extrapolated_voxels;
  } else {
    o = rt < 0 ? -1 : kNoSample;
    ++stats.background_voxels;
  }
}

}  // namespace posewarp::resample
