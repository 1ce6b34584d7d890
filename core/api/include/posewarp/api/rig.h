// Rig: everything the expensive half of the pipeline produces, and the engine facade that builds it.
#pragma once

#include <map>
#include <optional>
#include <string>
#include <vector>

#include "posewarp/common/bone_substitutes.h"
#include "posewarp/common/compact_intensities.h"
#include "posewarp/common/label_map.h"
#include "posewarp/common/progress.h"
#include "posewarp/common/result.h"
#include "posewarp/common/rig_params.h"
#include "posewarp/common/row_packed.h"
#include "posewarp/common/skeleton.h"
#include "posewarp/common/surface_mesh.h"
#include "posewarp/common/tet_mesh.h"
#include "posewarp/common/volume.h"

namespace posewarp::api {

// What the weights do with tissue cut off from every bone (an island): attach it to the nearest bone, or fail.
using posewarp::IslandPolicy;

// Every knob of a rig build, validated together before any work starts.
struct BuildParams {
  SkeletonParams skeleton;
  BodyMaskParams body;
  SkinContactParams skin_contacts;  // body parts touching at rest are cut apart before meshing
  MeshParams mesh;
  WeightsParams weights;
  CorParams cor;
  SurfaceParams surfaces;
  bool tissue_surfaces = false;  // also extract a surface per soft-tissue label (bones and skin always)
};

Status validate(const BuildParams& params);
// Canonical JSON of the parameters (stored in the rig; part of its id).
std::string params_to_json(const BuildParams& params);

struct BuildInputs {
  LabelVolume labels;
  std::optional<IntensityVolume> ct;
  // Surfaces at rest (one per bone label, the skin, optionally tissues) and their embedding in the rest tets.
  std::vector<SurfaceMesh> surfaces;
  std::vector<Embedding> embeddings;       // on the labels' grid; joins the body mask and is kept for posing
  std::optional<LabelVolume> body;         // a user's body mask (non-zero = body), replacing the computed one
  LabelMap label_map;
  RigSpec spec;
  std::string labels_source;               // file names, for provenance only
  std::string ct_source;
};

// Where the time went and what each stage reported; not part of the rig's content hash.
struct Provenance {
  std::string software_version;
  std::vector<std::pair<std::string, double>> stage_seconds;  // in pipeline order
  std::string stats_json;                                      // per-stage statistics (mesh health, weights, cor)
  std::string labels_source;
  std::string ct_source;
};

struct Rig {
  ImageGeometry source_geometry;           // the grid the rig was built from (labels and CT)
  std::string labels_hash;                 // hashes of the input voxels (hex)
  std::string ct_hash;                     // empty without a CT
  LabelMap label_map;
  Skeleton skeleton;
  TetMesh mesh;
  SkinWeights weights;
  RotationCentres centres;
  std::string params_json;
  Provenance provenance;
  // The source volumes posing warps (kept in the rig so a pose needs nothing else); the CT in int16 where its values
  // fit (CompactIntensities: half a float volume's bytes).
  LabelVolume labels;
  std::optional<CompactIntensities> ct;
  // Surfaces at rest (one per bone label, the skin, optionally tissues) and their embedding in the rest tets.
  std::vector<SurfaceMesh> surfaces;
  std::vector<Embedding> embeddings;
  // What a pose engine would otherwise compute when it opens the rig (a second or more on a whole body): per source
  // voxel the tet that owns it at rest (the identity warp's owner) and the nearest-bone region of the skin-contact
  // guard, and the soft-tissue voxel a bone voxel's value is replaced by where soft tissue maps onto the bone. Made
  // by build_rig; empty (no substitutes) in a rig from before them, whose engine computes them. The owner and region
  // tables are kept on their rows' spans (-1, no tet and no region, off them): a body's air takes no bytes.
  RowPacked<int32_t> rest_owner;
  RowPacked<int16_t> body_region;
  std::optional<BoneSubstitutes> bone_substitute;
  // And what the engine reads of the tables and volumes, which creating it would otherwise cost a whole body a tenth
  // of a second: per tet the body region at its rest centroid (-1 outside the grid; the warp's skin-contact guard),
  // the labels' voxels per value (the report's counts before the pose), and the CT's lowest value (the posed CT's
  // floor). Made by build_rig (complete_rig); empty in a rig from before them, whose engine makes them.
  std::vector<int16_t> tet_region;
  std::map<Label, int64_t> rest_label_counts;
  std::optional<float> ct_lowest;
  // Per tet-mesh vertex, 1 where it lies on the mesh's skin (fem::skin_vertices: the report's skin penetration and the
  // soft tissue's contacts), which costs a whole body a tenth of a second; made by build_rig, empty in a rig from
  // before it (its engine makes it on first use).
  std::vector<uint8_t> skin_vertex;
  // Sections of a newer writer that this reader does not understand, kept verbatim so a re-save loses nothing.
  std::vector<std::pair<uint32_t, std::string>> unknown_sections;

  // Content-derived id, 64 hex digits: SHA-256 of the input volumes' grids and voxels (labels_hash, ct_hash), the
  // label map, the build parameters with the rig spec and the body mask (params_json) and the software version. The
  // same study built with the same inputs gets the same id, so a store can answer a second build without building.
  std::string id() const;
  // Bytes the rig holds in memory (volumes, mesh, weights, centres, surfaces), for a cache's byte budget.
  int64_t footprint_bytes() const;
};

// The id build_rig() would give these inputs, without building (hashing the volumes: milliseconds), so a store can
// answer a build it already has.
std::string rig_id_of(const BuildInputs& inputs, const BuildParams& params);

// Builds a rig: body mask, skeleton, classes, mesh (with health checks), weights and centres of rotation.
// Before any of it, what each volume is for (check_labels_look_like_labels, and a CT that is not labels):
// a CT given as the labels, or labels given as the CT, is INVALID_ARGUMENT naming both inputs (labels_source,
// ct_source).
Result<Rig> build_rig(const BuildInputs& inputs, const BuildParams& params, const ProgressHooks& hooks);

// A 64-bit hash of a buffer as 16 hex digits (FNV-1a over 8-byte words; stable across platforms of one endianness).
std::string hash_bytes(const void* data, size_t size, uint64_t seed = 0);

}  // namespace posewarp::api
