// The quality report of a pose (DESIGN.md section 9): make damage visible instead of silent.
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "posewarp/common/quality_report.h"
#include "posewarp/common/tet_mesh.h"
#include "posewarp/common/volume.h"

namespace posewarp::report {

// The report's data (posewarp/common/quality_report.h), under the names the stage has always used.
using posewarp::MeshChange;
using posewarp::SegmentRigidity;
using posewarp::JointRegionChange;
using posewarp::SegmentVoxelRigidity;
using posewarp::BoneOverlap;
using posewarp::JointPastRange;
using posewarp::LabelChange;
using posewarp::QualityReport;

// det: per-tet determinants of the rest -> posed maps; rest_volume: per-tet rest volumes (mm^3).
MeshChange mesh_change(const TetMesh& rest, const Eigen::VectorXd& det, const Eigen::VectorXd& rest_volume);

// For every bone segment: how far the posed vertices of its tets lie from the segment's rigid transform of their
// rest positions. rotation/translation: rest -> posed per segment.
std::vector<SegmentRigidity> bone_rigidity(const TetMesh& rest, const Eigen::MatrixXd& posed,
                                           const std::vector<Eigen::Matrix3d>& rotation,
                                           const std::vector<Eigen::Vector3d>& translation,
                                           const std::vector<std::string>& segment_names);

// For each joint centre (rest, LPS mm) and each radius: the soft-tissue change around it.
std::vector<JointRegionChange> joint_region_changes(const TetMesh& rest, const Eigen::VectorXd& det,
                                                   const Eigen::VectorXd& rest_volume,
                                                   const std::vector<std::pair<std::string, Eigen::Vector3d>>& joints,
                                                   const std::vector<double>& radii_mm);

// When a figure of the report is bad enough to warn about.
struct WarningThresholds {
  double bone_deviation_voxels = 0.5;  // a bone voxel further than this from its bone's rigid motion
  double bone_overlap_ml = 1.0;        // per pair of bones
  double local_volume_change = 0.10;   // |change| of soft tissue within a moved joint's largest radius
  double folded_fraction = 0.01;
  double skin_inside_fraction = 0.01;  // of a moved joint's skin vertices passed into tissue or bone facing them
  double stretched_fraction = 0.05;
};

// Voxels per label value (parallel; dense counting where the values span a small range). `expected`, the range the
// values should lie in (a posed volume's: the rest values and the background), spares a pass that finds it; a value
// outside it is still counted (the range is then found, as without it).
std::map<Label, int64_t> label_counts(const LabelVolume& labels, std::optional<std::pair<Label, Label>> expected = {});
LabelChange label_change(const std::map<Label, int64_t>& before, const std::map<Label, int64_t>& after);

// Fills report.warnings from its figures. `voxel_mm`: the source grid's smallest spacing.
void add_warnings(QualityReport& report, double voxel_mm, const WarningThresholds& thresholds = {});

std::string to_json(const QualityReport& report);

}  // namespace posewarp::report
