// Placing one joint: its name and declared kind, the contact centre, the articular fits, the rig spec's word, the
// frame.
#include "joint_placement.h"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>

#include "joint_fit.h"
#include "posewarp/rig/anatomical_frame.h"

namespace posewarp::rig::detail {
namespace {

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

// The contacts between a joint's bones and their centroid.
struct JointContacts {
  const Contact* to_child = nullptr;   // the parent's voxels near the child
  const Contact* to_parent = nullptr;  // the child's voxels near the parent
  Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
};

// The joint's name, and its kind and flexion sense where the label map declares it.
Joint named_joint(const JointPlacement& at, int s, int c, double area) {
  const std::string& pn = at.skeleton.segments[static_cast<size_t>(s)].name;
  const std::string& cn = at.skeleton.segments[static_cast<size_t>(c)].name;
  Joint joint;
  joint.parent = s;
  joint.child = c;
  joint.contact_area_mm2 = area;
  joint.name = at.map.joint_name(pn, cn).value_or(pn + "__" + cn);
  if (const labels::JointName* declared = at.map.declared_joint(pn, cn)) {
    joint.kind = declared->kind;
    joint.flexion = declared->flexion;
    joint.declared = true;
    if (declared->segment_a != pn) {
      at.skeleton.notes.push_back("joint '" + joint.name + "' is declared " + declared->segment_a + " -> " +
                                  declared->segment_b + ", but the root's position made " + cn +
                                  " the child; its flexion sense follows the child");
    }
  }
  return joint;
}

// The first centre: the contacts' centroid, or for bones that do not touch, the child's surface voxel nearest to the
// parent's centroid.
JointContacts contact_centre(const JointPlacement& at, int s, int c, Joint& joint) {
  JointContacts k;
  const auto to_child_it = at.contacts.find({s, c});
  const auto to_parent_it = at.contacts.find({c, s});
  k.to_child = to_child_it == at.contacts.end() ? nullptr : &to_child_it->second;
  k.to_parent = to_parent_it == at.contacts.end() ? nullptr : &to_parent_it->second;
  if (k.to_child || k.to_parent) {
    Eigen::Vector3d sum = Eigen::Vector3d::Zero();
    double count = 0.0;
    for (const Contact* contact : {k.to_child, k.to_parent}) {
      if (!contact) continue;
      sum += contact->sum;
      count += static_cast<double>(contact->count);
    }
    k.centroid = sum / count;
    joint.centre_mm = k.centroid;
    joint.method = "contact-centroid";
  } else {
    const Eigen::Vector3d& parent_centroid = at.skeleton.segments[static_cast<size_t>(s)].centroid_mm;
    double best = std::numeric_limits<double>::infinity();
    for (const Index3& v : at.surface[static_cast<size_t>(c)]) {
      const Eigen::Vector3d p = physical(at.g, v[0], v[1], v[2]);
      const double d = (p - parent_centroid).norm();
      if (d < best) best = d, joint.centre_mm = p;
    }
    joint.method = "proximity";
  }
  return k;
}

// Where the bones nearly touch: the contact voxels nearly as close to the other bone as the closest (a long contact
// distance on thick slices also catches shafts and rims) and their middle. A joint sits at the end of a long child
// bone, the end toward its parent (a clavicle meets the sternum at its medial end, though it lies along the first
// rib): the middle of those within a tenth of its length (two voxels at least) of that end, when there are any.
struct ArticularRegion {
  double reach_mm = 0.0;  // contact voxels this close to the other bone are articular
  Eigen::Vector3d centre = Eigen::Vector3d::Zero();
};

ArticularRegion articular_region(const JointPlacement& at, int s, int c, const JointContacts& k) {
  const Segment& parent_segment = at.skeleton.segments[static_cast<size_t>(s)];
  const Segment& child_segment = at.skeleton.segments[static_cast<size_t>(c)];
  ArticularRegion region;
  double closest = std::numeric_limits<double>::infinity();
  for (const Contact* contact : {k.to_child, k.to_parent}) {
    for (const float d : contact->distance_mm) closest = std::min(closest, static_cast<double>(d));
  }
  region.reach_mm = closest + 1.5 * at.max_spacing;
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
  for (const Contact* contact : {k.to_child, k.to_parent}) {
    for (size_t i = 0; i < contact->voxels.size(); ++i) {
      if (contact->distance_mm[i] > region.reach_mm) continue;
      const Index3& v = contact->voxels[i];
      const Eigen::Vector3d p = physical(at.g, v[0], v[1], v[2]);
      articular_centre += p;
      articular_count += 1.0;
      const double t = (p - child_segment.centroid_mm).dot(child_axis);
      if (t >= end_lo && t <= end_hi) near_end += p, near_end_count += 1.0;
    }
  }
  region.centre = near_end_count > 0.0 ? Eigen::Vector3d(near_end / near_end_count)
                                       : Eigen::Vector3d(articular_centre / std::max(1.0, articular_count));
  return region;
}

// What the articular fits share: their parameters, and which side of the contact each bone is on.
struct Fitting {
  FitParams params;
  Eigen::Vector3d normal;  // points into the child
  // Bone b (the child when towards_child is +1) is convex here when the fit's centre lies on its side: the convex side
  // of a ball or a hinge has its centre on its own bone's side.
  bool convex(const SurfaceFit& fit, const Eigen::Vector3d& centroid, double towards_child) const {
    return fit.accepted && (fit.centre - centroid).dot(normal) * towards_child > 0.0;
  }
};

// A ball, or a joint of no declared kind: a sphere fitted to the child's head, taken when it is convex, plausible and,
// undeclared, sits in a concentric cup of the parent. Why a declared ball's fit was refused, else empty.
std::string fit_ball(const JointPlacement& at, int s, int c, const JointContacts& k, const Fitting& fitting,
                     Joint& joint) {
  constexpr double kPoolRadiusMm = 90.0;
  const SurfaceFit head = fit_sphere(face_points(at, c, k.to_parent->voxels),
                                     face_points_near(at, c, k.centroid, kPoolRadiusMm), fitting.params);
  bool take = fitting.convex(head, k.centroid, 1.0);
  if (take && joint.kind == labels::JointKind::kUnspecified) {
    // Undeclared: a ball only where the parent's contact is a concentric cup (a flat bone end fits a sphere too, but
    // the opposite end's sphere then lies elsewhere).
    FitParams loose = fitting.params;
    loose.max_relative_rms *= 2.0;
    const std::vector<Eigen::Vector3d> cup_points = face_points(at, s, k.to_child->voxels);
    const SurfaceFit cup = fit_sphere(cup_points, cup_points, loose);
    take = cup.accepted && (cup.centre - head.centre).norm() < 0.3 * head.radius;
  }
  if (take && centre_is_plausible(at, head.centre, s, c, k.to_child, k.to_parent)) {
    joint.centre_mm = head.centre;
    joint.method = "sphere-fit";
    joint.sphere_radius_mm = head.radius;
    joint.sphere_rms_mm = head.rms;
    return "";
  }
  if (joint.kind != labels::JointKind::kBall) return "";
  return head.accepted ? "its sphere fit is not on the head's side or too far from the bones"
                       : "no sphere fits the head (" + head.reason + ")";
}

// A hinge: a cylinder fitted to the convex side, the femoral condyles / humeral trochlea (parent) or the talar dome
// (child), its axis mediolateral, across the bone's long axis; of the two sides, the one whose own articular points
// support it best. Why no fit was taken, else empty.
std::string fit_hinge(const JointPlacement& at, int s, int c, const JointContacts& k, double articular_mm,
                      const Fitting& fitting, Joint& joint) {
  std::string refused;
  SurfaceFit best;
  double best_support = 0.0;
  for (const int side : {s, c}) {
    const Segment& bone = at.skeleton.segments[static_cast<size_t>(side)];
    Eigen::Vector3d guess =
        Eigen::Vector3d::UnitX() - Eigen::Vector3d::UnitX().dot(bone.principal_axis) * bone.principal_axis;
    if (guess.norm() < 0.3) guess = Eigen::Vector3d::UnitX();
    const double max_radius = 60.0;
    // The articular end only: the bone's boundary a little beyond the contact (the shaft would dominate). The convex
    // side of the contact: the bone's voxels within the contact distance of the other.
    const Contact* own = side == c ? k.to_parent : k.to_child;
    const SurfaceFit fit = fit_cylinder(face_points(at, side, own->voxels), guess, 15.0, max_radius, fitting.params);
    if (!fitting.convex(fit, k.centroid, side == c ? 1.0 : -1.0)) {
      if (refused.empty()) refused = fit.accepted ? "a cylinder fits only the concave side" : fit.reason;
      continue;
    }
    if (!centre_is_plausible(at, fit.centre, s, c, k.to_child, k.to_parent)) continue;
    // Which side's fit is the articular surface: the one its own close-contact points lie on.
    std::vector<Index3> articular;
    for (size_t i = 0; i < own->voxels.size(); ++i) {
      if (own->distance_mm[i] <= articular_mm) articular.push_back(own->voxels[i]);
    }
    const double support =
        surface_support(fit, face_points(at, side, articular), std::max(at.max_spacing, 0.2 * fit.radius));
    constexpr double kMinSupport = 0.4;
    if (support < kMinSupport) {
      if (refused.empty()) refused = "a cylinder fits the bone but not its articular surface";
      continue;
    }
    if (!best.accepted || support > best_support) best = fit, best_support = support;
  }
  if (!best.accepted) return "no cylinder fits its condyles (" + refused + ")";
  joint.centre_mm = best.centre;
  joint.hinge_axis = best.axis.x() >= 0.0 ? best.axis : Eigen::Vector3d(-best.axis);
  joint.method = "cylinder-fit";
  joint.sphere_radius_mm = best.radius;
  joint.sphere_rms_mm = best.rms;
  return "";
}

// Bones that touch on both sides: the middle of the articular region (flat and irregular joints turn about where the
// bones nearly touch, not about everything within the contact distance: a clavicle along the first rib, thick
// slices), then the fit of the joint's kind. A declared kind whose fit fails is noted.
void fit_articular_surface(const JointPlacement& at, int s, int c, const JointContacts& k, Joint& joint) {
  Fitting fitting;
  fitting.normal = k.to_parent->sum / static_cast<double>(k.to_parent->count) -
                   k.to_child->sum / static_cast<double>(k.to_child->count);
  fitting.params.max_relative_rms = at.params.sphere_max_relative_rms;
  fitting.params.min_points = at.params.sphere_min_points;
  fitting.params.band_floor_mm = 0.5 * at.max_spacing;
  fitting.params.rms_floor_mm = 0.35 * at.max_spacing;
  const ArticularRegion region = articular_region(at, s, c, k);
  joint.centre_mm = region.centre;
  std::string refused;
  if (joint.kind == labels::JointKind::kBall || joint.kind == labels::JointKind::kUnspecified) {
    refused = fit_ball(at, s, c, k, fitting, joint);
  } else if (joint.kind == labels::JointKind::kHinge) {
    refused = fit_hinge(at, s, c, k, region.reach_mm, fitting, joint);
  }
  if (!refused.empty()) {
    at.skeleton.notes.push_back("joint '" + joint.name + "' is declared a " +
                                std::string(labels::joint_kind_name(joint.kind)) + ", but " + refused +
                                "; it is placed at the contact centroid (check it, or give its centre in a rig spec)");
  }
}

// The rig spec's name and centre for the joint; then a centre far from both bones falls back to the contact centroid.
void apply_spec(const JointPlacement& at, int s, int c, const JointContacts& k, Joint& joint) {
  for (const JointSpec& js : at.spec.joints) {
    if (js.child != at.skeleton.segments[static_cast<size_t>(c)].name) continue;
    if (!js.name.empty()) joint.name = js.name;
    if (js.centre_mm) {
      joint.centre_mm = *js.centre_mm;
      joint.method = "rig-spec";
    }
  }
  if (joint.method != "rig-spec" && !centre_is_plausible(at, joint.centre_mm, s, c, k.to_child, k.to_parent) &&
      (k.to_child || k.to_parent)) {
    at.skeleton.notes.push_back("joint '" + joint.name + "': the " + joint.method +
                                " centre lies far from both bones; the contact centroid is used instead");
    joint.centre_mm = k.centroid;
    joint.method = "contact-centroid";
  }
}

// The frame: the child's long axis from the centre into the child, the patient's axes, the side. A bone that is not
// long, or whose longest spread runs across the way it leaves the joint (a vertebra is wider than tall, the thorax
// too, a femur cut off by the field of view), points from the joint to its centroid instead, or, in a limb, down:
// limbs lie along the body in a supine scan.
void set_frame(const JointPlacement& at, int c, Joint& joint) {
  constexpr double kLongBone = 1.5;
  constexpr double kAlongJoint = 0.7;  // cos 45 degrees
  const Segment& child_segment = at.skeleton.segments[static_cast<size_t>(c)];
  const Segment& root = at.skeleton.segments[static_cast<size_t>(at.skeleton.root)];
  joint.side = side_of_joint(joint.name, child_segment.name, child_segment.centroid_mm, root.centroid_mm);
  const Eigen::Vector3d to_centroid = child_segment.centroid_mm - joint.centre_mm;
  Eigen::Vector3d long_axis = child_segment.principal_axis.normalized();
  if (long_axis.dot(to_centroid) < 0.0) long_axis = -long_axis;
  const bool long_bone =
      child_segment.elongation >= kLongBone && long_axis.dot(to_centroid) >= kAlongJoint * to_centroid.norm();
  if (!long_bone && joint.side != BodySide::kMidline) {
    long_axis = -Eigen::Vector3d::UnitZ();
  } else if (!long_bone && to_centroid.norm() > 1e-6) {
    long_axis = to_centroid.normalized();
  }
  const AnatomicalFrame frame = anatomical_frame(long_axis, joint.flexion, joint.side, joint.hinge_axis);
  joint.frame = frame.frame;
  joint.internal_rotation_sign = frame.internal_rotation_sign;
  if (frame.degenerate) at.skeleton.notes.push_back("joint '" + joint.name + "': " + frame.note);
}

}  // namespace

Joint place_joint(const JointPlacement& at, int s, int c, double area) {
  Joint joint = named_joint(at, s, c, area);
  const JointContacts contacts = contact_centre(at, s, c, joint);
  if (contacts.to_child && contacts.to_parent) fit_articular_surface(at, s, c, contacts, joint);
  apply_spec(at, s, c, contacts, joint);
  set_frame(at, c, joint);
  return joint;
}

}  // namespace posewarp::rig::detail
