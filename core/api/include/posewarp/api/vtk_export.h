// Writes a rig's tet mesh (.vtu) and skeleton (.vtp) as VTK XML files for ParaView or the viewer.
#pragma once

#include <string>

#include "posewarp/api/rig.h"

namespace posewarp::api {

// Unstructured grid of tetrahedra in LPS mm. Point data: one weight array per bone segment ("w_<segment>"),
// "rigid" (1 where one segment dominates) and "centre_of_rotation" (3 components). Cell data: "class"
// (1 soft tissue, 2 + k bone segment k).
Status export_mesh_vtu(const Rig& rig, const std::string& path);

// Poly data: one point per segment centroid and per joint centre; lines from each parent segment's centroid to
// the joint and from the joint to the child's centroid. Point data "joint" (joint index, -1 for centroids) and
// "segment" (segment index, -1 for joints).
Status export_skeleton_vtp(const Rig& rig, const std::string& path);

}  // namespace posewarp::api
