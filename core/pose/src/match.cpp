// Posture matching: bone surfaces aligned segment by segment down the kinematic tree.
#include "posewarp/pose/match.h"

#include <Eigen/Geometry>
#include <Eigen/SVD>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <initializer_list>
#include <limits>
#include <map>
#include <optional>
#include <unordered_map>

#include "posewarp/rig/anatomical_frame.h"

namespace posewarp::pose {
namespace {

using Eigen::Matrix3d;
using Eigen::Vector3d;
using Points = std::vector<Vector3d>;

constexpr double kDegrees = 180.0 / M_PI;
// A limb bone whose centroid lies nearer its joint than this is a stump the scan cut off.
constexpr double kStumpMm = 50.0;

// Each label value's segment (-1: none), for the one pass over a volume.
class SegmentOf {
 public:
  explicit SegmentOf(const std::vector<std::vector<Label>>& labels_of_segment) {
    for (size_t s = 0; s < labels_of_segment.size(); ++s) {
      for (Label l : labels_of_segment[s]) {
        if (l >= 0 && l < kDense) {
          if (dense_.size() <= static_cast<size_t>(l)) dense_.resize(static_cast<size_t>(l) + 1, -1);
          dense_[static_cast<size_t>(l)] = static_cast<int>(s);
        } else {
          sparse_[l] = static_cast<int>(s);
        }
      }
    }
  }
  int operator()(Label l) const {
    if (l >= 0 && static_cast<size_t>(l) < dense_.size()) return dense_[static_cast<size_t>(l)];
    if (l >= 0 && l < kDense) return -1;
    const auto it = sparse_.find(l);
    return it == sparse_.end() ? -1 : it->second;
  }

 private:
  static constexpr Label kDense = 1 << 16;
  std::vector<int> dense_;
  std::unordered_map<Label, int> sparse_;
};

// What the match needs of one bone in one volume: its voxel count, centroid and surface voxels (LPS mm).
struct Bone {
  int64_t voxels = 0;
  Vector3d centroid = Vector3d::Zero();
  Points surface;
};

// Every segment's bone in `volume` in one pass: a voxel is on the surface when a face neighbour is not of its segment
// (or lies outside the grid). At most `max_points` surface voxels per segment, evenly spaced in scan order.
std::vector<Bone> bones_of(const LabelVolume& volume, const SegmentOf& segment_of, size_t segments, size_t max_points) {
  const ImageGeometry& g = volume.geometry();
  const int64_t nx = g.size[0], ny = g.size[1], nz = g.size[2];
  std::vector<Vector3d> index_sum(segments, Vector3d::Zero());
  std::vector<std::vector<int64_t>> surface(segments);
  std::vector<Bone> bones(segments);
  const Label* v = volume.data();
  for (int64_t k = 0; k < nz; ++k) {
    for (int64_t j = 0; j < ny; ++j) {
      for (int64_t i = 0; i < nx; ++i) {
        const int64_t at = i + nx * (j + ny * k);
        const int s = segment_of(v[at]);
        if (s < 0) continue;
        Bone& b = bones[static_cast<size_t>(s)];
        ++b.voxels;
        index_sum[static_cast<size_t>(s)] +=
            Vector3d(static_cast<double>(i), static_cast<double>(j), static_cast<double>(k));
        const bool inside = i > 0 && j > 0 && k > 0 && i + 1 < nx && j + 1 < ny && k + 1 < nz;
        const bool on_surface = !inside || segment_of(v[at - 1]) != s || segment_of(v[at + 1]) != s ||
                                segment_of(v[at - nx]) != s || segment_of(v[at + nx]) != s ||
                                segment_of(v[at - nx * ny]) != s || segment_of(v[at + nx * ny]) != s;
        if (on_surface) surface[static_cast<size_t>(s)].push_back(at);
      }
    }
  }
  for (size_t s = 0; s < segments; ++s) {
    Bone& b = bones[s];
    if (b.voxels == 0) continue;
    const Vector3d mean = index_sum[s] / static_cast<double>(b.voxels);
    const Vec3 c = g.index_to_physical({mean.x(), mean.y(), mean.z()});
    b.centroid = Vector3d(c[0], c[1], c[2]);
    const std::vector<int64_t>& all = surface[s];
    const size_t step = std::max<size_t>(1, (all.size() + max_points - 1) / std::max<size_t>(1, max_points));
    for (size_t n = 0; n < all.size(); n += step) {
      const int64_t at = all[n];
      const Vec3 p = g.index_to_physical(
          {static_cast<double>(at % nx), static_cast<double>((at / nx) % ny), static_cast<double>(at / (nx * ny))});
      b.surface.emplace_back(p[0], p[1], p[2]);
    }
  }
  return bones;
}

// Nearest points among a fixed set, on a grid of cells searched ring by ring out to a limit.
class NearestGrid {
 public:
  NearestGrid(const Points& points, double cell) : points_(points), cell_(cell) {
    for (size_t n = 0; n < points.size(); ++n) cells_[key(cell_of(points[n]))].push_back(static_cast<int>(n));
  }
  // The nearest point's index and distance; -1 when none lies within `rings` cells.
  std::pair<int, double> nearest(const Vector3d& q, int rings = 12) const {
    const Eigen::Vector3i c = cell_of(q);
    int best = -1;
    double best_d2 = std::numeric_limits<double>::infinity();
    for (int r = 0; r <= rings; ++r) {
      for (int dz = -r; dz <= r; ++dz) {
        for (int dy = -r; dy <= r; ++dy) {
          for (int dx = -r; dx <= r; ++dx) {
            if (std::max({std::abs(dx), std::abs(dy), std::abs(dz)}) != r) continue;  // this ring's shell only
            const auto it = cells_.find(key(c + Eigen::Vector3i(dx, dy, dz)));
            if (it == cells_.end()) continue;
            for (int n : it->second) {
              const double d2 = (points_[static_cast<size_t>(n)] - q).squaredNorm();
              if (d2 < best_d2) best_d2 = d2, best = n;
            }
          }
        }
      }
      // Points in the next ring lie at least r cells away.
      if (best >= 0 && std::sqrt(best_d2) <= static_cast<double>(r) * cell_) break;
    }
    return {best, std::sqrt(best_d2)};
  }

 private:
  Eigen::Vector3i cell_of(const Vector3d& p) const {
    return {static_cast<int>(std::floor(p.x() / cell_)), static_cast<int>(std::floor(p.y() / cell_)),
            static_cast<int>(std::floor(p.z() / cell_))};
  }
  static int64_t key(const Eigen::Vector3i& c) {
    return (static_cast<int64_t>(c.x()) & 0x1FFFFF) | (static_cast<int64_t>(c.y()) & 0x1FFFFF) << 21 |
           (static_cast<int64_t>(c.z()) & 0x1FFFFF) << 42;
  }
  const Points& points_;
  double cell_;
  std::unordered_map<int64_t, std::vector<int>> cells_;
};

// The rotation closest to `h` = sum of p q^T in the least-squares sense (Kabsch: a proper rotation).
Matrix3d kabsch(const Matrix3d& h) {
  const Eigen::JacobiSVD<Matrix3d> svd(h, Eigen::ComputeFullU | Eigen::ComputeFullV);
  Matrix3d d = Matrix3d::Identity();
  d(2, 2) = (svd.matrixV() * svd.matrixU().transpose()).determinant() < 0 ? -1.0 : 1.0;
  return svd.matrixV() * d * svd.matrixU().transpose();
}

// The rotation about `axis` (unit) taking the vectors `from` closest to `to` (each pair about the same point).
Matrix3d best_turn_about(const Vector3d& axis, const Points& from, const Points& to) {
  double sine = 0, cosine = 0;
  for (size_t n = 0; n < from.size(); ++n) {
    const Vector3d p = from[n] - axis * axis.dot(from[n]), q = to[n] - axis * axis.dot(to[n]);
    sine += axis.dot(p.cross(q));
    cosine += p.dot(q);
  }
  return Eigen::AngleAxisd(std::atan2(sine, cosine), axis).toRotationMatrix();
}

// A joint's range in angles relative to the rig's rest (AnatomicalRange less the rest posture's own angles).
struct Limits {
  Vector3d min_deg, max_deg;
};

// How a segment may move: freely (the root), about a point (a ball or plane joint), about an axis through a point;
// a joint with `limits` within them. A hinge's match starts with the turn about its axis.
struct Freedom {
  bool translate = false;
  Vector3d centre = Vector3d::Zero();
  bool hinge = false;
  bool start_about_axis = false;
  Vector3d axis = Vector3d::UnitX();
  const rig::Joint* joint = nullptr;
  std::optional<Limits> limits;
};

double wrapped_deg(double degrees) {
  const double d = std::remainder(degrees, 360.0);
  return d <= -180.0 ? d + 360.0 : d;
}

// How far `angles` lie outside `limits`, summed over the motions.
double excess(const Vector3d& angles, const Limits& limits) {
  return (limits.min_deg - angles).cwiseMax(0.0).sum() + (angles - limits.max_deg).cwiseMax(0.0).sum();
}

// A joint's turn kept within limits, its angles, and what was clamped.
struct Limited {
  Matrix3d rotation;
  Vector3d angles_deg;
  std::string held;
};

// Of a turn's two angle triples, (a, b, c) and (a + 180, 180 - b, c + 180), the one nearer `limits`.
Vector3d nearer_angles_deg(const rig::Joint& joint, const Matrix3d& rotation, const Limits& limits) {
  const Vector3d first = anatomical_angles_deg(joint, rotation);
  const Vector3d second(wrapped_deg(first.x() + 180.0), wrapped_deg(180.0 - first.y()), wrapped_deg(first.z() + 180.0));
  return excess(second, limits) < excess(first, limits) ? second : first;
}

// A turn's angles as people read them: for a limb joint the triple nearer its anatomical range.
Vector3d readable_angles_deg(const rig::Joint& joint, const Matrix3d& rotation) {
  const std::optional<AnatomicalRange> range = anatomical_range(joint.name);
  return range ? nearer_angles_deg(joint, rotation, Limits{range->min_deg, range->max_deg})
               : anatomical_angles_deg(joint, rotation);
}

// A joint's turn read as anatomical angles (the triple nearer the limits) and clamped into them; `held` names what
// was clamped, as "flexion 171.3 held at 150.0".
Limited within_limits(const rig::Joint& joint, const Matrix3d& rotation, const Limits& limits) {
  Limited out{rotation, nearer_angles_deg(joint, rotation, limits), ""};
  const Vector3d clamped = out.angles_deg.cwiseMax(limits.min_deg).cwiseMin(limits.max_deg);
  static constexpr const char* kMotions[] = {"flexion", "abduction", "rotation"};
  for (int m = 0; m < 3; ++m) {
    if (std::abs(clamped[m] - out.angles_deg[m]) < 1e-9) continue;
    char words[96];
    std::snprintf(words, sizeof words, "%s%s %.1f held at %.1f", out.held.empty() ? "" : ", ", kMotions[m],
                  out.angles_deg[m], clamped[m]);
    out.held += words;
  }
  if (!out.held.empty()) {
    out.rotation = rig::joint_rotation_from_angles(joint, clamped.x(), clamped.y(), clamped.z());
    out.angles_deg = clamped;
  }
  return out;
}

// A segment's points paired with the target bone's nearest points, those beyond three times the median distance
// left out; the distances of all pairs in `distances`.
struct Pairs {
  Points from, to;
  std::vector<double> distances;
};

// Whether `x` (LPS mm) lies within `grid`'s field of view: a scan says nothing of a bone beyond it.
bool in_view(const ImageGeometry& grid, const Vector3d& x) {
  const Vec3 index = grid.physical_to_index({x.x(), x.y(), x.z()});
  for (size_t a = 0; a < 3; ++a) {
    if (index[a] < -0.5 || index[a] > static_cast<double>(grid.size[a]) - 0.5) return false;
  }
  return true;
}

// The target bone a match looks for: its nearest-point grid, its points, and the field of view they were seen in.
struct TargetBone {
  const NearestGrid& nearest;
  const Points& points;
  const ImageGeometry& view;
};

Pairs pair_up(const Points& points, const RigidTransform& placed, const TargetBone& target, double floor_mm) {
  Pairs pairs;
  std::vector<std::pair<Vector3d, int>> found;
  for (const Vector3d& p : points) {
    const Vector3d x = placed.apply(p);
    if (!in_view(target.view, x)) continue;  // beyond the target's field of view: nothing to meet
    const auto [n, d] = target.nearest.nearest(x);
    if (n < 0) continue;
    found.emplace_back(p, n);
    pairs.distances.push_back(d);
  }
  if (found.empty()) return pairs;
  std::vector<double> sorted = pairs.distances;
  std::nth_element(sorted.begin(), sorted.begin() + static_cast<long>(sorted.size() / 2), sorted.end());
  const double limit = std::max(3.0 * sorted[sorted.size() / 2], floor_mm);
  for (size_t n = 0; n < found.size(); ++n) {
    if (pairs.distances[n] > limit) continue;
    pairs.from.push_back(found[n].first);
    pairs.to.push_back(target.points[static_cast<size_t>(found[n].second)]);
  }
  return pairs;
}

// What aligning a segment found: its own motion (in its parent's rest frame), the ICP iterations it took, and for a
// joint with limits its angles and what the limits held back in the last iteration.
struct Aligned {
  RigidTransform own;
  int iterations = 0;
  std::optional<Vector3d> angles_deg;
  std::string held;
};

// ICP of `points` (rest) onto the target bone, moving only as `freedom` allows (each step's turn kept within the
// joint's limits), after `parent` (the transform of the segment's parent; identity for the root) and from `start`
// (the segment's own motion in its parent's rest frame).
Aligned align(const Points& points, const RigidTransform& parent, RigidTransform start, const Freedom& freedom,
              const TargetBone& target, double floor_mm, int max_iterations) {
  const RigidTransform back = parent.inverse();
  Aligned out;
  RigidTransform& own = out.own;
  own = start;
  int n = 0;
  for (; n < max_iterations; ++n) {
    const Pairs pairs = pair_up(points, parent * own, target, floor_mm);
    if (pairs.from.size() < 3) break;
    // The target's points in the parent's rest frame, where the segment's own motion acts.
    Points to(pairs.to.size());
    for (size_t m = 0; m < to.size(); ++m) to[m] = back.apply(pairs.to[m]);
    RigidTransform next;
    if (freedom.translate) {
      Vector3d from_mean = Vector3d::Zero(), to_mean = Vector3d::Zero();
      for (size_t m = 0; m < to.size(); ++m) from_mean += pairs.from[m], to_mean += to[m];
      from_mean /= static_cast<double>(to.size());
      to_mean /= static_cast<double>(to.size());
      Matrix3d h = Matrix3d::Zero();
      for (size_t m = 0; m < to.size(); ++m) h += (pairs.from[m] - from_mean) * (to[m] - to_mean).transpose();
      next.rotation = kabsch(h);
      next.translation = to_mean - next.rotation * from_mean;
    } else {
      Points from_c(to.size()), to_c(to.size());
      for (size_t m = 0; m < to.size(); ++m)
        from_c[m] = pairs.from[m] - freedom.centre, to_c[m] = to[m] - freedom.centre;
      Matrix3d rotation;
      if (freedom.hinge) {
        rotation = best_turn_about(freedom.axis, from_c, to_c);
      } else {
        Matrix3d h = Matrix3d::Zero();
        for (size_t m = 0; m < to.size(); ++m) h += from_c[m] * to_c[m].transpose();
        rotation = kabsch(h);
      }
      if (freedom.limits) {
        Limited limited = within_limits(*freedom.joint, rotation, *freedom.limits);
        rotation = limited.rotation;
        out.angles_deg = limited.angles_deg;
        out.held = std::move(limited.held);
      }
      next = RigidTransform::about(rotation, freedom.centre);
    }
    const double turn = Eigen::AngleAxisd(next.rotation * own.rotation.transpose()).angle();
    const double shift = (next.translation - own.translation).norm();
    own = next;
    if (turn < 1e-5 && shift < 1e-4) {
      ++n;
      break;
    }
  }
  out.iterations = n;
  return out;
}

// The start of a child's match: the turn about its joint that takes the direction to its rest centroid onto the
// direction to the target bone's centroid (in the parent's rest frame), about the hinge axis for a hinge.
RigidTransform initial_turn(const Bone& rest, const Bone& target, const RigidTransform& parent, const Freedom& f) {
  const Vector3d from = rest.centroid - f.centre, to = parent.inverse().apply(target.centroid) - f.centre;
  if (from.norm() < 5.0 || to.norm() < 5.0) return RigidTransform::identity();
  const Matrix3d rotation = f.start_about_axis ? best_turn_about(f.axis, {from}, {to})
                                : Eigen::Quaterniond::FromTwoVectors(from, to).toRotationMatrix();
  return RigidTransform::about(rotation, f.centre);
}

// `f(segment, place in LPS mm)` for every voxel of `volume` whose segment was matched.
template <typename F>
void each_bone_voxel(const LabelVolume& volume, const SegmentOf& segment_of, const std::vector<SegmentMatch>& matches,
                     F f) {
  const ImageGeometry& g = volume.geometry();
  const Label* v = volume.data();
  for (int64_t k = 0; k < g.size[2]; ++k) {
    for (int64_t j = 0; j < g.size[1]; ++j) {
      for (int64_t i = 0; i < g.size[0]; ++i) {
        const int s = segment_of(v[i + g.size[0] * (j + g.size[1] * k)]);
        if (s < 0 || !matches[static_cast<size_t>(s)].matched) continue;
        const Vec3 x = g.index_to_physical({static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)});
        f(s, Vector3d(x[0], x[1], x[2]));
      }
    }
  }
}

// The segments' Dice overlap with the target bones on the target's grid: a target bone voxel is in the moved segment
// when its place moved back to rest is a voxel of that segment; the moved segment's size is its rest voxels that
// land on the target's grid, scaled by the voxels' volumes.
void dice(const LabelVolume& rest, const SegmentOf& rest_segment, const LabelVolume& target,
          const SegmentOf& target_segment, const std::vector<RigidTransform>& placed,
          const std::vector<Bone>& target_bones, std::vector<SegmentMatch>& out) {
  const ImageGeometry &t = target.geometry(), &r = rest.geometry();
  std::vector<RigidTransform> back(placed.size());
  for (size_t s = 0; s < placed.size(); ++s) back[s] = placed[s].inverse();
  std::vector<int64_t> both(placed.size(), 0), on_grid(placed.size(), 0);
  // A target bone voxel moved back to rest: a voxel of its segment there?
  each_bone_voxel(target, target_segment, out, [&](int s, const Vector3d& x) {
    const Vector3d at = back[static_cast<size_t>(s)].apply(x);
    const Vec3 index = r.physical_to_index({at.x(), at.y(), at.z()});
    const int64_t ri = std::lround(index[0]), rj = std::lround(index[1]), rk = std::lround(index[2]);
    if (ri < 0 || rj < 0 || rk < 0 || ri >= r.size[0] || rj >= r.size[1] || rk >= r.size[2]) return;
    both[static_cast<size_t>(s)] += rest_segment(rest.at(ri, rj, rk)) == s;
  });
  // The moved segment counts where it lands on the target's grid (a bone the target's field of view cuts is
  // compared within that field).
  each_bone_voxel(rest, rest_segment, out, [&](int s, const Vector3d& x) {
    on_grid[static_cast<size_t>(s)] += in_view(t, placed[static_cast<size_t>(s)].apply(x));
  });
  const double scale = (r.spacing[0] * r.spacing[1] * r.spacing[2]) / (t.spacing[0] * t.spacing[1] * t.spacing[2]);
  for (size_t s = 0; s < placed.size(); ++s) {
    if (!out[s].matched) continue;
    const double moved = static_cast<double>(on_grid[s]) * scale;
    out[s].dice = 2.0 * static_cast<double>(both[s]) / (moved + static_cast<double>(target_bones[s].voxels));
  }
}

// The motions whose found angle lies past the joint's measured range, in words ("" when none). The ranges are measured
// in 5-degree steps (api::RangeParams): an angle counts as past only beyond the step after the last one that fitted.
std::string beyond_range(const rig::Joint& joint, const Vector3d& angles_deg) {
  constexpr double kStepDeg = 5.0;
  std::string out;
  for (const MotionRange& range : joint.ranges) {
    const double angle = range.motion == "flexion" ? angles_deg.x() : range.motion == "abduction" ? angles_deg.y() : 0;
    const bool below = angle < -range.negative_deg - kStepDeg, above = angle > range.positive_deg + kStepDeg;
    if (!below && !above) continue;
    char words[160];
    std::snprintf(words, sizeof words, "%s%s %.1f past %.0f%s", out.empty() ? "" : ", ", range.motion.c_str(), angle,
                  below ? -range.negative_deg : range.positive_deg,
                  (below ? range.negative_stopped : range.positive_stopped) ? " (bones meet)" : "");
    out += words;
  }
  return out;
}

}  // namespace

std::optional<AnatomicalRange> anatomical_range(const std::string& joint) {
  // flexion, abduction, internal rotation: min and max. Flexion and abduction are positive as the pose files have
  // them (flexion forward at shoulder and hip, bending at elbow and knee; abduction away from the midline); where a
  // sign differs between sides or rigs (the wrist's deviation, the ankle's flexion) the range is the wider side's
  // both ways.
  struct Row {
    const char* name;
    double min[3], max[3];
  };
  static constexpr Row kRanges[] = {
      {"shoulder", {-60, -50, -90}, {180, 180, 90}}, {"elbow", {-10, -20, -90}, {150, 20, 90}},
      {"wrist", {-80, -35, -30}, {80, 35, 30}},      {"hip", {-30, -30, -45}, {125, 50, 45}},
      {"knee", {-10, -15, -40}, {150, 15, 40}},      {"ankle", {-50, -35, -30}, {50, 35, 30}},
  };
  const std::string first = joint.substr(0, joint.find('_'));
  for (const Row& row : kRanges) {
    if (first == row.name) {
      return AnatomicalRange{Vector3d(row.min[0], row.min[1], row.min[2]),
                             Vector3d(row.max[0], row.max[1], row.max[2])};
    }
  }
  return std::nullopt;
}

Eigen::Vector3d anatomical_angles_deg(const rig::Joint& joint, const Eigen::Matrix3d& rotation_lps) {
  // R = Rx(a) Ry(b) Rz(s c): R(0,2) = sin b, R(1,2) = -sin a cos b, R(2,2) = cos a cos b, R(0,1) = -cos b sin(s c),
  // R(0,0) = cos b cos(s c).
  const Matrix3d r = joint.frame.transpose() * rotation_lps * joint.frame;
  const double a = std::atan2(-r(1, 2), r(2, 2));
  const double b = std::asin(std::clamp(r(0, 2), -1.0, 1.0));
  const double c = std::atan2(-r(0, 1), r(0, 0));
  return Vector3d(a, b, joint.internal_rotation_sign * c) * kDegrees;
}

Result<MatchResult> match_posture(const rig::Skeleton& skeleton, const LabelVolume& rest, const LabelVolume& target,
                                  const std::vector<std::vector<Label>>& target_labels, const MatchOptions& options) {
  const size_t count = skeleton.segments.size();
  if (target_labels.size() != count) {
    return invalid_argument_error("the target's labels name " + std::to_string(target_labels.size()) +
                                  " segments; the rig has " + std::to_string(count));
  }
  if (skeleton.root < 0 || static_cast<size_t>(skeleton.root) >= count) {
    return invalid_argument_error("the rig's skeleton has no root segment");
  }
  std::vector<std::vector<Label>> rest_labels;
  for (const rig::Segment& s : skeleton.segments) rest_labels.push_back(s.labels);
  const SegmentOf rest_segment(rest_labels), target_segment(target_labels);
  const size_t max_points = static_cast<size_t>(std::max(10, options.max_points));
  const std::vector<Bone> rest_bones = bones_of(rest, rest_segment, count, max_points);
  // The target's surface voxels all take part: they are what the rest points look for.
  const std::vector<Bone> target_bones = bones_of(target, target_segment, count, size_t{1} << 40);
  const size_t root = static_cast<size_t>(skeleton.root);
  const std::string root_name = skeleton.segments[root].name;
  if (rest_bones[root].voxels == 0 || target_bones[root].voxels == 0) {
    return invalid_argument_error("the root segment '" + root_name + "' is missing from the " +
                                  (rest_bones[root].voxels == 0 ? "rig's" : "target's") +
                                  " labels: there is nothing to place the body by");
  }
  const ImageGeometry& tg = target.geometry();
  // Cells of about two voxels; pairs are never left out for lying within a voxel or so of each other.
  const double voxel = std::max({tg.spacing[0], tg.spacing[1], tg.spacing[2]});
  const double cell = 2.0 * voxel, floor_mm = 1.5 * voxel;

  MatchResult result;
  result.segments.resize(count);
  const ImageGeometry& rg = rest.geometry();
  const double voxel_ml = rg.spacing[0] * rg.spacing[1] * rg.spacing[2] / 1000.0;
  for (size_t s = 0; s < count; ++s) {
    result.segments[s].segment = skeleton.segments[s].name;
    result.segments[s].volume_ml = static_cast<double>(rest_bones[s].voxels) * voxel_ml;
  }
  std::vector<RigidTransform> placed(count, RigidTransform::identity());
  const auto match_segment = [&](size_t s, const RigidTransform& parent, const Freedom& freedom,
                                 const RigidTransform& start) -> RigidTransform {
    SegmentMatch& m = result.segments[s];
    if (rest_bones[s].voxels == 0 || target_bones[s].voxels == 0) {
      m.skipped = rest_bones[s].voxels == 0 ? "the rig's labels have no voxels of it"
                                            : "the target's labels have no voxels of it";
      return RigidTransform::identity();
    }
    const NearestGrid grid(target_bones[s].surface, cell);
    const TargetBone bone{grid, target_bones[s].surface, tg};
    Aligned aligned = align(rest_bones[s].surface, parent, start, freedom, bone, floor_mm, options.max_iterations);
    const RigidTransform& own = aligned.own;
    m.iterations = aligned.iterations;
    if (freedom.limits) {
      // (A match that stopped before its first step reads its start within the limits.)
      m.angles_deg = aligned.angles_deg ? *aligned.angles_deg
                                        : within_limits(*freedom.joint, own.rotation, *freedom.limits).angles_deg;
      m.held_at_range = std::move(aligned.held);
    }
    // The residual: every surface point of the moved segment within the target's view against the target bone.
    double sum = 0;
    int64_t paired = 0;
    for (const Vector3d& p : rest_bones[s].surface) {
      const Vector3d x = (parent * own).apply(p);
      if (!in_view(tg, x)) continue;
      const auto [n, d] = grid.nearest(x);
      if (n < 0) continue;
      sum += d, ++paired, m.max_distance_mm = std::max(m.max_distance_mm, d);
    }
    m.mean_distance_mm = paired > 0 ? sum / static_cast<double>(paired) : 0.0;
    m.matched = true;
    return own;
  };

  // The root: a rotation and a translation, from the centroids' offset.
  Freedom free;
  free.translate = true;
  RigidTransform start;
  start.translation = target_bones[root].centroid - rest_bones[root].centroid;
  placed[root] = match_segment(root, RigidTransform::identity(), free, start);
  const Vector3d c = skeleton.segments[root].centroid_mm;
  result.pose.root.rotation = placed[root].rotation;
  result.pose.root.translation = placed[root].rotation * c + placed[root].translation - c;
  // The rest posture's own angles at the limb joints (the turn that straightens them, limbs-straight), taken off
  // their anatomical ranges: a scan is rarely in the anatomical position.
  std::map<std::string, Vector3d> straightening;
  if (options.anatomical_ranges) {
    if (Result<Pose> straight = standard_posture(skeleton, "limbs-straight"); straight.ok()) {
      for (const JointRotation& j : straight->joints) straightening[j.joint] = *j.angles_deg;
    }
  }
  // Every joint in order, parents before children: its child turns about the joint's centre.
  for (const rig::Joint& joint : skeleton.joints) {
    if (joint.parent < 0 || joint.child < 0 || static_cast<size_t>(joint.child) >= count) continue;
    const size_t child = static_cast<size_t>(joint.child);
    SegmentMatch& m = result.segments[child];
    m.joint = joint.name;
    Freedom f;
    f.centre = joint.centre_mm;
    f.axis = joint.frame.col(0);
    f.joint = &joint;
    f.start_about_axis = joint.kind == JointKind::kHinge;
    if (const std::optional<AnatomicalRange> range = anatomical_range(joint.name); range && options.anatomical_ranges) {
      const auto it = straightening.find(joint.name);
      const Vector3d offset = it == straightening.end() ? Vector3d::Zero() : it->second;
      f.limits = Limits{range->min_deg + offset, range->max_deg + offset};
    }
    if (joint.kind == JointKind::kHinge && options.constrain_hinges) {
      const double slack = std::max(0.0, options.hinge_slack_deg);
      if (slack == 0.0) {
        f.hinge = true;  // about the axis alone, in closed form
      } else {
        // Within the slack off the axis (and within anatomy's range where it is narrower).
        Limits hinge{Vector3d(-180.0, -slack, -slack), Vector3d(180.0, slack, slack)};
        if (f.limits) {
          hinge.min_deg = hinge.min_deg.cwiseMax(f.limits->min_deg);
          hinge.max_deg = hinge.max_deg.cwiseMin(f.limits->max_deg).cwiseMax(hinge.min_deg);
        }
        f.limits = hinge;
      }
    }
    const RigidTransform& parent = placed[static_cast<size_t>(joint.parent)];
    // (A bone missing from either side is skipped before its start is used.)
    const RigidTransform own =
        match_segment(child, parent, f, initial_turn(rest_bones[child], target_bones[child], parent, f));
    placed[child] = parent * own;
    if (!m.matched) continue;
    if (!f.limits) m.angles_deg = readable_angles_deg(joint, own.rotation);
    m.beyond_range = beyond_range(joint, m.angles_deg);
    JointRotation rotation;
    rotation.joint = joint.name;
    rotation.rotation = Eigen::Quaterniond(joint.frame.transpose() * own.rotation * joint.frame).normalized();
    rotation.angles_deg = m.angles_deg;
    result.pose.joints.push_back(rotation);
  }
  dice(rest, rest_segment, target, target_segment, placed, target_bones, result.segments);
  return result;
}

Result<Pose> standard_posture(const rig::Skeleton& skeleton, const std::string& name) {
  const bool arms_up = name == "arms-up";
  if (name != "limbs-straight" && name != "supine-arms-down" && !arms_up) {
    return invalid_argument_error("there is no standard posture '" + name +
                                  "'; the standard postures are: limbs-straight (or supine-arms-down), arms-up");
  }
  // The joints whose children are limbs, by the joint names rigs use ("shoulder_left", "knee_right", ...).
  const auto starts = [](const std::string& joint, std::initializer_list<const char*> prefixes) {
    for (const char* prefix : prefixes) {
      if (joint.rfind(prefix, 0) == 0) return true;
    }
    return false;
  };
  const Vector3d down(0.0, 0.0, -1.0), up(0.0, 0.0, 1.0);
  const Vector3d middle =
      skeleton.root >= 0 ? skeleton.segments[static_cast<size_t>(skeleton.root)].centroid_mm : Vector3d::Zero();
  Pose pose;
  pose.name = name;
  std::vector<Matrix3d> turned(skeleton.segments.size(), Matrix3d::Identity());  // each segment's rotation
  for (const rig::Joint& joint : skeleton.joints) {
    if (joint.parent < 0 || joint.child < 0) continue;
    const Matrix3d& parent = turned[static_cast<size_t>(joint.parent)];
    Matrix3d own = Matrix3d::Identity();
    // The limb's direction: its frame's long axis, into the child (a child bone the scan cuts off has a frame that
    // hangs down, where a centroid would point along the stump).
    const Vector3d into = skeleton.segments[static_cast<size_t>(joint.child)].centroid_mm - joint.centre_mm;
    const Vector3d from = joint.frame.col(2).dot(into) < 0.0 ? Vector3d(-joint.frame.col(2)) : joint.frame.col(2);
    if (starts(joint.name, {"shoulder", "elbow", "hip", "knee"}) && into.norm() > 1e-6) {
      const bool arm = starts(joint.name, {"shoulder", "elbow"});
      // In the parent's rest frame, where the joint's own turn acts.
      const Vector3d to = parent.transpose() * (arms_up && arm ? up : down);
      if (into.norm() < kStumpMm) {
        // A bone the scan cuts off near its joint (a femoral head at the edge of an abdominal CT) says nothing of
        // where the limb points: left as it is.
      } else if (joint.kind == JointKind::kHinge) {
        own = best_turn_about(joint.frame.col(0), {from}, {to});
      } else {
        // A ball joint turning the limb more than a right angle goes through the side (abducted), the way arms are
        // raised over the head or brought down from it, not through whatever axis the shortest turn picks.
        const Vector3d side = parent.transpose() * Vector3d(joint.centre_mm.x() >= middle.x() ? 1.0 : -1.0, 0, 0);
        own = from.normalized().dot(to) < 0.0 ? Eigen::Quaterniond::FromTwoVectors(side, to).toRotationMatrix() *
                                                    Eigen::Quaterniond::FromTwoVectors(from, side).toRotationMatrix()
                                              : Eigen::Quaterniond::FromTwoVectors(from, to).toRotationMatrix();
      }
      JointRotation rotation;
      rotation.joint = joint.name;
      rotation.rotation = Eigen::Quaterniond(joint.frame.transpose() * own * joint.frame).normalized();
      rotation.angles_deg = readable_angles_deg(joint, own);
      pose.joints.push_back(rotation);
    }
    turned[static_cast<size_t>(joint.child)] = parent * own;
  }
  if (pose.joints.empty()) {
    return invalid_argument_error("the rig has no shoulder, elbow, hip or knee joint: posture '" + name +
                                  "' turns nothing");
  }
  return pose;
}

}  // namespace posewarp::pose
