// The quality report's parts that PoseEngine fills as a pose goes (pose_report.h).
#include "pose_report.h"

#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <optional>

#include "posewarp/common/parallel.h"
#include "posewarp/common/stopwatch.h"
#include "posewarp/fem/soft_tissue.h"
#include "posewarp/labels/label_map.h"
#include "posewarp/pose/forward_kinematics.h"
#include "posewarp/report/quality_report.h"

namespace posewarp::api::internal {
namespace {

// A joint rotation's flexion and abduction in degrees: the pose's own angles when it gave them, else the rotation
// `turn` (LPS) read in the joint's frame as x, then y, then z (rig::joint_rotation_from_angles's order).
std::pair<double, double> flexion_and_abduction(const rig::Joint& joint, const pose::JointRotation& rotation,
                                                const Eigen::Matrix3d& turn) {
  if (rotation.angles_deg) return {rotation.angles_deg->x(), rotation.angles_deg->y()};
  const Eigen::Matrix3d m = joint.frame.transpose() * turn * joint.frame;  // Rx(f) Ry(a) Rz(r)
  constexpr double kDegrees = 180.0 / M_PI;
  return {std::atan2(-m(1, 2), m(2, 2)) * kDegrees, std::asin(std::clamp(m(0, 2), -1.0, 1.0)) * kDegrees};
}

}  // namespace

void report_mesh(const PoseEngine::Prepared& p, const Pose& pose, const skinning::SegmentTransforms& segments,
                 const std::vector<std::string>& names, const ProgressHooks& hooks, PoseResult& result) {
  const TetMesh& mesh = p.rig.mesh;
  const rig::Skeleton& skeleton = p.rig.skeleton;
  QualityReport& qr = result.report;
  PhaseClock phases(hooks, "report-mesh");
  const Eigen::VectorXd det = skinning::tet_determinants(mesh, p.frames, result.posed_vertices);
  phases.mark("determinants");
  // The mesh's volume change is one serial pass (its sums in tet order, so that they are the same at any thread
  // count); it runs beside the rest of the report, whose passes are parallel, rather than before it. Each side's
  // phases are timed on its own clock and handed to the hook once both are done.
  double volume_change_s = 0.0, rigidity_s = 0.0, regions_s = 0.0, penetration_s = 0.0;
  const auto rest_of_report = [&] {
    Stopwatch clock;
    qr.rigidity = report::bone_rigidity(mesh, result.posed_vertices, segments.rotation, segments.translation, names);
    const ImageGeometry& source = p.rig.labels.geometry();
    const double voxel = std::min({source.spacing[0], source.spacing[1], source.spacing[2]});
    for (const SegmentRigidity& s : qr.rigidity)
      qr.bone_rigidity_error_mm = std::max(qr.bone_rigidity_error_mm, s.max_error_mm);
    qr.bone_rigidity_error_voxels = qr.bone_rigidity_error_mm / voxel;
    std::vector<std::pair<std::string, Eigen::Vector3d>> moved_joints;
    for (const JointRotation& rotation : pose.joints) {
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
    rigidity_s = clock.lap();
    const std::vector<double> radii{50.0, 100.0};
    qr.joint_regions = report::joint_region_changes(mesh, det, p.frames.rest_volume, moved_joints, radii);
    regions_s = clock.lap();
    std::vector<Eigen::Vector3d> centres;
    for (const auto& [name, centre] : moved_joints) centres.push_back(centre);
    const std::vector<std::vector<fem::Penetration>> inside =
        fem::penetration(mesh, result.posed_vertices, skin_of(p), centres, radii);
    for (size_t j = 0; j < moved_joints.size(); ++j) {
      for (size_t r = 0; r < radii.size(); ++r) {
        JointRegionChange& change = qr.joint_regions[j * radii.size() + r];
        change.skin_vertices = inside[j][r].skin_vertices;
        change.skin_inside_tissue = inside[j][r].inside_tissue;
        change.skin_inside_bone = inside[j][r].inside_bone;
      }
    }
    penetration_s = clock.lap();
  };
  parallel_for(0, 2, 1, [&](int64_t begin, int64_t end) {
    for (int64_t part = begin; part < end; ++part) {
      if (part == 0) {
        Stopwatch clock;
        qr.mesh = report::mesh_change(mesh, det, p.frames.rest_volume);
        volume_change_s = clock.seconds();
      } else {
        rest_of_report();
      }
    }
  });
  phases.report("volume-change (beside the rest)", volume_change_s);
  phases.report("rigidity", rigidity_s);
  phases.report("joint-regions", regions_s);
  phases.report("penetration", penetration_s);
}

void report_warp(const resample::TetWarp& warp, const std::vector<std::string>& names, PoseResult& result) {
  QualityReport& qr = result.report;
  const resample::WarpStats& stats = warp.stats();
  qr.covered_voxels = stats.covered_voxels;
  qr.conflicted_voxels = stats.conflicted_voxels;
  qr.extrapolated_voxels = stats.extrapolated_voxels;
  qr.background_voxels = stats.background_voxels;
  qr.degenerate_tets = stats.degenerate_tets;
  qr.rasterized_tets = warp.rasterized_tets();
  qr.bone_voxels = stats.bone_voxels;
  qr.skin_contact_voxels = stats.contact_guarded_voxels;
  const ImageGeometry& g = result.output_grid;
  for (const auto& [pair, count] : stats.bone_overlap_voxels) {
    qr.bone_overlaps.push_back({names[static_cast<size_t>(pair.first)], names[static_cast<size_t>(pair.second)], count,
                                static_cast<double>(count) * g.spacing[0] * g.spacing[1] * g.spacing[2] / 1000.0});
  }
}

void report_labels(const PoseEngine::Prepared& p, const resample::TetWarp& warp, const LabelVolume& posed,
                   const std::vector<std::pair<double, double>>& deviation, const std::vector<std::string>& names,
                   QualityReport& qr) {
  // The posed values are rest values or the background: their range is known.
  std::optional<std::pair<Label, Label>> range;
  if (!p.rest_label_counts.empty()) {
    range.emplace(std::min(p.rest_label_counts.begin()->first, warp.label_background()),
                  std::max(p.rest_label_counts.rbegin()->first, warp.label_background()));
  }
  qr.labels = report::label_change(p.rest_label_counts, report::label_counts(posed, range));
  for (const auto& [value, counts] : qr.labels.voxels) {
    if (const labels::LabelEntry* entry = p.rig.label_map.find(value)) qr.label_names[value] = entry->name;
  }
  for (size_t k = 0; k < deviation.size(); ++k) {
    qr.voxel_rigidity.push_back({names[k], deviation[k].first, deviation[k].second});
    qr.bone_voxel_deviation_mm = std::max(qr.bone_voxel_deviation_mm, deviation[k].first);
  }
}

std::vector<std::string> segment_names(const rig::Skeleton& skeleton) {
  std::vector<std::string> names;
  for (const rig::Segment& s : skeleton.segments) names.push_back(s.name);
  return names;
}

}  // namespace posewarp::api::internal
