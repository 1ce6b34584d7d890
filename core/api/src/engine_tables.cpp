#include "engine_tables.h"

#include "posewarp/api/rig_file.h"

#include "posewarp/common/parallel.h"
#include "posewarp/fem/soft_tissue.h"
#include "posewarp/labels/body.h"
#include "posewarp/report/quality_report.h"
#include "posewarp/resample/rigid_bones.h"
#include "posewarp/resample/tet_warp.h"
#include "posewarp/rig/skin_contacts.h"

#include <algorithm>
#include <cmath>
#include <limits>
#include <mutex>

namespace posewarp::api::internal {

namespace {

// Per tet: the body region at its rest centroid (-1 outside the grid).
std::vector<int16_t> tet_regions(const Rig& rig) {
  const ImageGeometry& g = rig.labels.geometry();
  const PhysicalToIndex to_index(g);
  std::vector<int16_t> tet_region(static_cast<size_t>(rig.mesh.tet_count()), -1);
  parallel_for(0, rig.mesh.tet_count(), 4096, [&](int64_t begin, int64_t end) {
    for (int64_t t = begin; t < end; ++t) {
      Eigen::Vector3d c = Eigen::Vector3d::Zero();
      for (int q = 0; q < 4; ++q) c += rig.mesh.vertices.row(rig.mesh.tets(t, q)).transpose();
      const Vec3 u = to_index({c.x() / 4, c.y() / 4, c.z() / 4});
      // Rounded only within the grid's reach: llround of a value beyond int64 (a damaged rig's far vertex) is
      // undefined; such a centre lies in no voxel.
      auto voxel = [](double x) { return std::abs(x) < 1e15 ? std::llround(x) : int64_t{-1}; };
      const int64_t i = voxel(u[0]), j = voxel(u[1]), k = voxel(u[2]);
      if (rig.labels.contains(i, j, k)) tet_region[static_cast<size_t>(t)] = rig.body_region.at(i, j, k);
    }
  });
  return tet_region;
}

// The lowest voxel of a volume, over every thread.
template <typename T>
float lowest_value(const Volume<T>& volume) {
  std::mutex merge;
  float lowest = std::numeric_limits<float>::max();
  parallel_for(0, volume.voxel_count(), int64_t{1} << 20, [&](int64_t begin, int64_t end) {
    const float low = static_cast<float>(*std::min_element(volume.data() + begin, volume.data() + end));
    const std::lock_guard<std::mutex> lock(merge);
    lowest = std::min(lowest, low);
  });
  return lowest;
}

}  // namespace

bool lacks_summary(const Rig& rig) {
  return static_cast<int64_t>(rig.tet_region.size()) != rig.mesh.tet_count() ||
         (rig.rest_label_counts.empty() && !rig.labels.empty()) || (rig.ct && !rig.ct_lowest);
}

void make_engine_summary(Rig& rig) {
  if (static_cast<int64_t>(rig.tet_region.size()) != rig.mesh.tet_count()) rig.tet_region = tet_regions(rig);
  if (rig.rest_label_counts.empty()) rig.rest_label_counts = report::label_counts(rig.labels);
  if (rig.ct && !rig.ct_lowest) {
    rig.ct_lowest = rig.ct->empty() ? 0.0f : rig.ct->visit([](const auto& ct) { return lowest_value(ct); });
  }
}

Status make_engine_tables(Rig& rig, const ProgressHooks& hooks) {
  const ImageGeometry& g = rig.labels.geometry();
  POSEWARP_ASSIGN_OR_RETURN(
      resample::TetWarp identity,
      resample::TetWarp::build({.rest = rig.mesh, .posed = rig.mesh.vertices, .source = g, .output = g}, hooks));
  rig.rest_owner = RowPacked<int32_t>::pack(identity.owner().data(), g.size, -1);
  // Body regions for the skin-contact guard: the body as a build with the default body parameters makes it.
  // (A rig without these tables is one from before them: its CT in floats for the mask, for a moment.)
  const std::optional<IntensityVolume> ct = rig.ct ? std::optional<IntensityVolume>(rig.ct->to_float()) : std::nullopt;
  POSEWARP_ASSIGN_OR_RETURN(const LabelVolume body, labels::body_mask(rig.label_map, rig.labels, ct ? &*ct : nullptr));
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
  if (internal::lacks_summary(rig)) what += std::string(what.empty() ? "" : " and ") + "the engine's summary (ENGN)";
  if (lacks_skin(rig)) what += std::string(what.empty() ? "" : " and ") + "the mesh's skin vertices (SKIN)";
  return what;
}

Result<bool> complete_rig(Rig& rig, const ProgressHooks& hooks) {
  if (rig.labels.empty()) {
    return failed_precondition_error("the rig holds no source volume to make its tables from; rebuild it");
  }
  const bool tables = lacks_tables(rig);
  const bool summary = internal::lacks_summary(rig);
  const bool skin = lacks_skin(rig);
  if (tables) POSEWARP_RETURN_IF_ERROR(internal::make_engine_tables(rig, hooks));
  if (summary) internal::make_engine_summary(rig);
  if (skin) rig.skin_vertex = fem::skin_vertices(rig.mesh);
  return tables || summary || skin;
}

}  // namespace posewarp::api
