// PoseEngine: forward kinematics, skinning, tet maps, the volume warp and the quality report, timed per stage.
// A pose runs as numbered steps (pose_unguarded), each a function of its own over what create() prepared.
#include "posewarp/api/pose_engine.h"

#include "engine_state.h"
#include "engine_tables.h"
#include "pose_report.h"
#include "posewarp/common/exception_wall.h"
#include "posewarp/common/parallel.h"
#include "posewarp/common/stopwatch.h"
#include "posewarp/fem/soft_tissue.h"
#include "posewarp/labels/body.h"
#include "posewarp/labels/label_map.h"
#include "posewarp/mapping/tet_locator.h"
#include "posewarp/pose/forward_kinematics.h"
#include "posewarp/report/quality_report.h"
#include "posewarp/resample/tet_warp.h"
#include "posewarp/rig/skeleton.h"
#include "posewarp/rig/skin_contacts.h"
#include "posewarp/skinning/skinning.h"
#include "posewarp/skinning/tet_maps.h"

#include <Eigen/Dense>

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <mutex>
#include <unordered_map>
#include <utility>

namespace posewarp::api {

namespace {

// The api's names for the stages' settings.
skinning::Method stage_method(Method method) {
  switch (method) {
    case Method::kDqs: return skinning::Method::kDqs;
    case Method::kLbs: return skinning::Method::kLbs;
    case Method::kFem: return skinning::Method::kFem;
    case Method::kCor: break;
  }
  return skinning::Method::kCor;
}

resample::GridPolicy stage_grid(GridPolicy grid) {
  switch (grid) {
    case GridPolicy::kGrow: return resample::GridPolicy::kGrow;
    case GridPolicy::kGiven: return resample::GridPolicy::kGiven;
    case GridPolicy::kInput: break;
  }
  return resample::GridPolicy::kInput;
}

resample::ResampleParams stage_resample(const OutputLimits& limits) {
  resample::ResampleParams params;
  params.max_output_voxels = limits.max_voxels;
  params.max_output_bytes = limits.max_bytes;
  return params;
}

}  // namespace

std::string report_to_json(const QualityReport& report) {
  return report::to_json(report);
}

std::string_view method_name(Method method) {
  return skinning::method_name(stage_method(method));
}

Result<Method> method_from_name(std::string_view name) {
  POSEWARP_ASSIGN_OR_RETURN(const skinning::Method method, skinning::method_from_name(name));
  for (const Method m : {Method::kCor, Method::kDqs, Method::kLbs, Method::kFem}) {
    if (stage_method(m) == method) return m;
  }
  return invalid_argument_error("unknown method '" + std::string(name) + "'");
}

const Rig& PoseEngine::rig() const {
  return prepared_->rig;
}

namespace internal {

const std::vector<uint8_t>& skin_of(const PoseEngine::Prepared& p) {
  if (static_cast<int64_t>(p.rig.skin_vertex.size()) == p.rig.mesh.vertex_count()) return p.rig.skin_vertex;
  std::call_once(p.fem.skin_once, [&] { p.fem.skin = fem::skin_vertices(p.rig.mesh); });
  return p.fem.skin;
}

}  // namespace internal

namespace {

using Prepared = PoseEngine::Prepared;
using namespace internal;

// The segments' rigid transforms as the skinning takes them.
skinning::SegmentTransforms segment_transforms(const std::vector<pose::RigidTransform>& transforms) {
  skinning::SegmentTransforms segments;
  for (const pose::RigidTransform& t : transforms) {
    segments.rotation.push_back(t.rotation);
    segments.translation.push_back(t.translation);
  }
  return segments;
}

// The solve's parameters for a request's options (0: the default); INVALID_ARGUMENT naming the option out of range.
Result<fem::FemParams> fem_params(const FemOptions& options) {
  fem::FemParams params;
  if (options.max_iterations != 0) params.max_iterations = options.max_iterations;
  if (options.volume_weight != 0.0) params.volume_weight = options.volume_weight;
  params.contact = options.contact;
  POSEWARP_RETURN_IF_ERROR(fem::validate(params));
  if (options.refine_iterations < 0 || options.refine_iterations > 1000) {
    return invalid_argument_error("fem refine_iterations must be in [0, 1000], got " +
                                  std::to_string(options.refine_iterations));
  }
  return params;
}

// The refinement after the projective solve (FemOptions::refine_iterations): a star volume of 100 with 1 per tet
// and a barrier of 10 (from J = 0.7), which posewarp_fem_probe measured on the body phantom's hip, knee, elbow and
// shoulder at 90 degrees. It moves the bent tissue within 2 edges of a star the solve left below 0.9 of its volume,
// the rest held where the solve put it, and only the stars the solve left compressed (below 1) keep their volume:
// at a hip a fifth of the bent tissue, with a sparser matrix than every star's, for more volume in each iteration
// (README: fem).
fem::NonlinearParams refine_params(int iterations) {
  fem::NonlinearParams params;
  params.tet_volume_weight = 1.0;
  params.star_volume_weight = 100.0;
  params.barrier_weight = 10.0;
  params.max_iterations = iterations;
  params.margin_mm = 0.0;
  params.region_below = 0.9;
  params.region_rings = 2;
  params.star_below = 1.0;
  return params;
}

// Restricts the rig to what its surfaces need: their tets, renumbered, on their vertices, renumbered.
void prepare_preview(const Rig& rig, PreviewRig& preview) {
  // New numbers in the order of first use (-1: not used yet).
  std::vector<int32_t> tet_index(static_cast<size_t>(rig.mesh.tet_count()), -1);
  std::vector<int32_t> vertex_index(static_cast<size_t>(rig.mesh.vertex_count()), -1);
  std::vector<int32_t> tets, vertices;
  auto number = [](std::vector<int32_t>& index, std::vector<int32_t>& used, int32_t old) {
    int32_t& renumbered = index[static_cast<size_t>(old)];
    if (renumbered < 0) renumbered = static_cast<int32_t>(used.size()), used.push_back(old);
    return renumbered;
  };
  for (const mapping::Embedding& e : rig.embeddings) {
    mapping::Embedding sub = e;
    for (int64_t p = 0; p < e.tet.size(); ++p) sub.tet(p) = number(tet_index, tets, e.tet(p));
    preview.embeddings.push_back(std::move(sub));
  }
  preview.mesh.tets.resize(static_cast<Eigen::Index>(tets.size()), 4);
  for (size_t t = 0; t < tets.size(); ++t) {
    for (int c = 0; c < 4; ++c) {
      preview.mesh.tets(static_cast<Eigen::Index>(t), c) = number(vertex_index, vertices, rig.mesh.tets(tets[t], c));
    }
  }
  const auto n = static_cast<Eigen::Index>(vertices.size());
  preview.rig_vertex = vertices;
  preview.mesh.vertices.resize(n, 3);
  preview.weights.influences = rig.weights.influences;
  preview.weights.segment_count = rig.weights.segment_count;
  preview.weights.segment.resize(n, rig.weights.influences);
  preview.weights.weight.resize(n, rig.weights.influences);
  preview.centres.centre.resize(n, 3);
  preview.centres.rigid.resize(static_cast<size_t>(n));
  for (Eigen::Index i = 0; i < n; ++i) {
    const int32_t v = vertices[static_cast<size_t>(i)];
    preview.mesh.vertices.row(i) = rig.mesh.vertices.row(v);
    preview.weights.segment.row(i) = rig.weights.segment.row(v);
    preview.weights.weight.row(i) = rig.weights.weight.row(v);
    preview.centres.centre.row(i) = rig.centres.centre.row(v);
    preview.centres.rigid[static_cast<size_t>(i)] = rig.centres.rigid[static_cast<size_t>(v)];
  }
  preview.mesh.segment_count = rig.mesh.segment_count;
}

// The segments' transforms of a pose; a pose that does not fit the rig is INVALID_ARGUMENT naming where it came
// from. forward_kinematics validates the pose: the one check a pose gets.
Result<std::vector<RigidTransform>> kinematics(const Prepared& p, const Pose& pose, const std::string& source) {
  Result<std::vector<RigidTransform>> transforms = pose::forward_kinematics(p.rig.skeleton, pose);
  if (!transforms.ok() && !source.empty()) return transforms.status().with_context(source);
  return transforms;
}

// What a soft-tissue solve is for: a pose (its request's options, from the warm start) or a slider's preview.
enum class SolveFor { kPose, kPreview };

// The soft tissue's steady state from skinned (CoR) vertices; a preview's takes a few iterations of it, going on from
// where the last solve on the same free vertices ended.
Result<Eigen::MatrixXd> soft_tissue(const Prepared& p, const Eigen::MatrixXd& warm,
                                    const skinning::SegmentTransforms& segments, const ProgressHooks& hooks,
                                    SolveFor purpose, const FemOptions& options = {}) {
  std::call_once(p.fem.once, [&] { p.fem.topology = fem::topology(p.rig.mesh, skin_of(p)); });
  POSEWARP_ASSIGN_OR_RETURN(fem::FemParams params, fem_params(options));
  if (purpose == SolveFor::kPreview) {  // a slider's next call goes on from where the last one ended
    // At most 4 iterations per call, as many as fit in 70 ms of solve (at least one), whatever the rig and the
    // machine; the rest of a call (skinning, surfaces) is a few ms. Fewer per call leave the tissue a little further
    // from the steady state after a slider's calls (README: posewarp_fem_probe's figures), but a slider's updates
    // come as fast as the calls end (the latest wins), so it iterates about as much per second and shows each step
    // sooner.
    params.max_iterations = 4;
    params.time_budget_seconds = 0.070;
    params.continue_from_last = true;
    params.margin_mm = 0.0;   // only the tissue the pose bends (the margin changes the figures by 0.1-0.7%)
    params.untangle = false;  // a slider's steps within the preview's budget; the pose turns the folds back
    params.contact = false;   // and pushes the skin out of the tissue facing it
  }
  POSEWARP_ASSIGN_OR_RETURN(
      Eigen::MatrixXd solved,
      fem::solve({p.rig.mesh, p.frames, p.fem.topology, p.rig.weights, segments, warm, &p.fem.cache}, params, hooks));
  if (purpose == SolveFor::kPose && options.refine_iterations > 0) {
    return fem::solve_nonlinear({p.rig.mesh, p.frames, p.fem.topology, p.rig.weights, segments, solved},
                                refine_params(options.refine_iterations), hooks);
  }
  return solved;
}

// The skinned tet vertices of a method other than fem (fem starts from CoR's: soft_tissue).
Result<Eigen::MatrixXd> skinned(const Prepared& p, Method method, const skinning::SegmentTransforms& segments) {
  const skinning::Method m = method == Method::kFem ? skinning::Method::kCor : stage_method(method);
  return skinning::skin(m, p.rig.mesh.vertices, p.rig.weights, p.rig.centres, segments);
}

// Step 4: each surface vertex follows its rest tet's barycentric combination of posed tet vertices.
Status pose_surfaces(const Prepared& p, const PoseRequest& request, PoseResult& result) {
  const TetMesh& mesh = p.rig.mesh;
  // The rig's surfaces side by side (most are small), each one's vertices moved and its triangles copied.
  result.surfaces.resize(p.rig.surfaces.size());
  parallel_for(0, static_cast<int64_t>(p.rig.surfaces.size()), 1, [&](int64_t s0, int64_t s1) {
    for (auto i = static_cast<size_t>(s0); i < static_cast<size_t>(s1); ++i) {
      const SurfaceMesh& rest = p.rig.surfaces[i];
      result.surfaces[i] = {rest.name, rest.label,
                            mapping::deform_points(p.rig.embeddings[i], mesh, result.posed_vertices), rest.triangles};
    }
  });
  for (const SurfaceMesh& extra : request.extra_surfaces) {
    POSEWARP_ASSIGN_OR_RETURN(const mapping::Embedding e, mapping::embed_points(mesh, extra.vertices, {}));
    SurfaceMesh posed = extra;
    posed.vertices = mapping::deform_points(e, mesh, result.posed_vertices);
    result.surfaces.push_back(std::move(posed));
  }
  return ok_status();
}

// The forward field on the source grid: each bone voxel moves with its bone, every other source voxel with the rest
// tet that covers it, a voxel outside the mesh with the root.
void forward_field(const Prepared& p, const skinning::SegmentTransforms& segments, const RigidTransform& root,
                   PoseResult& result) {
  const TetMesh& mesh = p.rig.mesh;
  const ImageGeometry& source = p.rig.labels.geometry();
  result.forward_field.assign(static_cast<size_t>(source.voxel_count()) * 3, 0.0f);
  const Eigen::MatrixXd& posed = result.posed_vertices;
  parallel_for(0, source.size[2], 1, [&](int64_t k0, int64_t k1) {
    for (int64_t k = k0; k < k1; ++k) {
      for (int64_t j = 0; j < source.size[1]; ++j) {
        for (int64_t i = 0; i < source.size[0]; ++i) {
          const int64_t v = source.offset(i, j, k);
          const Vec3 at = source.index_to_physical({double(i), double(j), double(k)});
          const Eigen::Vector3d x(at[0], at[1], at[2]);
          int32_t t = p.rest_owner.at(i, j, k);
          if (t <= -2) t = -2 - t;
          Eigen::Vector3d moved;
          const int16_t bone = p.bone_voxels.segment_of(v);
          if (bone != resample::BoneVoxels::kNone) {  // a bone voxel moves with its bone, exactly
            moved = segments.rotation[static_cast<size_t>(bone)] * x + segments.translation[static_cast<size_t>(bone)];
          } else if (t >= 0) {
            Eigen::Matrix3d inv;
            for (int r = 0; r < 3; ++r)
              for (int c = 0; c < 3; ++c) inv(r, c) = p.frames.rest_inverse(t, 3 * r + c);
            const Eigen::Vector3d lambda = inv * (x - mesh.vertices.row(mesh.tets(t, 0)).transpose());
            moved = posed.row(mesh.tets(t, 0)).transpose();
            for (int c = 0; c < 3; ++c) {
              moved += lambda(c) * (posed.row(mesh.tets(t, c + 1)) - posed.row(mesh.tets(t, 0))).transpose();
            }
          } else {
            moved = root.apply(x);
          }
          for (int a = 0; a < 3; ++a)
            result.forward_field[static_cast<size_t>(3 * v + a)] = static_cast<float>(moved(a) - x(a));
        }
      }
    }
  });
}

}  // namespace

Result<PoseEngine> PoseEngine::create(Rig rig, const ProgressHooks& hooks) {
  return guarded("preparing the rig for posing", [&] {
    return in_arena(hooks.threads, [&]() -> Result<PoseEngine> {
      if (rig.labels.empty()) {
        return failed_precondition_error(
            "the rig holds no source volume to warp; rebuild it with this posewarp version");
      }
      auto p = std::make_shared<Prepared>();
      p->frames = skinning::rest_tet_frames(rig.mesh);
      // A rig file holds its owner and region tables and the engine's summary of them; a rig from an earlier
      // version gets them made here.
      if (rig.rest_owner.empty() || rig.body_region.empty() || !rig.bone_substitute) {
        POSEWARP_RETURN_IF_ERROR(internal::make_engine_tables(rig, hooks));
      }
      internal::make_engine_summary(rig);  // what the rig file lacks of it
      p->rest_owner = std::move(rig.rest_owner);
      p->region = std::move(rig.body_region);
      p->tet_region = std::move(rig.tet_region);
      p->rest_label_counts = std::move(rig.rest_label_counts);
      if (rig.ct) p->ct_minimum = std::min(0.0f, *rig.ct_lowest);
      p->label_spans = resample::row_spans(rig.labels.data(), rig.labels.size(), 0);
      std::vector<std::vector<Label>> segment_labels;
      for (const rig::Segment& segment : rig.skeleton.segments) segment_labels.push_back(segment.labels);
      POSEWARP_ASSIGN_OR_RETURN(p->bone_voxels,
                                resample::bone_voxels(rig.labels, segment_labels, &*rig.bone_substitute));
      rig.bone_substitute.reset();  // the engine keeps them as the bone voxels' own
      p->separated = rig::separated_segments(rig.skeleton);
      p->rig = std::move(rig);
      return PoseEngine(std::move(p));
    });
  });
}

namespace {

// The preview's share of the rig, made once, by the first preview that needs it.
const PreviewRig& preview_of(const PoseEngine::Prepared& p) {
  std::call_once(p.preview_once, [&] { prepare_preview(p.rig, p.preview); });
  return p.preview;
}

}  // namespace

Result<PreviewResult> PoseEngine::preview(const Pose& pose, Method method) const {
  return guarded("previewing the pose", [&]() -> Result<PreviewResult> {
    const Prepared& p = *prepared_;
    const PreviewRig& preview = preview_of(p);
    POSEWARP_ASSIGN_OR_RETURN(const std::vector<RigidTransform> transforms, kinematics(p, pose, ""));
    const skinning::SegmentTransforms segments = segment_transforms(transforms);
    PreviewResult result;
    if (method == Method::kFem) {
      // The steady state needs the whole mesh; a slider gets a few iterations of it per call, each call going on
      // from where the last one ended (the solve's system is kept between calls), so the shape converges while the
      // slider moves and settles when it stops.
      POSEWARP_ASSIGN_OR_RETURN(const Eigen::MatrixXd warm, skinned(p, Method::kCor, segments));
      POSEWARP_ASSIGN_OR_RETURN(const Eigen::MatrixXd posed, soft_tissue(p, warm, segments, {}, SolveFor::kPreview));
      // The surfaces through the preview's own tets (the same barycentrics), their corners gathered first: the
      // whole mesh's vertices are a few times more and scattered.
      Eigen::MatrixXd corners(static_cast<Eigen::Index>(preview.rig_vertex.size()), 3);
      for (size_t i = 0; i < preview.rig_vertex.size(); ++i) {
        corners.row(static_cast<Eigen::Index>(i)) = posed.row(preview.rig_vertex[i]);
      }
      for (const mapping::Embedding& e : preview.embeddings) {
        result.surface_vertices.push_back(mapping::deform_points(e, preview.mesh, corners));
      }
    } else {
      POSEWARP_ASSIGN_OR_RETURN(
          const Eigen::MatrixXd posed,
          skinning::skin(stage_method(method), preview.mesh.vertices, preview.weights, preview.centres, segments));
      for (const mapping::Embedding& e : preview.embeddings) {
        result.surface_vertices.push_back(mapping::deform_points(e, preview.mesh, posed));
      }
    }
    // A joint centre moves with its parent segment (the child turns about it).
    for (const rig::Joint& joint : p.rig.skeleton.joints) {
      result.joint_centres.push_back(transforms[static_cast<size_t>(joint.parent)].apply(joint.centre_mm));
    }
    return result;
  });
}

namespace {

// The plan for an output grid; RESOURCE_EXHAUSTED over the budget.
Result<PosePlan> check_output_budget(const Prepared& p, const PoseRequest& request, const ImageGeometry& grid) {
  // Per output voxel the warp's owner code, labels (stored as 32-bit), CT and the inverse field; the forward field
  // per source voxel.
  PosePlan plan;
  plan.output_grid = grid;
  const int64_t per_voxel =
      4 + (request.want_labels ? 4 : 0) + (request.want_ct && p.rig.ct ? 4 : 0) + (request.want_fields ? 12 : 0);
  plan.output_bytes = grid.voxel_count() * per_voxel + (request.want_fields ? p.rig.labels.voxel_count() * 12 : 0);
  plan.budget_bytes = request.limits.max_bytes;
  if (plan.budget_bytes <= 0) {
    plan.budget_bytes = static_cast<int64_t>(::sysconf(_SC_PHYS_PAGES)) * ::sysconf(_SC_PAGE_SIZE) / 2;
  }
  if (plan.output_bytes > plan.budget_bytes) {
    return resource_exhausted_error("this pose's output (" + grid.describe() + ") would take " +
                                    std::to_string(plan.output_bytes >> 20) + " MB, over the budget of " +
                                    std::to_string(plan.budget_bytes >> 20) +
                                    " MB; use a coarser or smaller grid, or leave out the fields or the CT");
  }
  return plan;
}

// The output grid of a request, given the posed tet vertices (used only to grow the grid).
Result<ImageGeometry> output_grid(const Prepared& p, const PoseRequest& request, const Eigen::MatrixXd& posed) {
  return resample::output_geometry(stage_grid(request.grid), p.rig.labels.geometry(), posed,
                                   request.given_grid ? &*request.given_grid : nullptr, stage_resample(request.limits));
}

}  // namespace

Result<PosePlan> PoseEngine::plan(const PoseRequest& request) const {
  return guarded("planning the pose", [&]() -> Result<PosePlan> {
    const Prepared& p = *prepared_;
    if (request.method == Method::kFem) POSEWARP_RETURN_IF_ERROR(fem_params(request.fem).status());
    if (!(request.want_labels || request.want_ct || request.want_fields)) return PosePlan{};
    POSEWARP_ASSIGN_OR_RETURN(const std::vector<RigidTransform> transforms,
                              kinematics(p, request.pose, request.pose_source));
    Eigen::MatrixXd posed;
    if (request.grid == GridPolicy::kGrow) {  // the grown grid holds the posed body
      // fem moves only soft tissue between bones that CoR has placed: its grid is CoR's (the pose checks its own).
      POSEWARP_ASSIGN_OR_RETURN(posed, skinned(p, request.method, segment_transforms(transforms)));
    }
    POSEWARP_ASSIGN_OR_RETURN(const ImageGeometry grid, output_grid(p, request, posed));
    return check_output_budget(p, request, grid);
  });
}

namespace {

// Step 5 of a pose: the volume warp, each volume handed to its callback as soon as it is complete (a server sends it
// while the rest is computed), then the label report, which needs only the labels, then the fields.
Status warp_volumes(const Prepared& p, const PoseRequest& request, const skinning::SegmentTransforms& segments,
                    const RigidTransform& root, const std::vector<std::string>& names, const ProgressHooks& hooks,
                    StageTimer& clock, PoseResult& result) {
  QualityReport& qr = result.report;
  POSEWARP_ASSIGN_OR_RETURN(result.output_grid, output_grid(p, request, result.posed_vertices));
  POSEWARP_RETURN_IF_ERROR(check_output_budget(p, request, result.output_grid).status());
  resample::ResampleParams params = stage_resample(request.limits);
  if (p.rig.ct) params.intensity_background = std::max(p.ct_minimum, params.intensity_background);
  resample::RigidBones bones;
  bones.voxels = &p.bone_voxels;
  bones.rotation = segments.rotation;
  bones.translation = segments.translation;
  bones.region = &p.region;
  bones.tet_region = &p.tet_region;
  bones.separated = &p.separated;
  POSEWARP_ASSIGN_OR_RETURN(resample::TetWarp warp,
                            resample::TetWarp::build({.rest = p.rig.mesh,
                                                      .posed = result.posed_vertices,
                                                      .source = p.rig.labels.geometry(),
                                                      .output = result.output_grid,
                                                      .background_rotation = root.rotation,
                                                      .background_translation = root.translation,
                                                      .rest_owner = &p.rest_owner,
                                                      .params = params,
                                                      .bones = &bones},
                                                     hooks));
  report_warp(warp, names, result);
  clock.lap("warp-prepare");
  std::shared_ptr<const LabelVolume> handed_out;  // the labels given to labels_ready: the report reads them
  const LabelVolume* posed_labels = nullptr;
  std::vector<std::pair<double, double>> bone_deviation;  // per segment, found with the labels, for their report
  if (request.want_labels) {
    POSEWARP_ASSIGN_OR_RETURN(LabelVolume labels, warp.warp_labels(p.rig.labels, &bone_deviation, &p.label_spans));
    clock.lap("warp-labels");
    if (request.labels_ready) {
      handed_out = std::make_shared<const LabelVolume>(std::move(labels));
      posed_labels = handed_out.get();
      request.labels_ready(handed_out);
    } else {
      posed_labels = &result.labels.emplace(std::move(labels));
    }
  }
  if (request.want_ct && p.rig.ct) {
    const resample::Interpolation interpolation = request.ct_interpolation == Interpolation::kNearest
                                                      ? resample::Interpolation::kNearest
                                                      : resample::Interpolation::kLinear;
    POSEWARP_ASSIGN_OR_RETURN(IntensityVolume ct, p.rig.ct->visit([&](const auto& source) {
      return warp.warp_intensities(source, interpolation);
    }));
    clock.lap("warp-ct");
    if (request.ct_ready) {
      request.ct_ready(std::make_shared<const IntensityVolume>(std::move(ct)));
    } else {
      result.ct = std::move(ct);
    }
  }
  if (request.want_labels) {
    POSEWARP_RETURN_IF_ERROR(StageProgress(hooks, "pose").check_cancel());
    report_labels(p, warp, *posed_labels, bone_deviation, names, qr);
    clock.lap("report-labels");
  }
  if (request.want_fields) {
    result.inverse_field = warp.inverse_displacement();
    forward_field(p, segments, root, result);
    clock.lap("fields");
  }
  return ok_status();
}

// A pose's steps, timed: 1 forward kinematics, 2 skinning (fem: CoR, then the soft tissue's steady state), 3 the mesh
// report, 4 surfaces, 5 the volume warp with its report.
Result<PoseResult> pose_unguarded(const Prepared& p, const PoseRequest& request, const ProgressHooks& hooks) {
  PoseResult result;
  QualityReport& qr = result.report;
  StageTimer clock(qr.stage_seconds);
  qr.pose_name = request.pose.name;
  qr.method = std::string(method_name(request.method));

  POSEWARP_ASSIGN_OR_RETURN(const std::vector<RigidTransform> transforms,
                            kinematics(p, request.pose, request.pose_source));
  if (request.method == Method::kFem) POSEWARP_RETURN_IF_ERROR(fem_params(request.fem).status());
  const skinning::SegmentTransforms segments = segment_transforms(transforms);
  result.segment_rotation = segments.rotation;
  result.segment_translation = segments.translation;
  clock.lap("kinematics");

  POSEWARP_ASSIGN_OR_RETURN(result.posed_vertices, skinned(p, request.method, segments));
  clock.lap("skinning");
  if (request.method == Method::kFem) {
    POSEWARP_ASSIGN_OR_RETURN(result.posed_vertices,
                              soft_tissue(p, result.posed_vertices, segments, hooks, SolveFor::kPose, request.fem));
    clock.lap("fem");
  }

  const std::vector<std::string> names = segment_names(p.rig.skeleton);
  report_mesh(p, request.pose, segments, names, hooks, result);
  clock.lap("report-mesh");
  POSEWARP_RETURN_IF_ERROR(StageProgress(hooks, "pose").check_cancel());

  if (request.want_surfaces) {
    POSEWARP_RETURN_IF_ERROR(pose_surfaces(p, request, result));
    clock.lap("surfaces");
  }

  if (request.want_labels || request.want_ct || request.want_fields) {
    const RigidTransform& root = transforms[static_cast<size_t>(p.rig.skeleton.root)];
    POSEWARP_RETURN_IF_ERROR(warp_volumes(p, request, segments, root, names, hooks, clock, result));
  }
  const ImageGeometry& source = p.rig.labels.geometry();
  report::add_warnings(qr, std::min({source.spacing[0], source.spacing[1], source.spacing[2]}));
  return result;
}

}  // namespace

Result<PoseResult> PoseEngine::pose(const PoseRequest& request, const ProgressHooks& hooks) const {
  return guarded("posing",
                 [&] { return in_arena(hooks.threads, [&] { return pose_unguarded(*prepared_, request, hooks); }); });
}

}  // namespace posewarp::api
