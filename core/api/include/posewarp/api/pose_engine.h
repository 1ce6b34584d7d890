// PoseEngine: answers pose requests on a loaded rig (skin the tet mesh, warp labels and CT, deform surfaces,
// report), with everything that does not depend on the pose computed once.
#pragma once

#include <Eigen/Core>

#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "posewarp/api/rig.h"
#include "posewarp/api/types.h"
#include "posewarp/common/pose.h"
#include "posewarp/common/progress.h"
#include "posewarp/common/quality_report.h"
#include "posewarp/common/surface_mesh.h"
#include "posewarp/common/volume.h"

namespace posewarp::api {

// The fem method's solve, for a request that trades time for how far it converges (the others ignore it). 0 takes
// the engine's default.
struct FemOptions {
  int max_iterations = 0;      // 1 to 10000; default 20
  double volume_weight = 0.0;  // how much more keeping volume counts than keeping shape, up to 1e6; default 100
  bool contact = false;        // push skin out of the tissue facing it (fem::FemParams::contact)
  // Then this many Newton iterations of the nonlinear material with a volume per compressed vertex star and no new
  // folds (fem::solve_nonlinear with its barrier), 0 (none) to 1000; default 3. They give back the volume a bent
  // hip loses to the solve's per-tet volume (README: fem), at 0.1-0.2 s an iteration on a body's hip. They have no
  // contact term: skin that `contact` kept out of the tissue facing it may pass back in.
  int refine_iterations = 3;
};

struct PoseRequest {
  Pose pose;
  // Where the pose came from, for messages ("pose file 'knee.json'"): a pose that does not fit the rig is
  // INVALID_ARGUMENT with this in front of what is wrong.
  std::string pose_source;
  Method method = Method::kCor;
  FemOptions fem;
  GridPolicy grid = GridPolicy::kInput;
  std::optional<ImageGeometry> given_grid;  // for GridPolicy::kGiven
  bool want_labels = true;
  bool want_ct = true;
  bool want_surfaces = true;
  std::vector<SurfaceMesh> extra_surfaces;  // a user's meshes in rest space, embedded for this request
  bool want_fields = false;                 // inverse (output grid) and forward (source grid) displacement fields
  Interpolation ct_interpolation = Interpolation::kLinear;
  OutputLimits limits;
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
  std::vector<SurfaceMesh> surfaces;  // posed rig surfaces, then posed extra surfaces, in order
  std::vector<float> inverse_field;   // output grid, x_source - x_output (mm)
  std::vector<float> forward_field;   // source grid, x_posed - x_source (mm)
  Eigen::MatrixXd posed_vertices;     // #V x 3
  std::vector<Eigen::Matrix3d> segment_rotation;
  std::vector<Eigen::Vector3d> segment_translation;
  QualityReport report;
};

// The report as JSON (DESIGN.md section 9): what the CLI writes with --report-out and the server sends.
std::string report_to_json(const QualityReport& report);

// What a pose will produce and cost, known before anything large is allocated.
struct PosePlan {
  ImageGeometry output_grid;  // empty when no volume is wanted
  int64_t output_bytes = 0;   // the warp's owner map, labels, CT and fields (the bulk of a pose's memory)
  int64_t budget_bytes = 0;   // the request's max_output_bytes, or half the machine's memory
};

// The posed rest surfaces of a preview, in the rig's surface order (vertex positions only: the topology is the
// rig's, rig().surfaces[i].triangles).
struct PreviewResult {
  std::vector<Eigen::MatrixXd> surface_vertices;  // #P_i x 3, LPS mm
  std::vector<Eigen::Vector3d> joint_centres;     // posed, in the skeleton's joint order, LPS mm
};

// Copies share one prepared rig (and the fem method's solver state), so a cache may hand them out freely.
class PoseEngine {
 public:
  // Precomputes the rest tet frames, the rest ownership of the source grid and the rest label counts.
  static Result<PoseEngine> create(Rig rig, const ProgressHooks& hooks = {});

  const Rig& rig() const;
  Result<PoseResult> pose(const PoseRequest& request, const ProgressHooks& hooks = {}) const;
  // The output grid and the bytes pose() will allocate for it: the pose is validated and, for a grown grid, the
  // tet mesh skinned (milliseconds). RESOURCE_EXHAUSTED when the bytes are over the budget, so a server refuses
  // such a request before it queues; pose() makes the same check.
  Result<PosePlan> plan(const PoseRequest& request) const;
  // The fast path for sliders: the rig's surfaces posed, nothing else. Only the tet vertices that hold a surface
  // vertex are skinned (prepared once in create()); no volume, no report. `fem` solves the whole bent tissue, a few
  // iterations per call going on from the last call's (as many as fit in 70 ms), so its surfaces depend on the calls
  // before and on the machine's speed; a pose's never do.
  Result<PreviewResult> preview(const Pose& pose, Method method) const;

  // What create() prepares (frames, ownership, bone voxels, regions, the preview's share, the fem solver's state),
  // private to pose_engine.cpp.
  struct Prepared;

 private:
  explicit PoseEngine(std::shared_ptr<const Prepared> prepared) : prepared_(std::move(prepared)) {}
  std::shared_ptr<const Prepared> prepared_;
};

}  // namespace posewarp::api
