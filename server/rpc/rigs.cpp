// GetRig, ListRigs, DeleteRig, GetRigAssets: the store's rigs and their loaded engines (engine_cache.h).
#include <algorithm>
#include <set>

#include "convert.h"
#include "posewarp/api/rig_info.h"
#include "service.h"

namespace posewarp::server {
namespace {

// One surface of a rig as an asset: VTP bytes or the proto's mesh, with its role for a viewer.
Result<v1::RigAsset> surface_asset(const SurfaceMesh& mesh, const std::string& role, v1::AssetFormat format) {
  v1::RigAsset part;
  if (format == v1::ASSET_FORMAT_VTP) {
    POSEWARP_ASSIGN_OR_RETURN(std::string vtp, api::surface_to_vtp_bytes(mesh));
    part.mutable_vtp()->set_name(mesh.name);
    part.mutable_vtp()->set_label(mesh.label);
    part.mutable_vtp()->set_data(std::move(vtp));
    part.mutable_vtp()->set_role(role);
  } else {
    put_surface(mesh, true, part.mutable_surface());
    part.mutable_surface()->set_role(role);
  }
  return part;
}

}  // namespace

grpc::Status PosewarpService::GetRig(grpc::ServerContext* context, const v1::GetRigRequest* request,
                                     v1::Rig* response) {
  Call call(frame_, context, "GetRig", request->rig_id());
  if (call.refused()) return call.refusal();
  Result<RigRecord> stored = store_->rig(request->rig_id());
  if (!stored.ok()) return call.done(stored.status());
  Result<EngineCache::Engine> engine = engines_.get(request->rig_id());
  if (!engine.ok()) return call.done(engine.status());
  put_rig(*stored, (*engine)->rig(), response);
  return call.done(ok_status());
}

grpc::Status PosewarpService::ListRigs(grpc::ServerContext* context, const v1::ListRigsRequest* request,
                                       v1::ListRigsResponse* response) {
  Call call(frame_, context, "ListRigs");
  if (call.refused()) return call.refusal();
  const int page = request->page_size() <= 0 ? 50 : std::min(request->page_size(), 1000);
  if (!request->page_token().empty() && !api::is_hex_id(request->page_token())) {
    return call.done(invalid_argument_error("page_token is the next_page_token of a previous answer"));
  }
  Result<std::vector<RigRecord>> rows = store_->rigs(request->page_token(), page + 1);
  if (!rows.ok()) return call.done(rows.status());
  for (const RigRecord& row : *rows) {
    if (response->rigs_size() == page) {
      response->set_next_page_token(response->rigs(page - 1).id());
      break;
    }
    put_rig_row(row, response->add_rigs());
  }
  return call.done(ok_status());
}

grpc::Status PosewarpService::DeleteRig(grpc::ServerContext* context, const v1::GetRigRequest* request,
                                        v1::DeleteRigResponse*) {
  Call call(frame_, context, "DeleteRig", request->rig_id());
  if (call.refused()) return call.refusal();
  engines_.evict(request->rig_id());  // poses holding the engine finish with it; new ones find no rig
  return call.done(store_->delete_rig(request->rig_id()));
}

grpc::Status PosewarpService::GetRigAssets(grpc::ServerContext* context, const v1::GetRigAssetsRequest* request,
                                           grpc::ServerWriter<v1::RigAsset>* writer) {
  Call call(frame_, context, "GetRigAssets", request->rig_id());
  if (call.refused()) return call.refusal();
  if (!api::is_hex_id(request->rig_id()))
    return call.done(invalid_argument_error("a rig id is 64 lowercase hex digits"));
  Result<EngineCache::Engine> engine = engines_.get(request->rig_id());
  if (!engine.ok()) return call.done(engine.status());
  const api::Rig& rig = (*engine)->rig();
  v1::RigAsset asset;
  put_skeleton(rig, asset.mutable_skeleton());
  if (!call.write(writer, asset)) return call.done(client_gone());
  // Each surface's role, for a viewer: a bone segment's label, the skin (label 0), or another tissue.
  const std::vector<std::string> roles = api::surface_roles(rig);
  for (size_t i = 0; i < rig.surfaces.size(); ++i) {
    Result<v1::RigAsset> part = surface_asset(rig.surfaces[i], roles[i], request->format());
    if (!part.ok()) return call.done(part.status());
    if (!call.write(writer, *part)) return call.done(client_gone());
  }
  return call.done(ok_status());
}

}  // namespace posewarp::server
