// What a pose engine derives from its rig's volumes and mesh, one value per source voxel, and costs a whole body a
// second or more: the identity warp's owner tet, the nearest-bone region and the bone voxels' soft-tissue
// substitutes. build_rig makes them and the rig file keeps them (sections OWNR, REGN and SUBS), so that opening a rig
// and creating its engine is reading; a rig from an earlier version has none, and PoseEngine::create makes them.
#pragma once

#include "posewarp/api/rig.h"
#include "posewarp/common/progress.h"

namespace posewarp::api::internal {

// Fills rig.rest_owner, rig.body_region and rig.bone_substitute from the rest of the rig (its labels, CT, skeleton
// and mesh). complete_rig (rig_file.h) adds the skin vertices to them.
Status make_engine_tables(Rig& rig, const ProgressHooks& hooks);

// Whether the engine's summary of the tables and volumes (rig.tet_region, rest_label_counts, ct_lowest) is missing
// or does not fit the mesh; make_engine_summary fills in what is (from the region table, the labels and the CT) and
// leaves the rest.
bool lacks_summary(const Rig& rig);
void make_engine_summary(Rig& rig);

}  // namespace posewarp::api::internal
