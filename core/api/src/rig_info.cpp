// The skeleton in the api's own types.
#include "posewarp/api/rig_info.h"
#include "posewarp/labels/label_map.h"
#include "posewarp/rig/skeleton.h"

#include <iomanip>
#include <set>
#include <sstream>

namespace posewarp::api {
namespace {

std::string mm(double value) {
  std::ostringstream out;
  out << std::fixed << std::setprecision(1) << value << " mm";
  return out.str();
}

// The sentence for JointInfo::placed_because. A refused fit left a note naming the joint; it says why.
std::string placed_because(const rig::Joint& j, const std::vector<std::string>& notes) {
  if (j.method == "rig-spec") return "the rig spec gives its centre";
  if (j.method == "sphere-fit") {
    return "a sphere of radius " + mm(j.sphere_radius_mm) + " fits the child's articular head (rms " +
           mm(j.sphere_rms_mm) + "); the joint turns about its centre";
  }
  if (j.method == "cylinder-fit") {
    return "a cylinder of radius " + mm(j.sphere_radius_mm) + " fits the convex articular surface (rms " +
           mm(j.sphere_rms_mm) + "); the hinge turns about its axis";
  }
  if (j.method == "proximity") {
    return "its bones do not touch: the child's surface point nearest the parent's centroid";
  }
  const std::string quoted = "'" + j.name + "'";
  for (const std::string& note : notes) {
    if (note.find(quoted) != std::string::npos && note.find("contact centroid") != std::string::npos) return note;
  }
  switch (j.kind) {
    case labels::JointKind::kPlane:
      return "declared a plane joint (flat or irregular surfaces, no single centre to fit): it turns about the middle "
             "of where its bones nearly touch";
    case labels::JointKind::kUnspecified:
      return "no kind declared, and the child's end is no ball in a concentric cup: it turns about the middle of "
             "where its bones nearly touch (declare its kind in the label map for a fit)";
    default: return "it turns about the middle of where its bones nearly touch";
  }
}

}  // namespace

SkeletonInfo describe_skeleton(const Rig& rig) {
  const rig::Skeleton& s = rig.skeleton;
  SkeletonInfo info;
  if (s.root >= 0 && static_cast<size_t>(s.root) < s.segments.size()) info.root = s.segments[static_cast<size_t>(s.root)].name;
  for (const rig::Segment& segment : s.segments) {
    info.segments.push_back({segment.name, segment.labels, segment.voxels, segment.centroid_mm});
  }
  for (const rig::Joint& j : s.joints) {
    JointInfo joint;
    joint.name = j.name;
    joint.parent = s.segments[static_cast<size_t>(j.parent)].name;
    joint.child = s.segments[static_cast<size_t>(j.child)].name;
    joint.centre_mm = j.centre_mm;
    joint.method = j.method;
    joint.kind = std::string(labels::joint_kind_name(j.kind));
    joint.side = std::string(rig::body_side_name(j.side));
    joint.declared = j.declared;
    joint.contact_area_mm2 = j.contact_area_mm2;
    joint.frame = j.frame;
    joint.internal_rotation_sign = j.internal_rotation_sign;
    joint.flexion_moves_child = std::string(labels::flexion_direction_name(j.flexion));
    joint.fit_radius_mm = j.sphere_radius_mm;
    joint.fit_rms_mm = j.sphere_rms_mm;
    joint.hinge_axis = j.hinge_axis;
    joint.ranges = j.ranges;
    joint.placed_because = placed_because(j, s.notes);
    info.joints.push_back(std::move(joint));
  }
  info.missing_segments = s.missing_segments;
  info.notes = s.notes;
  return info;
}

std::vector<std::string> surface_roles(const Rig& rig) {
  std::set<Label> bone_labels;
  for (const rig::Segment& segment : rig.skeleton.segments) bone_labels.insert(segment.labels.begin(), segment.labels.end());
  std::vector<std::string> roles;
  for (const SurfaceMesh& mesh : rig.surfaces) {
    roles.push_back(mesh.label == 0 ? "skin" : bone_labels.count(mesh.label) ? "bone" : "tissue");
  }
  return roles;
}

}  // namespace posewarp::api
