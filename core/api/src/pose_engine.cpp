// PoseEngine: forward kinematics, skinning, tet maps, the volume warp and the quality report, timed per stage.
#include "posewarp/api/pose_engine.h"

#include <Eigen/Dense>

#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <mutex>
#include <new>
#include <unordered_map>
#include <utility>

#include "posewarp/common/stopwatch.h"
#include "posewarp/common/exception_wall.h"
#include "posewarp/common/parallel.h"
#include "posewarp/fem/soft_tissue.h"
#include "posewarp/pose/forward_kinematics.h"

namespace posewarp::api {

struct PoseEngine::Fem {
  std::once_flag once;
  fem::Topology topology;
  std::once_flag skin_once;
  std::vector<uint8_t> skin;  // the report's skin vertices (fem::skin_vertices), made by the first pose that needs them
  fem::SolveCache cache;      // the last solve's factored system: a slider's next pose frees the same vertices
};

Result<PoseEngine> PoseEngine::create(Rig rig, const ProgressHooks& hooks) {
  return guarded("preparing the rig for posing",
                 [&] { return in_arena(hooks.threads, [&] { return create_unguarded(std::move(rig), hooks); }); });
}

namespace {

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
  POSEWARP_RETURN_IF_ERROR(fem::validate(params));
  return params;
}

// A joint rotation's flexion and abduction in degrees: the pose's own angles when it gave them, else the rotation
// `turn` (LPS) read in the joint's frame as x, then y, then z (rig::joint_rotation_from_angles's order).
std::pair<double, double> flexion_and_abduction(const rig::Joint& joint, const pose::JointRotation& rotation,
                                                const Eigen::Matrix3d& turn) {
  if (rotation.angles_deg) return {rotation.angles_deg->x(), rotation.angles_deg->y()};
  const Eigen::Matrix3d m = joint.frame.transpose() * turn * joint.frame;  // Rx(f) Ry(a) Rz(r)
  constexpr double kDegrees = 180.0 / M_PI;
  return {std::atan2(-m(1, 2), m(2, 2)) * kDegrees, std::asin(std::clamp(m(0, 2), -1.0, 1.0)) * kDegrees};
}

// Restricts the rig to what its surfaces need: their tets, renumbered, on their vertices, renumbered.
template <typename Preview>
void prepare_preview(const Rig& rig, Preview& preview) {
  std::unordered_map<int32_t, int32_t> tet_index, vertex_index;
  std::vector<int32_t> tets, vertices;
  for (const mapping::Embedding& e : rig.embeddings) {
    mapping::Embedding sub = e;
    for (int64_t p = 0; p < e.tet.size(); ++p) {
      const auto [it, fresh] = tet_index.emplace(e.tet(p), static_cast<int32_t>(tets.size()));
      if (fresh) tets.push_back(e.tet(p));
      sub.tet(p) = it->second;
    }
    preview.embeddings.push_back(std::move(sub));
  }
  preview.mesh.tets.resize(static_cast<Eigen::Index>(tets.size()), 4);
  for (size_t t = 0; t < tets.size(); ++t) {
    for (int c = 0; c < 4; ++c) {
      const int32_t v = rig.mesh.tets(tets[t], c);
      const auto [it, fresh] = vertex_index.emplace(v, static_cast<int32_t>(vertices.size()));
      if (fresh) vertices.push_back(v);
      preview.mesh.tets(static_cast<Eigen::Index>(t), c) = it->second;
    }
  }
  const auto n = static_cast<Eigen::Index>(vertices.size());
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

}  // namespace

Result<Eigen::MatrixXd> PoseEngine::posed_vertices(skinning::Method method, const skinning::SegmentTransforms& segments,
                                                   const ProgressHooks& hooks) const {
  if (method != skinning::Method::kFem) {
    return skinning::skin(method, rig_.mesh.vertices, rig_.weights, rig_.centres, segments);
  }
  POSEWARP_ASSIGN_OR_RETURN(const Eigen::MatrixXd warm, skinning::skin(skinning::Method::kCor, rig_.mesh.vertices,
                                                                       rig_.weights, rig_.centres, segments));
  return soft_tissue(warm, segments, hooks);
}

Result<Eigen::MatrixXd> PoseEngine::soft_tissue(const Eigen::MatrixXd& warm, const skinning::SegmentTransforms& segments,
                                                const ProgressHooks& hooks, int max_iterations,
                                                const FemOptions& options) const {
  std::call_once(fem_->once, [&] { fem_->topology = fem::topology(rig_.mesh); });
  POSEWARP_ASSIGN_OR_RETURN(fem::FemParams params, fem_params(options));
  if (max_iterations > 0) {  // a preview: a slider's next call goes on from where the last one ended
    params.max_iterations = max_iterations;
    params.continue_from_last = true;
    params.margin_mm = 0.0;  // only the tissue the pose bends (the margin changes the figures by 0.1-0.7%)
  }
  return fem::solve({rig_.mesh, frames_, fem_->topology, rig_.weights, segments, warm, &fem_->cache}, params, hooks);
}

Result<PreviewResult> PoseEngine::preview(const pose::Pose& pose, skinning::Method method) const {
  return guarded("previewing the pose", [&]() -> Result<PreviewResult> {
    POSEWARP_RETURN_IF_ERROR(pose::validate_pose(pose, rig_.skeleton));
    POSEWARP_ASSIGN_OR_RETURN(const std::vector<pose::RigidTransform> transforms,
                              pose::forward_kinematics(rig_.skeleton, pose));
    const skinning::SegmentTransforms segments = segment_transforms(transforms);
    PreviewResult result;
    if (method == skinning::Method::kFem) {
      // The steady state needs the whole mesh; a slider gets a few iterations of it per call, each call going on
      // from where the last one ended (the solve's system is kept between calls), so the shape converges while the
      // slider moves and settles when it stops.
      constexpr int kPreviewIterations = 5;
      POSEWARP_ASSIGN_OR_RETURN(const Eigen::MatrixXd warm, skinning::skin(skinning::Method::kCor, rig_.mesh.vertices,
                                                                           rig_.weights, rig_.centres, segments));
      POSEWARP_ASSIGN_OR_RETURN(const Eigen::MatrixXd posed, soft_tissue(warm, segments, {}, kPreviewIterations));
      for (const mapping::Embedding& e : rig_.embeddings) {
        result.surface_vertices.push_back(mapping::deform_points(e, rig_.mesh, posed));
      }
    } else {
      POSEWARP_ASSIGN_OR_RETURN(const Eigen::MatrixXd posed, skinning::skin(method, preview_.mesh.vertices,
                                                                            preview_.weights, preview_.centres, segments));
      for (const mapping::Embedding& e : preview_.embeddings) {
        result.surface_vertices.push_back(mapping::deform_points(e, preview_.mesh, posed));
      }
    }
    // A joint centre moves with its parent segment (the child turns about it).
    for (const rig::Joint& joint : rig_.skeleton.joints) {
      result.joint_centres.push_back(transforms[static_cast<size_t>(joint.parent)].apply(joint.centre_mm));
    }
    return result;
  });
}

Result<PoseEngine> PoseEngine::create_unguarded(Rig rig, const ProgressHooks& hooks) {
  if (rig.labels.empty()) {
    return failed_precondition_error("the rig holds no source volume to warp; rebuild it with this posewarp version");
  }
  PoseEngine engine;  // create() runs this behind the exception wall ("preparing the rig for posing")
  engine.frames_ = skinning::rest_tet_frames(rig.mesh);
  const ImageGeometry& g = rig.labels.geometry();
  POSEWARP_ASSIGN_OR_RETURN(resample::TetWarp identity,
                            resample::TetWarp::build(rig.mesh, rig.mesh.vertices, g, g,
                                                     Eigen::Matrix3d::Identity(), Eigen::Vector3d::Zero(), nullptr,
                                                     {}, hooks));
  engine.rest_owner_ = identity.owner();
  std::vector<std::vector<Label>> segment_labels;
  for (const rig::Segment& segment : rig.skeleton.segments) segment_labels.push_back(segment.labels);
  POSEWARP_ASSIGN_OR_RETURN(engine.bone_voxels_, resample::bone_voxels(rig.labels, segment_labels));
  // Body regions for the skin-contact guard: the body as the build made it (default body parameters).
  POSEWARP_ASSIGN_OR_RETURN(const LabelVolume body,
                            labels::body_mask(rig.label_map, rig.labels, rig.ct ? &*rig.ct : nullptr));
  POSEWARP_ASSIGN_OR_RETURN(rig::BodyRegions regions, rig::body_regions(rig.skeleton, rig.labels, body));
  engine.region_ = std::move(regions.segment);
  engine.separated_ = rig::separated_segments(rig.skeleton);
  engine.tet_region_.assign(static_cast<size_t>(rig.mesh.tet_count()), -1);
  for (int64_t t = 0; t < rig.mesh.tet_count(); ++t) {
    Eigen::Vector3d c = Eigen::Vector3d::Zero();
    for (int q = 0; q < 4; ++q) c += rig.mesh.vertices.row(rig.mesh.tets(t, q)).transpose();
    const Vec3 u = g.physical_to_index({c.x() / 4, c.y() / 4, c.z() / 4});
    // Rounded only within the grid's reach: llround of a value beyond int64 (a damaged rig's far vertex) is
    // undefined; such a centre lies in no voxel.
    auto voxel = [](double x) { return std::abs(x) < 1e15 ? std::llround(x) : int64_t{-1}; };
    const int64_t i = voxel(u[0]), j = voxel(u[1]), k = voxel(u[2]);
    if (rig.labels.contains(i, j, k)) engine.tet_region_[static_cast<size_t>(t)] = engine.region_[static_cast<size_t>(g.offset(i, j, k))];
  }
  engine.rest_label_counts_ = report::label_counts(rig.labels);
  if (rig.ct) {
    engine.ct_minimum_ = 0.0f;
    for (const float v : rig.ct->voxels()) engine.ct_minimum_ = std::min(engine.ct_minimum_, v);
  }
  prepare_preview(rig, engine.preview_);
  engine.fem_ = std::make_shared<Fem>();
  engine.rig_ = std::move(rig);
  return engine;
}

Result<PosePlan> PoseEngine::check_output_budget(const PoseRequest& request, const ImageGeometry& grid) const {
  // Per output voxel the warp's owner code, labels (stored as 32-bit), CT and the inverse field; the forward field
  // per source voxel.
  PosePlan plan;
  plan.output_grid = grid;
  const int64_t per_voxel = 4 + (request.want_labels ? 4 : 0) + (request.want_ct && rig_.ct ? 4 : 0) +
                            (request.want_fields ? 12 : 0);
  plan.output_bytes = grid.voxel_count() * per_voxel + (request.want_fields ? rig_.labels.voxel_count() * 12 : 0);
  plan.budget_bytes = request.resample.max_output_bytes;
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

Result<PosePlan> PoseEngine::plan(const PoseRequest& request) const {
  return guarded("planning the pose", [&]() -> Result<PosePlan> {
    if (request.method == skinning::Method::kFem) POSEWARP_RETURN_IF_ERROR(fem_params(request.fem).status());
    if (!(request.want_labels || request.want_ct || request.want_fields)) return PosePlan{};
    const rig::Skeleton& skeleton = rig_.skeleton;
    POSEWARP_RETURN_IF_ERROR(pose::validate_pose(request.pose, skeleton));
    Eigen::MatrixXd posed;
    if (request.grid == resample::GridPolicy::kGrow) {  // the grown grid holds the posed body
      POSEWARP_ASSIGN_OR_RETURN(const std::vector<pose::RigidTransform> transforms,
                                pose::forward_kinematics(skeleton, request.pose));
      const skinning::SegmentTransforms segments = segment_transforms(transforms);
      // fem moves only soft tissue between bones that CoR has placed: its grid is CoR's (the pose checks its own).
      const skinning::Method method =
          request.method == skinning::Method::kFem ? skinning::Method::kCor : request.method;
      POSEWARP_ASSIGN_OR_RETURN(posed, posed_vertices(method, segments, {}));
    }
    POSEWARP_ASSIGN_OR_RETURN(const ImageGeometry grid,
                              resample::output_geometry(request.grid, rig_.labels.geometry(), posed,
                                                        request.given_grid ? &*request.given_grid : nullptr,
                                                        request.resample));
    return check_output_budget(request, grid);
  });
}

Result<PoseResult> PoseEngine::pose(const PoseRequest& request, const ProgressHooks& hooks) const {
  return guarded("posing", [&] { return in_arena(hooks.threads, [&] { return pose_unguarded(request, hooks); }); });
}

Result<PoseResult> PoseEngine::pose_unguarded(const PoseRequest& request, const ProgressHooks& hooks) const {
  PoseResult result;
  report::QualityReport& qr = result.report;
  StageTimer clock(qr.stage_seconds);
  qr.pose_name = request.pose.name;
  qr.method = std::string(skinning::method_name(request.method));
  const TetMesh& mesh = rig_.mesh;
  const rig::Skeleton& skeleton = rig_.skeleton;

  // 1. Forward kinematics: one rigid transform per segment.
  POSEWARP_RETURN_IF_ERROR(pose::validate_pose(request.pose, skeleton));
  if (request.method == skinning::Method::kFem) POSEWARP_RETURN_IF_ERROR(fem_params(request.fem).status());
  POSEWARP_ASSIGN_OR_RETURN(const std::vector<pose::RigidTransform> transforms,
                            pose::forward_kinematics(skeleton, request.pose));
  const skinning::SegmentTransforms segments = segment_transforms(transforms);
  result.segment_rotation = segments.rotation;
  result.segment_translation = segments.translation;
  clock.lap("kinematics");

  // 2. Skinning of the tet vertices (fem: CoR, then the soft tissue's steady state).
  const bool fem = request.method == skinning::Method::kFem;
  POSEWARP_ASSIGN_OR_RETURN(result.posed_vertices,
                            posed_vertices(fem ? skinning::Method::kCor : request.method, segments, hooks));
  clock.lap("skinning");
  if (fem) {
    POSEWARP_ASSIGN_OR_RETURN(result.posed_vertices, soft_tissue(result.posed_vertices, segments, hooks, 0, request.fem));
    clock.lap("fem");
  }

  // 3. Mesh quality: inversions, volume change, bone rigidity.
  const Eigen::VectorXd det = skinning::tet_determinants(mesh, frames_, result.posed_vertices);
  qr.mesh = report::mesh_change(mesh, det, frames_.rest_volume);
  std::vector<std::string> names;
  for (const rig::Segment& s : skeleton.segments) names.push_back(s.name);
  qr.rigidity = report::bone_rigidity(mesh, result.posed_vertices, segments.rotation, segments.translation, names);
  const ImageGeometry& source = rig_.labels.geometry();
  const double voxel = std::min({source.spacing[0], source.spacing[1], source.spacing[2]});
  for (const report::SegmentRigidity& s : qr.rigidity) qr.bone_rigidity_error_mm = std::max(qr.bone_rigidity_error_mm, s.max_error_mm);
  qr.bone_rigidity_error_voxels = qr.bone_rigidity_error_mm / voxel;
  std::vector<std::pair<std::string, Eigen::Vector3d>> moved_joints;
  for (const pose::JointRotation& rotation : request.pose.joints) {
    const int j = skeleton.joint_index(rotation.joint);
    const rig::Joint& joint = skeleton.joints[static_cast<size_t>(j)];
    const Eigen::Matrix3d turn = pose::joint_rotation_in_lps(joint, rotation);
    if (turn.isIdentity(1e-12)) continue;
    moved_joints.emplace_back(joint.name, joint.centre_mm);
    const auto [flexion, abduction] = flexion_and_abduction(joint, rotation, turn);
    for (const rig::MotionRange& range : joint.ranges) {
      const double angle = range.motion == "abduction" ? abduction : flexion;
      constexpr double kSlackDeg = 0.5;
      if ((range.positive_stopped && angle > range.positive_deg + kSlackDeg) ||
          (range.negative_stopped && angle < -range.negative_deg - kSlackDeg)) {
        qr.past_range.push_back({joint.name, range.motion, angle, range.negative_deg, range.positive_deg});
      }
    }
  }
  const std::vector<double> radii{50.0, 100.0};
  qr.joint_regions = report::joint_region_changes(mesh, det, frames_.rest_volume, moved_joints, radii);
  if (!moved_joints.empty()) std::call_once(fem_->skin_once, [&] { fem_->skin = fem::skin_vertices(mesh); });
  for (size_t j = 0; j < moved_joints.size(); ++j) {
    const std::vector<fem::Penetration> inside =
        fem::penetration(mesh, result.posed_vertices, fem_->skin, moved_joints[j].second, radii);
    for (size_t r = 0; r < radii.size(); ++r) {
      report::JointRegionChange& change = qr.joint_regions[j * radii.size() + r];
      change.skin_vertices = inside[r].skin_vertices;
      change.skin_inside_tissue = inside[r].inside_tissue;
      change.skin_inside_bone = inside[r].inside_bone;
    }
  }
  clock.lap("report-mesh");
  POSEWARP_RETURN_IF_ERROR(StageProgress(hooks, "pose").check_cancel());

  // 4. Surfaces: each vertex follows its rest tet's barycentric combination of posed tet vertices.
  if (request.want_surfaces) {
    for (size_t i = 0; i < rig_.surfaces.size(); ++i) {
      surface::SurfaceMesh posed = rig_.surfaces[i];
      posed.vertices = mapping::deform_points(rig_.embeddings[i], mesh, result.posed_vertices);
      result.surfaces.push_back(std::move(posed));
    }
    for (const surface::SurfaceMesh& extra : request.extra_surfaces) {
      POSEWARP_ASSIGN_OR_RETURN(const mapping::Embedding e, mapping::embed_points(mesh, extra.vertices, {}));
      surface::SurfaceMesh posed = extra;
      posed.vertices = mapping::deform_points(e, mesh, result.posed_vertices);
      result.surfaces.push_back(std::move(posed));
    }
    clock.lap("surfaces");
  }

  // 5. The volume warp.
  if (request.want_labels || request.want_ct || request.want_fields) {
    const pose::RigidTransform& root = transforms[static_cast<size_t>(skeleton.root)];
    POSEWARP_ASSIGN_OR_RETURN(result.output_grid,
                              resample::output_geometry(request.grid, source, result.posed_vertices,
                                                        request.given_grid ? &*request.given_grid : nullptr,
                                                        request.resample));
    POSEWARP_RETURN_IF_ERROR(check_output_budget(request, result.output_grid).status());
    resample::ResampleParams params = request.resample;
    if (rig_.ct) params.intensity_background = std::max(ct_minimum_, params.intensity_background);
    resample::RigidBones bones;
    bones.voxels = &bone_voxels_;
    bones.rotation = segments.rotation;
    bones.translation = segments.translation;
    bones.region = &region_;
    bones.tet_region = &tet_region_;
    bones.separated = &separated_;
    POSEWARP_ASSIGN_OR_RETURN(resample::TetWarp warp,
                              resample::TetWarp::build(mesh, result.posed_vertices, source, result.output_grid,
                                                       root.rotation, root.translation, &rest_owner_, params, hooks,
                                                       &bones));
    const resample::WarpStats& stats = warp.stats();
    qr.covered_voxels = stats.covered_voxels;
    qr.conflicted_voxels = stats.conflicted_voxels;
    qr.extrapolated_voxels = stats.extrapolated_voxels;
    qr.background_voxels = stats.background_voxels;
    qr.degenerate_tets = stats.degenerate_tets;
    qr.rasterized_tets = warp.rasterized_tets();
    qr.bone_voxels = stats.bone_voxels;
    qr.skin_contact_voxels = stats.contact_guarded_voxels;
    for (const auto& [pair, count] : stats.bone_overlap_voxels) {
      qr.bone_overlaps.push_back({names[static_cast<size_t>(pair.first)], names[static_cast<size_t>(pair.second)], count,
                                  static_cast<double>(count) * result.output_grid.spacing[0] *
                                      result.output_grid.spacing[1] * result.output_grid.spacing[2] / 1000.0});
    }
    clock.lap("warp-prepare");
    // The volumes first, each handed to its callback as soon as it is complete (a server sends it while the rest
    // is computed), then the label report, which needs only the labels.
    std::shared_ptr<const LabelVolume> handed_out;  // the labels given to labels_ready: the report reads them
    const LabelVolume* posed_labels = nullptr;
    if (request.want_labels) {
      POSEWARP_ASSIGN_OR_RETURN(LabelVolume labels, warp.warp_labels(rig_.labels));
      clock.lap("warp-labels");
      if (request.labels_ready) {
        handed_out = std::make_shared<const LabelVolume>(std::move(labels));
        posed_labels = handed_out.get();
        request.labels_ready(handed_out);
      } else {
        posed_labels = &result.labels.emplace(std::move(labels));
      }
    }
    if (request.want_ct && rig_.ct) {
      POSEWARP_ASSIGN_OR_RETURN(IntensityVolume ct, warp.warp_intensities(*rig_.ct, request.ct_interpolation));
      clock.lap("warp-ct");
      if (request.ct_ready) {
        request.ct_ready(std::make_shared<const IntensityVolume>(std::move(ct)));
      } else {
        result.ct = std::move(ct);
      }
    }
    if (request.want_labels) {
      POSEWARP_RETURN_IF_ERROR(StageProgress(hooks, "pose").check_cancel());
      qr.labels = report::label_change(rest_label_counts_, report::label_counts(*posed_labels));
      for (const auto& [value, counts] : qr.labels.voxels) {
        if (const labels::LabelEntry* entry = rig_.label_map.find(value)) qr.label_names[value] = entry->name;
      }
      const std::vector<std::pair<double, double>> deviation = warp.bone_deviation_mm();
      for (size_t k = 0; k < deviation.size(); ++k) {
        qr.voxel_rigidity.push_back({names[k], deviation[k].first, deviation[k].second});
        qr.bone_voxel_deviation_mm = std::max(qr.bone_voxel_deviation_mm, deviation[k].first);
      }
      clock.lap("report-labels");
    }
    if (request.want_fields) {
      result.inverse_field = warp.inverse_displacement();
      // Forward field on the source grid: each bone voxel moves with its bone, every other source voxel with the rest
      // tet that covers it.
      result.forward_field.assign(static_cast<size_t>(source.voxel_count()) * 3, 0.0f);
      const Eigen::MatrixXd& posed = result.posed_vertices;
      parallel_for(0, source.size[2], 1, [&](int64_t k0, int64_t k1) {
        for (int64_t k = k0; k < k1; ++k) {
          for (int64_t j = 0; j < source.size[1]; ++j) {
            for (int64_t i = 0; i < source.size[0]; ++i) {
              const int64_t v = source.offset(i, j, k);
              const Vec3 p = source.index_to_physical({double(i), double(j), double(k)});
              const Eigen::Vector3d x(p[0], p[1], p[2]);
              int32_t t = rest_owner_[static_cast<size_t>(v)];
              if (t <= -2) t = -2 - t;
              Eigen::Vector3d moved;
              const int16_t bone = bone_voxels_.segment[static_cast<size_t>(v)];
              if (bone != resample::BoneVoxels::kNone) {  // a bone voxel moves with its bone, exactly
                moved = segments.rotation[static_cast<size_t>(bone)] * x + segments.translation[static_cast<size_t>(bone)];
              } else if (t >= 0) {
                Eigen::Matrix3d inv;
                for (int r = 0; r < 3; ++r)
                  for (int c = 0; c < 3; ++c) inv(r, c) = frames_.rest_inverse(t, 3 * r + c);
                const Eigen::Vector3d lambda = inv * (x - mesh.vertices.row(mesh.tets(t, 0)).transpose());
                moved = posed.row(mesh.tets(t, 0)).transpose();
                for (int c = 0; c < 3; ++c) {
                  moved += lambda(c) * (posed.row(mesh.tets(t, c + 1)) - posed.row(mesh.tets(t, 0))).transpose();
                }
              } else {
                moved = root.apply(x);
              }
              for (int a = 0; a < 3; ++a) result.forward_field[static_cast<size_t>(3 * v + a)] = static_cast<float>(moved(a) - x(a));
            }
          }
        }
      });
      clock.lap("fields");
    }
  }
  report::add_warnings(qr, voxel);
  return result;
}

}  // namespace posewarp::api
