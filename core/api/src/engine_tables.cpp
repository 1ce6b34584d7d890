#include "engine_tables.h"

#include "posewarp/api/rig_file.h"

#include "posewarp/fem/soft_tissue.h"
#include "posewarp/labels/body.h"
#include "posewarp/resample/rigid_bones.h"
#include "posewarp/resample/tet_warp.h"
#include "posewarp/rig/skin_contacts.h"

namespace posewarp::api::internal {

Status make_engine_tables(Rig& rig, const ProgressHooks& hooks) {
  const ImageGeometry& g = rig.labels.geometry();
  POSEWARP_ASSIGN_OR_RETURN(
      resample::TetWarp identity,
      resample::TetWarp::build({.rest = rig.mesh, .posed = rig.mesh.vertices, .source = g, .output = g}, hooks));
  rig.rest_owner = RowPacked<int32_t>::pack(identity.owner().data(), g.size, -1);
  // Body regions for the skin-contact guard: the body as a build with the default body parameters makes it.
  POSEWARP_ASSIGN_OR_RETURN(const LabelVolume body,
                            labels::body_mask(rig.label_map, rig.labels, rig.ct ? &*rig.ct : nullptr));
  POSEWARP_ASSIGN_OR_RETURN(rig::BodyRegions regions, rig::body_regions(rig.skeleton, rig.labels, body));
  rig.body_region = RowPacked<int16_t>::pack(regions.segment.data(), g.size, int16_t{-1});
  std::vector<std::vector<Label>> segment_labels;
  for (const rig::Segment& segment : rig.skeleton.segments) segment_labels.push_back(segment.labels);
  POSEWARP_ASSIGN_OR_RETURN(resample::BoneVoxels bones, resample::bone_voxels(rig.labels, segment_labels));
  rig.bone_substitute = bones.sparse();
  return ok_status();
}

}  // namespace posewarp::api::internal

namespace posewarp::api {
namespace {

bool lacks_tables(const Rig& rig) {
  return rig.rest_owner.empty() || rig.body_region.empty() || !rig.bone_substitute;
}

bool lacks_skin(const Rig& rig) {
  return rig.skin_vertex.empty();
}

}  // namespace

std::string missing_from_rig(const Rig& rig) {
  std::string what = lacks_tables(rig) ? "the engine's per-voxel tables (OWNR, REGN, SUBS)" : "";
  if (lacks_skin(rig)) what += std::string(what.empty() ? "" : " and ") + "the mesh's skin vertices (SKIN)";
  return what;
}

Result<bool> complete_rig(Rig& rig, const ProgressHooks& hooks) {
  if (rig.labels.empty()) {
    return failed_precondition_error("the rig holds no source volume to make its tables from; rebuild it");
  }
  const bool tables = lacks_tables(rig);
  const bool skin = lacks_skin(rig);
  if (tables) POSEWARP_RETURN_IF_ERROR(internal::make_engine_tables(rig, hooks));
  if (skin) rig.skin_vertex = fem::skin_vertices(rig.mesh);
  return tables || skin;
}

}  // namespace posewarp::api
