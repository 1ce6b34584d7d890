// Automatic skeleton: segments from the label map, contact graph weighted by contact area, maximum spanning tree
// from a root, joint centres (contact centroid or sphere fit) and frames, names from the presets.
#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <map>
#include <numeric>
#include <queue>
#include <set>
#include <limits>
#include <unordered_map>

#include "posewarp/rig/skeleton.h"

#include "joint_fit.h"
#include "posewarp/common/tet_mesh.h"
#include "posewarp/rig/anatomical_frame.h"

namespace posewarp::rig {
namespace {

// Contact of segment a with segment b: the voxels of a that lie within the contact distance of b.
struct Contact {
  int64_t count = 0;
  Eigen::Vector3d sum = Eigen::Vector3d::Zero();
  std::vector<Index3> voxels;
  std::vector<float> distance_mm;  // per voxel: to the nearest voxel of b (centre to centre)
};

struct DisjointSets {
  std::vector<int> parent;
  explicit DisjointSets(int n) : parent(static_cast<size_t>(n)) { std::iota(parent.begin(), parent.end(), 0); }
  int find(int v) {
    while (parent[static_cast<size_t>(v)] != v) v = parent[static_cast<size_t>(v)] = parent[static_cast<size_t>(parent[static_cast<size_t>(v)])];
    return v;
  }
  bool unite(int a, int b) {
    a = find(a);
    b = find(b);
    if (a == b) return false;
    parent[static_cast<size_t>(b)] = a;
    return true;
  }
};

Eigen::Vector3d physical(const ImageGeometry& g, int64_t i, int64_t j, int64_t k) {
  const Vec3 p = g.index_to_physical({static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)});
  return {p[0], p[1], p[2]};
}

// The centres of the faces between voxel v of segment s and its 6-neighbours outside s: the bone's boundary at the
// true position of the voxel surface, whatever the spacing (voxel centres would sit half a slice inside the bone).
void add_face_points(const ImageGeometry& g, const std::vector<int16_t>& segment_at, int s, const Index3& v,
                     std::vector<Eigen::Vector3d>& out) {
  static constexpr int kFaces[6][3] = {{-1, 0, 0}, {1, 0, 0}, {0, -1, 0}, {0, 1, 0}, {0, 0, -1}, {0, 0, 1}};
  for (const auto& f : kFaces) {
    const int64_t x = v[0] + f[0], y = v[1] + f[1], z = v[2] + f[2];
    const bool inside = x >= 0 && y >= 0 && z >= 0 && x < g.size[0] && y < g.size[1] && z < g.size[2] &&
                        segment_at[static_cast<size_t>(g.offset(x, y, z))] == s;
    if (inside) continue;
    const Vec3 p = g.index_to_physical({v[0] + 0.5 * f[0], v[1] + 0.5 * f[1], v[2] + 0.5 * f[2]});
    out.emplace_back(p[0], p[1], p[2]);
  }
}

// What placing a joint needs from the skeleton builder.
struct JointPlacement {
  const ImageGeometry& g;
  const labels::LabelMap& map;
  const RigSpec& spec;
  const SkeletonParams& params;
  Skeleton& skeleton;
  const std::vector<int16_t>& segment_at;
  const std::vector<std::vector<Index3>>& surface;
  const std::map<std::pair<int, int>, Contact>& contacts;
  double max_spacing;
  double max_offset;
};

// Face points of segment s's boundary voxels in `voxels`, or of all its boundary voxels within `radius` of `near`.
std::vector<Eigen::Vector3d> face_points(const JointPlacement& at, int s, const std::vector<Index3>& voxels) {
  std::vector<Eigen::Vector3d> points;
  for (const Index3& v : voxels) add_face_points(at.g, at.segment_at, s, v, points);
  return points;
}

std::vector<Eigen::Vector3d> face_points_near(const JointPlacement& at, int s, const Eigen::Vector3d& near, double radius) {
  std::vector<Eigen::Vector3d> points;
  for (const Index3& v : at.surface[static_cast<size_t>(s)]) {
    if ((physical(at.g, v[0], v[1], v[2]) - near).squaredNorm() < radius * radius) {
      add_face_points(at.g, at.segment_at, s, v, points);
    }
  }
  return points;
}

// Within max_offset of a voxel of either bone (or inside one): a centre a joint can turn about without tearing
// the bones it joins apart.
bool centre_is_plausible(const JointPlacement& at, const Eigen::Vector3d& centre, int parent, int child,
                         const Contact* to_child, const Contact* to_parent) {
  if (!centre.allFinite()) return false;
  const Vec3 index = at.g.physical_to_index({centre.x(), centre.y(), centre.z()});
  const int64_t i = std::llround(index[0]), j = std::llround(index[1]), k = std::llround(index[2]);
  if (i >= 0 && j >= 0 && k >= 0 && i < at.g.size[0] && j < at.g.size[1] && k < at.g.size[2]) {
    const int s = at.segment_at[static_cast<size_t>(at.g.offset(i, j, k))];
    if (s == parent || s == child) return true;
  }
  for (const Contact* contact : {to_child, to_parent}) {
    if (contact == nullptr) continue;
    for (const Index3& v : contact->voxels) {
      if ((physical(at.g, v[0], v[1], v[2]) - centre).norm() <= at.max_offset) return true;
    }
  }
  return false;
}

// Places the joint between parent s and child c: its centre from the articular geometry (a sphere fitted to a ball,
// a cylinder to a hinge's convex side, else the contact centroid), checked for sanity, then its anatomical frame.
Joint place_joint(const JointPlacement& at, int s, int c, double area) {
  Skeleton& skeleton = at.skeleton;
  const Segment& parent_segment = skeleton.segments[static_cast<size_t>(s)];
  const Segment& child_segment = skeleton.segments[static_cast<size_t>(c)];
  Joint joint;
  joint.parent = s;
  joint.child = c;
  joint.contact_area_mm2 = area;
  const std::string& pn = parent_segment.name;
  const std::string& cn = child_segment.name;
  joint.name = at.map.joint_name(pn, cn).value_or(pn + "__" + cn);
  if (const labels::JointName* declared = at.map.declared_joint(pn, cn)) {
    joint.kind = declared->kind;
    joint.flexion = declared->flexion;
    joint.declared = true;
    if (declared->segment_a != pn) {
      skeleton.notes.push_back("joint '" + joint.name + "' is declared " + declared->segment_a + " -> " +
                               declared->segment_b + ", but the root's position made " + cn +
                               " the child; its flexion sense follows the child");
    }
  }

  const auto to_child_it = at.contacts.find({s, c});   // parent's voxels near the child
  const auto to_parent_it = at.contacts.find({c, s});  // child's voxels near the parent
  const Contact* to_child = to_child_it == at.contacts.end() ? nullptr : &to_child_it->second;
  const Contact* to_parent = to_parent_it == at.contacts.end() ? nullptr : &to_parent_it->second;
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
  if (to_child || to_parent) {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    double count = 0.0;
    for (const Contact* contact : {to_child, to_parent}) {
      if (!contact) continue;
      sum += contact->sum;
      count += static_cast<double>(contact->count);
    }
    centroid = sum / count;
    joint.centre_mm = centroid;
    joint.method = "contact-centroid";
  } else {
    // Proximity attachment: the child's surface voxel nearest to the parent's centroid.
    double best = std::numeric_limits<double>::infinity();
    for (const Index3& v : at.surface[static_cast<size_t>(c)]) {
      const Eigen::Vector3d p = physical(at.g, v[0], v[1], v[2]);
      const double d = (p - parent_segment.centroid_mm).norm();
      if (d < best) best = d, joint.centre_mm = p;
    }
    joint.method = "proximity";
  }

  if (to_child && to_parent) {
    // Points into the child: the convex side of a ball or a hinge has its centre on its own bone's side.
    const Eigen::Vector3d normal = (to_parent->sum / static_cast<double>(to_parent->count) -
                                    to_child->sum / static_cast<double>(to_child->count));
    detail::FitParams fit_params;
    fit_params.max_relative_rms = at.params.sphere_max_relative_rms;
    fit_params.min_points = at.params.sphere_min_points;
    fit_params.band_floor_mm = 0.5 * at.max_spacing;
    fit_params.rms_floor_mm = 0.35 * at.max_spacing;
    constexpr double kPoolRadiusMm = 90.0;
    // The articular region: the contact voxels nearly as close to the other bone as the closest (a long contact
    // distance on thick slices also catches shafts and rims), its centre and how far it reaches.
    double closest = std::numeric_limits<double>::infinity();
    for (const Contact* contact : {to_child, to_parent}) {
      for (const float d : contact->distance_mm) closest = std::min(closest, static_cast<double>(d));
    }
    const double articular_mm = closest + 1.5 * at.max_spacing;
    // A joint sits at the end of a long child bone, the end toward its parent (a clavicle meets the sternum at its
    // medial end, though it lies along the first rib): within a tenth of its length (two voxels at least) of it.
    double end_lo = -std::numeric_limits<double>::infinity(), end_hi = std::numeric_limits<double>::infinity();
    const Eigen::Vector3d child_axis = child_segment.principal_axis.normalized();
    constexpr double kLongChild = 1.5;
    if (child_segment.elongation >= kLongChild) {
      double t_min = std::numeric_limits<double>::infinity(), t_max = -t_min;
      for (const Index3& v : at.surface[static_cast<size_t>(c)]) {
        const double t = (physical(at.g, v[0], v[1], v[2]) - child_segment.centroid_mm).dot(child_axis);
        t_min = std::min(t_min, t), t_max = std::max(t_max, t);
      }
      const double t_parent = (parent_segment.centroid_mm - child_segment.centroid_mm).dot(child_axis);
      const double end_reach = std::max(0.1 * (t_max - t_min), 2.0 * at.max_spacing);
      if (t_parent < 0.5 * (t_min + t_max)) {
        end_hi = t_min + end_reach;
      } else {
        end_lo = t_max - end_reach;
      }
    }
    Eigen::Vector3d articular_centre = Eigen::Vector3d::Zero(), near_end = Eigen::Vector3d::Zero();
    double articular_count = 0.0, near_end_count = 0.0;
    for (const Contact* contact : {to_child, to_parent}) {
      for (size_t i = 0; i < contact->voxels.size(); ++i) {
        if (contact->distance_mm[i] > articular_mm) continue;
        const Index3& v = contact->voxels[i];
        const Eigen::Vector3d p = physical(at.g, v[0], v[1], v[2]);
        articular_centre += p;
        articular_count += 1.0;
        const double t = (p - child_segment.centroid_mm).dot(child_axis);
        if (t >= end_lo && t <= end_hi) near_end += p, near_end_count += 1.0;
      }
    }
    articular_centre = near_end_count > 0.0 ? Eigen::Vector3d(near_end / near_end_count)
                                            : Eigen::Vector3d(articular_centre / std::max(1.0, articular_count));
    // Flat and irregular joints turn about the middle of where the bones nearly touch, not of everything within
    // the contact distance (a clavicle lying along the first rib, thick slices).
    joint.centre_mm = articular_centre;
    // Bone b (the child when towards_child is +1) is convex here when the fit's centre lies on its side.
    auto convex = [&](const detail::SurfaceFit& fit, double towards_child) {
      return fit.accepted && (fit.centre - centroid).dot(normal) * towards_child > 0.0;
    };
    std::string refused;
    if (joint.kind == labels::JointKind::kBall || joint.kind == labels::JointKind::kUnspecified) {
      const detail::SurfaceFit head = detail::fit_sphere(face_points(at, c, to_parent->voxels),
                                                         face_points_near(at, c, centroid, kPoolRadiusMm), fit_params);
      bool take = convex(head, 1.0);
      if (take && joint.kind == labels::JointKind::kUnspecified) {
        // Undeclared: a ball only where the parent's contact is a concentric cup (a flat bone end fits a sphere
        // too, but the opposite end's sphere then lies elsewhere).
        detail::FitParams loose = fit_params;
        loose.max_relative_rms *= 2.0;
        const std::vector<Eigen::Vector3d> cup_points = face_points(at, s, to_child->voxels);
        const detail::SurfaceFit cup = detail::fit_sphere(cup_points, cup_points, loose);
        take = cup.accepted && (cup.centre - head.centre).norm() < 0.3 * head.radius;
      }
      if (take && centre_is_plausible(at, head.centre, s, c, to_child, to_parent)) {
        joint.centre_mm = head.centre;
        joint.method = "sphere-fit";
        joint.sphere_radius_mm = head.radius;
        joint.sphere_rms_mm = head.rms;
      } else if (joint.kind == labels::JointKind::kBall) {
        refused = head.accepted ? "its sphere fit is not on the head's side or too far from the bones"
                                : "no sphere fits the head (" + head.reason + ")";
      }
    } else if (joint.kind == labels::JointKind::kHinge) {
      // The convex side is the femoral condyles / humeral trochlea (parent) or the talar dome (child); the axis is
      // mediolateral, across the bone's long axis.
      detail::SurfaceFit best;
      double best_support = 0.0;
      for (const int side : {s, c}) {
        const Segment& bone = skeleton.segments[static_cast<size_t>(side)];
        Eigen::Vector3d guess = Eigen::Vector3d::UnitX() - Eigen::Vector3d::UnitX().dot(bone.principal_axis) * bone.principal_axis;
        if (guess.norm() < 0.3) guess = Eigen::Vector3d::UnitX();
        const double max_radius = 60.0;
        // The articular end only: the bone's boundary a little beyond the contact (the shaft would dominate).
        // The convex side of the contact: the bone's voxels within the contact distance of the other.
        const Contact* own_contact = side == c ? to_parent : to_child;
        const detail::SurfaceFit fit = detail::fit_cylinder(face_points(at, side, own_contact->voxels), guess,
                                                            15.0, max_radius, fit_params);
        if (!convex(fit, side == c ? 1.0 : -1.0)) {
          if (refused.empty()) refused = fit.accepted ? "a cylinder fits only the concave side" : fit.reason;
          continue;
        }
        if (!centre_is_plausible(at, fit.centre, s, c, to_child, to_parent)) continue;
        // Which side's fit is the articular surface: the one its own close-contact points lie on.
        const Contact* own = side == c ? to_parent : to_child;
        std::vector<Index3> articular;
        for (size_t i = 0; i < own->voxels.size(); ++i) {
          if (own->distance_mm[i] <= articular_mm) articular.push_back(own->voxels[i]);
        }
        const double support =
            detail::surface_support(fit, face_points(at, side, articular), std::max(at.max_spacing, 0.2 * fit.radius));
        constexpr double kMinSupport = 0.4;
        if (support < kMinSupport) {
          if (refused.empty()) refused = "a cylinder fits the bone but not its articular surface";
          continue;
        }
        if (!best.accepted || support > best_support) best = fit, best_support = support;
      }
      if (best.accepted) {
        joint.centre_mm = best.centre;
        joint.hinge_axis = best.axis.x() >= 0.0 ? best.axis : Eigen::Vector3d(-best.axis);
        joint.method = "cylinder-fit";
        joint.sphere_radius_mm = best.radius;
        joint.sphere_rms_mm = best.rms;
        refused.clear();
      } else {
        refused = "no cylinder fits its condyles (" + refused + ")";
      }
    }
    if (!refused.empty()) {
      skeleton.notes.push_back("joint '" + joint.name + "' is declared a " + std::string(labels::joint_kind_name(joint.kind)) +
                               ", but " + refused + "; it is placed at the contact centroid (check it, or give its "
                               "centre in a rig spec)");
    }
  }

  for (const JointSpec& js : at.spec.joints) {
    if (js.child != cn) continue;
    if (!js.name.empty()) joint.name = js.name;
    if (js.centre_mm) {
      joint.centre_mm = *js.centre_mm;
      joint.method = "rig-spec";
    }
  }
  if (joint.method != "rig-spec" && !centre_is_plausible(at, joint.centre_mm, s, c, to_child, to_parent) &&
      (to_child || to_parent)) {
    skeleton.notes.push_back("joint '" + joint.name + "': the " + joint.method + " centre lies far from both bones; "
                             "the contact centroid is used instead");
    joint.centre_mm = centroid;
    joint.method = "contact-centroid";
  }

  // The frame: the child's long axis from the centre into the child, the patient's axes, the side. A bone that is
  // not long, or whose longest spread runs across the way it leaves the joint (a vertebra is wider than tall, the
  // thorax too, a femur cut off by the field of view), points from the joint to its centroid instead, or, in a limb,
  // down: limbs lie along the body in a supine scan.
  constexpr double kLongBone = 1.5;
  constexpr double kAlongJoint = 0.7;  // cos 45 degrees
  const Segment& root = skeleton.segments[static_cast<size_t>(skeleton.root)];
  joint.side = side_of_joint(joint.name, cn, child_segment.centroid_mm, root.centroid_mm);
  const Eigen::Vector3d to_centroid = child_segment.centroid_mm - joint.centre_mm;
  Eigen::Vector3d long_axis = child_segment.principal_axis.normalized();
  if (long_axis.dot(to_centroid) < 0.0) long_axis = -long_axis;
  const bool long_bone = child_segment.elongation >= kLongBone &&
                         long_axis.dot(to_centroid) >= kAlongJoint * to_centroid.norm();
  if (!long_bone && joint.side != BodySide::kMidline) {
    long_axis = -Eigen::Vector3d::UnitZ();
  } else if (!long_bone && to_centroid.norm() > 1e-6) {
    long_axis = to_centroid.normalized();
  }
  const AnatomicalFrame frame = anatomical_frame(long_axis, joint.flexion, joint.side, joint.hinge_axis);
  joint.frame = frame.frame;
  joint.internal_rotation_sign = frame.internal_rotation_sign;
  if (frame.degenerate) skeleton.notes.push_back("joint '" + joint.name + "': " + frame.note);
  return joint;
}

}  // namespace

int Skeleton::segment_index(const std::string& name) const {
  for (size_t k = 0; k < segments.size(); ++k) {
    if (segments[k].name == name) return static_cast<int>(k);
  }
  return -1;
}

int Skeleton::joint_index(const std::string& name) const {
  for (size_t j = 0; j < joints.size(); ++j) {
    if (joints[j].name == name) return static_cast<int>(j);
  }
  return -1;
}

Status validate(const SkeletonParams& params) {
  if (params.contact_distance_mm < 0.0 || !std::isfinite(params.contact_distance_mm) ||
      params.contact_distance_mm > kMaxContactDistanceMm) {
    return invalid_argument_error("contact_distance_mm must be 0 (automatic) or up to " +
                                  std::to_string(static_cast<int>(kMaxContactDistanceMm)) +
                                  " mm (joint spaces are a few mm; the contact search grows with its cube)");
  }
  if (!(params.sphere_max_relative_rms > 0.0)) return invalid_argument_error("sphere_max_relative_rms must be positive");
  if (params.sphere_min_points < 4) return invalid_argument_error("sphere_min_points must be at least 4");
  return ok_status();
}

Result<Skeleton> build_skeleton(const LabelVolume& labels, const labels::LabelMap& map, const RigSpec& spec,
                                const SkeletonParams& params, const ProgressHooks& hooks) {
  POSEWARP_RETURN_IF_ERROR(validate(params));
  if (labels.empty()) return invalid_argument_error("the label volume is empty");
  StageProgress progress(hooks, "skeleton");
  const ImageGeometry& g = labels.geometry();

  // 1. Segments: the map's bone segments, regrouped by the spec, keeping those present in the volume.
  std::vector<std::pair<std::string, std::vector<Label>>> candidates;
  std::set<Label> regrouped;
  for (const auto& [name, values] : spec.segments) regrouped.insert(values.begin(), values.end());
  for (const std::string& name : map.bone_segments()) {
    std::vector<Label> values;
    for (const Label v : map.labels_of_segment(name)) {
      if (!regrouped.count(v)) values.push_back(v);
    }
    if (!values.empty()) candidates.emplace_back(name, values);
  }
  for (const auto& entry : spec.segments) {
    auto same = std::find_if(candidates.begin(), candidates.end(), [&](const auto& c) { return c.first == entry.first; });
    if (same != candidates.end()) {
      same->second.insert(same->second.end(), entry.second.begin(), entry.second.end());
    } else {
      candidates.push_back(entry);
    }
  }
  std::unordered_map<Label, int> candidate_of;
  for (size_t c = 0; c < candidates.size(); ++c) {
    for (const Label v : candidates[c].second) candidate_of[v] = static_cast<int>(c);
  }
  std::vector<int64_t> candidate_voxels(candidates.size(), 0);
  std::map<Label, int64_t> label_voxels;
  for (const Label v : labels.voxels()) {
    auto it = candidate_of.find(v);
    if (it != candidate_of.end()) {
      ++candidate_voxels[static_cast<size_t>(it->second)];
      ++label_voxels[v];
    }
  }
  for (const auto& [name, values] : spec.segments) {
    for (const Label v : values) {
      if (!label_voxels.count(v)) {
        return invalid_argument_error("the rig spec puts label " + std::to_string(v) + " into segment '" + name +
                                      "', but the label volume holds no voxel of it; remove it from the spec");
      }
    }
  }
  Skeleton skeleton;
  std::vector<int> segment_of_candidate(candidates.size(), -1);
  for (size_t c = 0; c < candidates.size(); ++c) {
    if (candidate_voxels[c] == 0) {
      skeleton.missing_segments.push_back(candidates[c].first);
      continue;
    }
    segment_of_candidate[c] = static_cast<int>(skeleton.segments.size());
    Segment segment;
    segment.name = candidates[c].first;
    for (const Label v : candidates[c].second) {
      if (label_voxels.count(v)) segment.labels.push_back(v);
    }
    skeleton.segments.push_back(segment);
  }
  const int n = static_cast<int>(skeleton.segments.size());
  if (n == 0) {
    int bone_labels = 0;
    for (const auto& entry : map.entries()) bone_labels += entry.role == labels::LabelRole::kBone;
    return failed_precondition_error(
        "no bone labels found: the label map '" + map.name() + "' names " + std::to_string(bone_labels) +
        " bone labels and the volume holds none of them. Check that the segmentation labels bones and that the "
        "label map (a preset, or a map of your own) matches it");
  }
  if (n == 1) {
    return failed_precondition_error("only one bone segment ('" + skeleton.segments[0].name +
                                     "') is present; a rig needs at least two segments joined by a joint. Label "
                                     "more bones, or split the bone into segments with a rig spec");
  }

  // 2. Segment index per voxel, statistics and surface voxels.
  std::vector<int16_t> segment_at(static_cast<size_t>(labels.voxel_count()), -1);
  for (int64_t v = 0; v < labels.voxel_count(); ++v) {
    auto it = candidate_of.find(labels.data()[v]);
    if (it != candidate_of.end()) segment_at[static_cast<size_t>(v)] = static_cast<int16_t>(segment_of_candidate[static_cast<size_t>(it->second)]);
  }
  std::vector<Eigen::Matrix3d> second_moment(static_cast<size_t>(n), Eigen::Matrix3d::Zero());
  std::vector<std::vector<Index3>> surface(static_cast<size_t>(n));
  for (int64_t k = 0; k < g.size[2]; ++k) {
    for (int64_t j = 0; j < g.size[1]; ++j) {
      for (int64_t i = 0; i < g.size[0]; ++i) {
        const int s = segment_at[static_cast<size_t>(g.offset(i, j, k))];
        if (s < 0) continue;
        Segment& segment = skeleton.segments[static_cast<size_t>(s)];
        const Eigen::Vector3d p = physical(g, i, j, k);
        ++segment.voxels;
        segment.centroid_mm += p;
        second_moment[static_cast<size_t>(s)] += p * p.transpose();
        bool on_surface = false;
        const int64_t neighbours[6][3] = {{i - 1, j, k}, {i + 1, j, k}, {i, j - 1, k},
                                          {i, j + 1, k}, {i, j, k - 1}, {i, j, k + 1}};
        for (const auto& q : neighbours) {
          if (!labels.contains(q[0], q[1], q[2]) || segment_at[static_cast<size_t>(g.offset(q[0], q[1], q[2]))] != s) {
            on_surface = true;
            break;
          }
        }
        if (on_surface) surface[static_cast<size_t>(s)].push_back({i, j, k});
      }
    }
  }
  for (int s = 0; s < n; ++s) {
    Segment& segment = skeleton.segments[static_cast<size_t>(s)];
    const double count = static_cast<double>(segment.voxels);
    segment.centroid_mm /= count;
    const Eigen::Matrix3d covariance =
        second_moment[static_cast<size_t>(s)] / count - segment.centroid_mm * segment.centroid_mm.transpose();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen(covariance);
    segment.principal_axis = eigen.eigenvectors().col(2).normalized();
    const Eigen::Vector3d spread = eigen.eigenvalues().cwiseMax(1e-12);
    segment.elongation = std::sqrt(spread(2) / spread(1));
  }
  POSEWARP_RETURN_IF_ERROR(progress.check_cancel());
  progress.update(0.2);

  // 3. Contacts: surface voxels of a within the contact distance of a voxel of b.
  const double max_spacing = std::max({g.spacing[0], g.spacing[1], g.spacing[2]});
  const double contact_mm = spec.contact_distance_mm.value_or(
      params.contact_distance_mm > 0.0 ? params.contact_distance_mm : std::min(3.5 * max_spacing, kMaxContactDistanceMm));
  const int64_t reach[3] = {static_cast<int64_t>(std::floor(contact_mm / g.spacing[0])),
                            static_cast<int64_t>(std::floor(contact_mm / g.spacing[1])),
                            static_cast<int64_t>(std::floor(contact_mm / g.spacing[2]))};
  std::map<std::pair<int, int>, Contact> contacts;
  std::vector<std::pair<int, double>> near;  // segment, squared distance to its nearest voxel
  for (int s = 0; s < n; ++s) {
    for (const Index3& v : surface[static_cast<size_t>(s)]) {
      near.clear();
      for (int64_t dk = -reach[2]; dk <= reach[2]; ++dk) {
        for (int64_t dj = -reach[1]; dj <= reach[1]; ++dj) {
          for (int64_t di = -reach[0]; di <= reach[0]; ++di) {
            const double d2 = std::pow(di * g.spacing[0], 2) + std::pow(dj * g.spacing[1], 2) + std::pow(dk * g.spacing[2], 2);
            if (d2 > contact_mm * contact_mm) continue;
            const int64_t x = v[0] + di, y = v[1] + dj, z = v[2] + dk;
            if (!labels.contains(x, y, z)) continue;
            const int other = segment_at[static_cast<size_t>(g.offset(x, y, z))];
            if (other < 0 || other == s) continue;
            auto known = std::find_if(near.begin(), near.end(), [&](const auto& e) { return e.first == other; });
            if (known == near.end()) {
              near.emplace_back(other, d2);
            } else {
              known->second = std::min(known->second, d2);
            }
          }
        }
      }
      const Eigen::Vector3d p = physical(g, v[0], v[1], v[2]);
      for (const auto& [other, d2] : near) {
        Contact& contact = contacts[{s, other}];
        ++contact.count;
        contact.sum += p;
        contact.voxels.push_back(v);
        contact.distance_mm.push_back(static_cast<float>(std::sqrt(d2)));
      }
    }
    progress.update(0.2 + 0.6 * (s + 1) / n);
    POSEWARP_RETURN_IF_ERROR(progress.check_cancel());
  }

  // 4. Root: the spec's, else the map's, else the most central large segment.
  int root = -1;
  const std::string wanted_root = !spec.root.empty() ? spec.root : map.root_segment();
  if (!wanted_root.empty()) root = skeleton.segment_index(wanted_root);
  if (!spec.root.empty() && root < 0) {
    return invalid_argument_error("the rig spec's root '" + spec.root + "' is not a bone segment present in the volume");
  }
  if (root < 0) {
    Eigen::Vector3d body_centre = Eigen::Vector3d::Zero();
    double total = 0.0;
    for (const Segment& segment : skeleton.segments) {
      body_centre += segment.centroid_mm * static_cast<double>(segment.voxels);
      total += static_cast<double>(segment.voxels);
    }
    body_centre /= total;
    double extent = 1.0;
    for (const Segment& segment : skeleton.segments) extent = std::max(extent, (segment.centroid_mm - body_centre).norm());
    double best = -1.0;
    for (int s = 0; s < n; ++s) {
      const Segment& segment = skeleton.segments[static_cast<size_t>(s)];
      const double score = static_cast<double>(segment.voxels) * std::exp(-4.0 * (segment.centroid_mm - body_centre).norm() / extent);
      if (score > best) best = score, root = s;
    }
    skeleton.notes.push_back("root chosen as the most central large segment: " + skeleton.segments[static_cast<size_t>(root)].name);
  }
  skeleton.root = root;

  // 5. Maximum spanning tree over contact area; the spec's joints are forced in, its removals kept out.
  auto segment_named = [&](const std::string& name, const char* what) -> Result<int> {
    const int s = skeleton.segment_index(name);
    if (s < 0) {
      return invalid_argument_error(std::string("the rig spec's ") + what + " '" + name +
                                    "' is not a bone segment present in the volume");
    }
    return s;
  };
  std::set<std::pair<int, int>> removed;
  for (const auto& [a, b] : spec.remove_joints) {
    POSEWARP_ASSIGN_OR_RETURN(const int sa, segment_named(a, "removed joint segment"));
    POSEWARP_ASSIGN_OR_RETURN(const int sb, segment_named(b, "removed joint segment"));
    removed.insert({std::min(sa, sb), std::max(sa, sb)});
  }
  const double face_area = (g.spacing[0] * g.spacing[1] + g.spacing[1] * g.spacing[2] + g.spacing[0] * g.spacing[2]) / 3.0;
  struct Edge {
    int a, b;
    double area;
    int priority;   // 2 rig spec, 1 declared by the label map, 0 contact only
    int order = 0;  // declaration order among the map's joints
  };
  std::vector<Edge> edges;
  auto area_of = [&](int x, int y) {
    const auto one = contacts.find({x, y});
    const auto other = contacts.find({y, x});
    const double count = 0.5 * ((one == contacts.end() ? 0.0 : static_cast<double>(one->second.count)) +
                                (other == contacts.end() ? 0.0 : static_cast<double>(other->second.count)));
    return count * face_area;
  };
  for (const auto& [pair, contact] : contacts) {
    if (pair.first > pair.second) continue;
    if (removed.count(pair)) continue;
    edges.push_back({pair.first, pair.second, area_of(pair.first, pair.second), 0});
  }
  std::map<int, int> forced_parent;  // child -> parent
  for (const JointSpec& joint : spec.joints) {
    POSEWARP_ASSIGN_OR_RETURN(const int child, segment_named(joint.child, "joint child"));
    if (joint.parent.empty()) continue;
    POSEWARP_ASSIGN_OR_RETURN(const int parent, segment_named(joint.parent, "joint parent"));
    if (parent == child) return invalid_argument_error("the rig spec joins segment '" + joint.child + "' to itself");
    forced_parent[child] = parent;
    edges.push_back({parent, child, area_of(parent, child), 2});
  }
  // The label map's declared joints come next, in its order, whenever both segments are present: they give the
  // anatomical tree (thorax -> clavicle -> scapula -> humerus) where the largest contact would not.
  int declared_order = 0;
  for (const labels::JointName& declared : map.joint_names()) {
    const int a = skeleton.segment_index(declared.segment_a), b = skeleton.segment_index(declared.segment_b);
    if (a < 0 || b < 0 || removed.count({std::min(a, b), std::max(a, b)})) continue;
    edges.push_back({a, b, area_of(a, b), 1, declared_order++});
  }
  std::stable_sort(edges.begin(), edges.end(), [](const Edge& x, const Edge& y) {
    if (x.priority != y.priority) return x.priority > y.priority;
    if (x.priority == 1) return x.order < y.order;
    return x.area > y.area;
  });
  DisjointSets sets(n);
  std::vector<std::vector<std::pair<int, double>>> adjacency(static_cast<size_t>(n));
  for (const Edge& e : edges) {
    if (!sets.unite(e.a, e.b)) {
      // A declared joint that closes a loop is an alternative (scapulothoracic when the clavicle is there).
      if (e.priority == 2) {
        return invalid_argument_error("the rig spec's joints between '" + skeleton.segments[static_cast<size_t>(e.a)].name +
                                      "' and '" + skeleton.segments[static_cast<size_t>(e.b)].name +
                                      "' close a loop; a skeleton is a tree");
      }
      continue;
    }
    adjacency[static_cast<size_t>(e.a)].emplace_back(e.b, e.area);
    adjacency[static_cast<size_t>(e.b)].emplace_back(e.a, e.area);
  }
  // Segments that touch nothing are attached to the nearest connected segment (by centroids), and reported.
  for (;;) {
    std::vector<int> attached;
    std::vector<int> detached;
    for (int s = 0; s < n; ++s) (sets.find(s) == sets.find(root) ? attached : detached).push_back(s);
    if (detached.empty()) break;
    double best = std::numeric_limits<double>::infinity();
    int best_a = -1, best_d = -1;
    for (const int d : detached) {
      for (const int a : attached) {
        const double dist = (skeleton.segments[static_cast<size_t>(d)].centroid_mm - skeleton.segments[static_cast<size_t>(a)].centroid_mm).norm();
        if (dist < best) best = dist, best_a = a, best_d = d;
      }
    }
    sets.unite(best_a, best_d);
    adjacency[static_cast<size_t>(best_a)].emplace_back(best_d, 0.0);
    adjacency[static_cast<size_t>(best_d)].emplace_back(best_a, 0.0);
    skeleton.notes.push_back("segment '" + skeleton.segments[static_cast<size_t>(best_d)].name +
                             "' touches no other bone; attached to the nearest, '" +
                             skeleton.segments[static_cast<size_t>(best_a)].name + "' (check it, or add a joint in a rig spec)");
  }

  // 6. Orient from the root (breadth first, so parents come before children) and place the joints.
  const double max_offset =
      params.max_centre_offset_mm > 0.0 ? params.max_centre_offset_mm : std::max(10.0, 2.0 * max_spacing);
  const JointPlacement placement{g, map, spec, params, skeleton, segment_at, surface, contacts, max_spacing, max_offset};
  std::vector<int> parent_of(static_cast<size_t>(n), -2);
  parent_of[static_cast<size_t>(root)] = -1;
  std::queue<int> queue;
  queue.push(root);
  while (!queue.empty()) {
    const int s = queue.front();
    queue.pop();
    std::vector<std::pair<int, double>> next = adjacency[static_cast<size_t>(s)];
    std::sort(next.begin(), next.end());
    for (const auto& [c, area] : next) {
      if (parent_of[static_cast<size_t>(c)] != -2) continue;
      parent_of[static_cast<size_t>(c)] = s;
      queue.push(c);

      Joint joint = place_joint(placement, s, c, area);
      skeleton.segments[static_cast<size_t>(c)].parent_joint = static_cast<int>(skeleton.joints.size());
      skeleton.joints.push_back(joint);
    }
  }
  for (const auto& [child, parent] : forced_parent) {
    if (parent_of[static_cast<size_t>(child)] != parent) {
      skeleton.notes.push_back("the rig spec asked for '" + skeleton.segments[static_cast<size_t>(parent)].name +
                               "' as parent of '" + skeleton.segments[static_cast<size_t>(child)].name +
                               "', but the root's position made it the child; the joint is kept with roles swapped");
    }
  }
  for (const JointSpec& js : spec.joints) {
    if (js.child == skeleton.segments[static_cast<size_t>(root)].name && (js.centre_mm || !js.name.empty())) {
      skeleton.notes.push_back("the rig spec names a joint for the root segment '" + js.child + "', which has none");
    }
  }
  std::set<std::string> names;
  for (Joint& joint : skeleton.joints) {
    if (!names.insert(joint.name).second) {
      joint.name += "__" + skeleton.segments[static_cast<size_t>(joint.child)].name;
      names.insert(joint.name);
    }
  }
  progress.finish();
  return skeleton;
}

LabelVolume skeleton_classes(const Skeleton& skeleton, const LabelVolume& labels, const LabelVolume& body) {
  std::unordered_map<Label, Label> class_of;
  for (size_t k = 0; k < skeleton.segments.size(); ++k) {
    for (const Label v : skeleton.segments[k].labels) class_of[v] = static_cast<Label>(kFirstBoneClass + k);
  }
  LabelVolume classes(labels.geometry(), 0);
  classes.set_source_type(PixelType::kUInt8);
  for (int64_t v = 0; v < labels.voxel_count(); ++v) {
    auto it = class_of.find(labels.data()[v]);
    if (it != class_of.end()) {
      classes.data()[v] = it->second;
    } else if (body.data()[v] != 0) {
      classes.data()[v] = kSoftTissueClass;
    }
  }
  // Bones that touch (joint spaces thinner than a voxel) would share mesh vertices, and a shared vertex cannot
  // follow both bones: open a soft layer where two segments meet, one voxel on each side.
  const ImageGeometry& g = labels.geometry();
  std::vector<int64_t> contact;
  for (int64_t k = 0; k < g.size[2]; ++k) {
    for (int64_t j = 0; j < g.size[1]; ++j) {
      for (int64_t i = 0; i < g.size[0]; ++i) {
        const Label c = classes.at(i, j, k);
        if (c < kFirstBoneClass) continue;
        bool touches = false;
        for (int64_t dk = -1; dk <= 1 && !touches; ++dk) {
          for (int64_t dj = -1; dj <= 1 && !touches; ++dj) {
            for (int64_t di = -1; di <= 1 && !touches; ++di) {
              if (!classes.contains(i + di, j + dj, k + dk)) continue;
              const Label other = classes.at(i + di, j + dj, k + dk);
              touches = other >= kFirstBoneClass && other != c;
            }
          }
        }
        if (touches) contact.push_back(g.offset(i, j, k));
      }
    }
  }
  for (const int64_t v : contact) classes.data()[v] = kSoftTissueClass;
  return classes;
}

}  // namespace posewarp::rig
