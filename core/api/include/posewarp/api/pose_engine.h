// PoseEngine: answers pose requests on a loaded rig (skin the tet mesh, warp labels and CT, deform surfaces,
// report), with everything that does not depend on the pose computed once.
#pragma once

#include <functional>
#include <map>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "posewarp/api/rig.h"
#include "posewarp/pose/pose.h"
#include "posewarp/report/quality_report.h"
#include "posewarp/resample/tet_warp.h"
#include "posewarp/skinning/skinning.h"
#include "posewarp/skinning/tet_maps.h"

namespace posewarp::api {

// How a request names the output grid (the input grid, grown to hold the posed body, or a given grid).
using resample::GridPolicy;

// The fem method's solve, for a request that trades time for how far it converges (the others ignore it). 0 takes
// the engine's default.
struct FemOptions {
  int max_iterations = 0;      // 1 to 10000; default 100
  double volume_weight = 0.0;  // how much more keeping volume counts than keeping shape, up to 1e6; default 100
};

struct PoseRequest {
  pose::Pose pose;
  skinning::Method method = skinning::Method::kCor;
  FemOptions fem;
  resample::GridPolicy grid = resample::GridPolicy::kInput;
  std::optional<ImageGeometry> given_grid;  // for GridPolicy::kGiven
  bool want_labels = true;
  bool want_ct = true;
  bool want_surfaces = true;
  std::vector<surface::SurfaceMesh> extra_surfaces;  // a user's meshes in rest space, embedded for this request
  bool want_fields = false;                 // inverse (output grid) and forward (source grid) displacement fields
  resample::Interpolation ct_interpolation = resample::Interpolation::kLinear;
  resample::ResampleParams resample;
  // When set, each volume goes here as soon as it is complete instead of into PoseResult (whose labels / ct then
  // stay empty), while pose() goes on with the rest (the CT, the label report, fields, ...): a server sends it from
  // a thread of its own. Called on the calling thread; the engine only reads the volume afterwards.
  std::function<void(std::shared_ptr<const LabelVolume>)> labels_ready;
  std::function<void(std::shared_ptr<const IntensityVolume>)> ct_ready;
};

struct PoseResult {
  ImageGeometry output_grid;
  std::optional<LabelVolume> labels;
  std::optional<IntensityVolume> ct;
  std::vector<surface::SurfaceMesh> surfaces;  // posed rig surfaces, then posed extra surfaces, in order
  std::vector<float> inverse_field;         // output grid, x_source - x_output (mm)
  std::vector<float> forward_field;         // source grid, x_posed - x_source (mm)
  Eigen::MatrixXd posed_vertices;           // #V x 3
  std::vector<Eigen::Matrix3d> segment_rotation;
  std::vector<Eigen::Vector3d> segment_translation;
  report::QualityReport report;
};

// What a pose will produce and cost, known before anything large is allocated.
struct PosePlan {
  ImageGeometry output_grid;    // empty when no volume is wanted
  int64_t output_bytes = 0;     // the warp's owner map, labels, CT and fields (the bulk of a pose's memory)
  int64_t budget_bytes = 0;     // the request's max_output_bytes, or half the machine's memory
};

// The posed rest surfaces of a preview, in the rig's surface order (vertex positions only: the topology is the
// rig's, rig().surfaces[i].triangles).
struct PreviewResult {
  std::vector<Eigen::MatrixXd> surface_vertices;  // #P_i x 3, LPS mm
  std::vector<Eigen::Vector3d> joint_centres;     // posed, in the skeleton's joint order, LPS mm
};

class PoseEngine {
 public:
  // Precomputes the rest tet frames, the rest ownership of the source grid and the rest label counts.
  static Result<PoseEngine> create(Rig rig, const ProgressHooks& hooks = {});

  const Rig& rig() const { return rig_; }
  Result<PoseResult> pose(const PoseRequest& request, const ProgressHooks& hooks = {}) const;
  // The output grid and the bytes pose() will allocate for it: the pose is validated and, for a grown grid, the
  // tet mesh skinned (milliseconds). RESOURCE_EXHAUSTED when the bytes are over the budget, so a server refuses
  // such a request before it queues; pose() makes the same check.
  Result<PosePlan> plan(const PoseRequest& request) const;
  // The fast path for sliders: the rig's surfaces posed, nothing else. Only the tet vertices that hold a surface
  // vertex are skinned (prepared once in create()); no volume, no report.
  Result<PreviewResult> preview(const pose::Pose& pose, skinning::Method method) const;

 private:
  // The bodies of create() and pose(), which run them behind the exception wall.
  static Result<PoseEngine> create_unguarded(Rig rig, const ProgressHooks& hooks);
  Result<PoseResult> pose_unguarded(const PoseRequest& request, const ProgressHooks& hooks) const;
  // The plan for an output grid; RESOURCE_EXHAUSTED over the budget.
  Result<PosePlan> check_output_budget(const PoseRequest& request, const ImageGeometry& grid) const;
  PoseEngine() = default;
  Rig rig_;
  skinning::RestTetFrames frames_;
  std::map<Label, int64_t> rest_label_counts_;  // the report's "before" counts, once
  std::vector<int32_t> rest_owner_;  // TetWarp::owner() of the identity warp: the warp's lookups, forward fields
  resample::BoneVoxels bone_voxels_;  // which source voxel is which bone: bones rigid at voxel level
  std::vector<int16_t> region_;       // per source voxel: nearest-bone region (skin contacts)
  std::vector<int16_t> tet_region_;   // per tet: the region at its rest centroid
  std::vector<uint8_t> separated_;    // regions that must not show each other's tissue
  float ct_minimum_ = 0.0f;          // the CT's lowest value: the warp's background is never below it
  // The preview's share of the rig: the tets holding a surface vertex, on their own vertices, with those vertices'
  // weights and centres, and the surfaces embedded in them.
  struct PreviewRig {
    TetMesh mesh;
    SkinWeights weights;
    RotationCentres centres;
    std::vector<mapping::Embedding> embeddings;
  };
  PreviewRig preview_;
  // The fem method's share (its mesh topology), made by the first fem request and shared by copies of the engine.
  struct Fem;
  std::shared_ptr<Fem> fem_;
  // The posed tet vertices of a method: skinning, then for fem the soft tissue's steady state from CoR.
  Result<Eigen::MatrixXd> posed_vertices(skinning::Method method, const skinning::SegmentTransforms& segments,
                                         const ProgressHooks& hooks) const;
  // The soft tissue's steady state from skinned (CoR) vertices. With `max_iterations` (a preview's), at most that
  // many, going on from where the last solve on the same free vertices ended; 0: the solve's own, from the warm start.
  Result<Eigen::MatrixXd> soft_tissue(const Eigen::MatrixXd& warm, const skinning::SegmentTransforms& segments,
                                      const ProgressHooks& hooks, int max_iterations = 0,
                                      const FemOptions& options = {}) const;
};

}  // namespace posewarp::api
