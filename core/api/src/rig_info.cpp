// The skeleton in the api's own types.
#include "posewarp/api/rig_info.h"
#include "posewarp/labels/label_map.h"
#include "posewarp/rig/skeleton.h"

#include <set>

namespace posewarp::api {

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
