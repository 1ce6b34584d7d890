// PoseEngine's private state (what PoseEngine::create prepares once per rig, and what the first request that needs it
// adds), shared by the engine's steps in pose_engine.cpp and its report in pose_report.cpp.
#pragma once

#include <map>
#include <mutex>
#include <vector>

#include "posewarp/api/pose_engine.h"
#include "posewarp/fem/soft_tissue.h"
#include "posewarp/mapping/tet_locator.h"
#include "posewarp/resample/tet_warp.h"
#include "posewarp/skinning/tet_maps.h"

namespace posewarp::api {

// The preview's share of the rig: the tets holding a surface vertex, on their own vertices, with those vertices'
// weights and centres, and the surfaces embedded in them.
struct PreviewRig {
  TetMesh mesh;
  std::vector<int32_t> rig_vertex;  // preview vertex -> the rig mesh's vertex
  SkinWeights weights;
  RotationCentres centres;
  std::vector<mapping::Embedding> embeddings;
};

// The fem method's share (its mesh topology, the report's skin vertices, the last solve), made by the first request
// that needs it and shared by copies of the engine.
struct FemState {
  std::once_flag once;
  fem::Topology topology;
  std::once_flag skin_once;
  std::vector<uint8_t> skin;  // the mesh's skin vertices (skin_of), for the report and the topology
  fem::SolveCache cache;      // the last solve's factored system: a slider's next pose frees the same vertices
};

struct PoseEngine::Prepared {
  Rig rig;
  skinning::RestTetFrames frames;
  std::map<Label, int64_t> rest_label_counts;  // the report's "before" counts, once
  // TetWarp::owner() of the identity warp, packed on its rows' spans (-1 off them): the warp's lookups, forward fields.
  RowPacked<int32_t> rest_owner;
  // Per source row, where the labels differ from 0: a turned background's lookups skip the air.
  resample::RowSpans label_spans;
  resample::BoneVoxels bone_voxels;  // which source voxel is which bone: bones rigid at voxel level
  RowPacked<int16_t> region;         // per source voxel: nearest-bone region, -1 off the body (skin contacts)
  std::vector<int16_t> tet_region;   // per tet: the region at its rest centroid
  std::vector<uint8_t> separated;    // regions that must not show each other's tissue
  float ct_minimum = 0.0f;           // the CT's lowest value: the warp's background is never below it
  // The preview's share (preview_of), made by the first preview: a command-line pose never needs it.
  mutable std::once_flag preview_once;
  mutable PreviewRig preview;
  mutable FemState fem;
};

namespace internal {

// The mesh's skin vertices (fem::skin_vertices): the report's penetration count and the fem topology share them. The
// rig file keeps them (section SKIN); for a rig from before it, the first request that needs them makes them.
const std::vector<uint8_t>& skin_of(const PoseEngine::Prepared& p);

}  // namespace internal
}  // namespace posewarp::api
