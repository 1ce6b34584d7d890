// Mesher: labelled image (0 outside, 1 soft tissue, 2 + k bone segment k) -> tetrahedra, behind an interface.
#pragma once

#include <array>
#include <cstdint>
#include <memory>
#include <string>
#include <vector>

#include "posewarp/common/progress.h"
#include "posewarp/common/result.h"
#include "posewarp/common/rig_params.h"
#include "posewarp/common/tet_mesh.h"
#include "posewarp/common/volume.h"

namespace posewarp::mesh {

using posewarp::MeshParams;  // posewarp/common/rig_params.h

// INVALID_ARGUMENT naming the field and its valid range.
Status validate(const MeshParams& params);

// What the checks found about a mesh.
struct MeshHealth {
  Index3 downsample_factor{1, 1, 1};
  std::vector<int64_t> tets_per_class;          // index = class (0 unused, 1 soft tissue, 2 + k bone k)
  std::vector<double> voxel_volume_ml;          // per class, from the class volume
  std::vector<double> mesh_volume_ml;           // per class, from the tets
  double max_bone_volume_error = 0.0;           // max over bones of |mesh - voxels| / voxels
  double body_volume_error = 0.0;               // |mesh - voxels| / voxels over the whole body
  int body_components = 0;                      // connected pieces of the mesh (through shared vertices)
  int64_t degenerate_tets = 0;                  // volume quality below 1e-4 (1 = regular tet)
  double min_tet_quality = 1.0;
  std::vector<std::string> lost_segments;       // bone segments without a single tet
  bool sequential_fallback = false;             // the watchdog stopped the parallel mesher
  int64_t estimated_vertices = 0;               // the estimate checked against max_vertices before refining
  std::vector<std::string> warnings;            // what a user should know about how the mesh was made
};

class Mesher {
 public:
  virtual ~Mesher() = default;
  virtual std::string name() const = 0;
  // `classes` holds 0 / 1 / 2 + k; `segment_count` bone segments are expected. The mesh is in physical LPS mm.
  virtual Result<TetMesh> mesh(const LabelVolume& classes, int segment_count, const MeshParams& params,
                               const ProgressHooks& hooks, MeshHealth* health) = 0;
};

// The CGAL Mesh_3 backend (GPL-3.0-or-later).
std::unique_ptr<Mesher> make_cgal_mesher();

// Downsamples a class volume by `factor` per axis with the bone-precedence vote; the grid keeps its physical
// extent (block centres become voxel centres).
LabelVolume downsample_classes(const LabelVolume& classes, const Index3& factor);
// The smallest isotropic-ish integer factor that brings the voxel count within `budget`.
Index3 downsample_factor_for(const ImageGeometry& geometry, int64_t budget);

// Relabels as soft tissue every bone tet that touches a vertex owned by another bone segment (a vertex's owner is
// the segment with most incident tets, ties to the lower index: the rule the weights use). A vertex shared by two
// bones cannot follow both, so without this the tets bridging a thin joint space would tear. Returns the number of
// tets relabelled.
int64_t separate_bone_segments(TetMesh& mesh);

// Splits every edge whose two vertices belong to bone tets of two different segments (and to no segment in common)
// at its midpoint: each tet holding such an edge becomes two, the new vertex in soft tissue only, so that no soft
// tet keeps corners on two bones across an edge. Such tets fill the gap between two bones (a joint's articular
// space), where bones fix every corner and a bent joint folds them whatever moves the tissue; after the split a
// solve can move their middle. Orientation and classes are kept; returns the number of edges split. Run after
// separate_bone_segments (whose bone tets have no such edge).
int64_t split_bone_gaps(TetMesh& mesh);

// Checks a finished mesh against its class volume: fills `health` and fails (FAILED_PRECONDITION, naming the
// segments) when a bone segment got no tets, rather than dropping a bone silently.
Status check_mesh_health(const TetMesh& mesh, const LabelVolume& classes, const std::vector<std::string>& segment_names,
                         MeshHealth* health);

}  // namespace posewarp::mesh
