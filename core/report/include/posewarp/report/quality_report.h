// The quality report of a pose (DESIGN.md section 9): make damage visible instead of silent.
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "posewarp/common/tet_mesh.h"
#include "posewarp/common/volume.h"

namespace posewarp::report {

struct MeshChange {
  int64_t inverted_tets = 0;            // det(A_t) <= 0
  double det_min = 1.0, det_max = 1.0;  // range of det(A_t) over all tets
  double soft_tissue_volume_change = 0.0;  // posed / rest soft-tissue mesh volume - 1
  double body_volume_change = 0.0;
  // Volume-weighted mean of |det(A_t) - 1| over soft-tissue tets: local squashing and bulging, which cancel in
  // the total (DQS bulges on one side of a bend and pinches on the other).
  double soft_tissue_local_volume_error = 0.0;
};

// det: per-tet determinants of the rest -> posed maps; rest_volume: per-tet rest volumes (mm^3).
MeshChange mesh_change(const TetMesh& rest, const Eigen::VectorXd& det, const Eigen::VectorXd& rest_volume);

struct SegmentRigidity {
  std::string segment;
  double max_error_mm = 0.0;  // largest distance of a bone vertex from its segment's rigid transform
};

// For every bone segment: how far the posed vertices of its tets lie from the segment's rigid transform of their
// rest positions. rotation/translation: rest -> posed per segment.
std::vector<SegmentRigidity> bone_rigidity(const TetMesh& rest, const Eigen::MatrixXd& posed,
                                           const std::vector<Eigen::Matrix3d>& rotation,
                                           const std::vector<Eigen::Vector3d>& translation,
                                           const std::vector<std::string>& segment_names);

// Soft tissue around one moved joint: the tets whose rest centroid lies within radius_mm of the joint centre.
struct JointRegionChange {
  std::string joint;
  double radius_mm = 0.0;
  double rest_volume_ml = 0.0;
  double volume_change = 0.0;       // posed / rest soft-tissue volume - 1
  double folded_fraction = 0.0;     // of the rest volume in tets with det <= 0
  double stretched_fraction = 0.0;  // of the rest volume in tets with det > 2 or 0 < det < 0.5
  // Skin vertices within the radius (rest) and those that ended inside tissue or bone from elsewhere in the body:
  // a crease where one part passed into the part facing it (fem/soft_tissue.h, penetration). Filled by the engine.
  int64_t skin_vertices = 0;
  int64_t skin_inside_tissue = 0;
  int64_t skin_inside_bone = 0;
};

// For each joint centre (rest, LPS mm) and each radius: the soft-tissue change around it.
std::vector<JointRegionChange> joint_region_changes(const TetMesh& rest, const Eigen::VectorXd& det,
                                                   const Eigen::VectorXd& rest_volume,
                                                   const std::vector<std::pair<std::string, Eigen::Vector3d>>& joints,
                                                   const std::vector<double>& radii_mm);

// Bone rigidity measured on the output voxels that hold a bone's value (TetWarp::bone_deviation_mm).
struct SegmentVoxelRigidity {
  std::string segment;
  double max_mm = 0.0;
  double p99_mm = 0.0;
};

// Two bones that pass through each other in the pose.
struct BoneOverlap {
  std::string segment_a, segment_b;
  int64_t voxels = 0;
  double volume_ml = 0.0;
};

// A moved joint turned past the range of motion measured for it at rig build, where its bones meet (rig::Joint::
// ranges): the pose asks for what the study's bones do not allow, and bone overlap or crushed tissue follows.
struct JointPastRange {
  std::string joint;
  std::string motion;        // "flexion" or "abduction"
  double angle_deg = 0.0;    // the pose's angle of that motion
  double negative_deg = 0.0, positive_deg = 0.0;  // the measured range: -negative_deg .. positive_deg
};

// When a figure of the report is bad enough to warn about.
struct WarningThresholds {
  double bone_deviation_voxels = 0.5;  // a bone voxel further than this from its bone's rigid motion
  double bone_overlap_ml = 1.0;        // per pair of bones
  double local_volume_change = 0.10;   // |change| of soft tissue within a moved joint's largest radius
  double folded_fraction = 0.01;
  double skin_inside_fraction = 0.01;  // of a moved joint's skin vertices passed into tissue or bone facing them
  double stretched_fraction = 0.05;
};

struct LabelChange {
  std::map<Label, std::pair<int64_t, int64_t>> voxels;  // label -> (before, after)
  std::vector<Label> vanished;                          // present before, absent after
  std::vector<Label> appeared;                          // absent before, present after (must stay empty)
};

// Voxels per label value (parallel; dense counting where the values span a small range).
std::map<Label, int64_t> label_counts(const LabelVolume& labels);
LabelChange label_change(const std::map<Label, int64_t>& before, const std::map<Label, int64_t>& after);

struct QualityReport {
  std::string pose_name;
  std::string method;
  MeshChange mesh;
  std::vector<SegmentRigidity> rigidity;
  double bone_rigidity_error_mm = 0.0;      // max over segments
  double bone_rigidity_error_voxels = 0.0;  // the same in voxels of the source grid
  LabelChange labels;
  std::map<Label, std::string> label_names;
  int64_t covered_voxels = 0, conflicted_voxels = 0, extrapolated_voxels = 0, background_voxels = 0;
  int64_t degenerate_tets = 0;
  int64_t rasterized_tets = 0;  // tets the warp rasterized: those not moving with the background (root)
  int64_t bone_voxels = 0;      // output voxels mapped by their bone's own rigid transform
  // Output voxels whose tet (or skin shell) would have shown tissue of a body part cut apart from its own at a skin
  // contact (a hand's shell over the thigh it rested on): left empty (background) instead.
  int64_t skin_contact_voxels = 0;
  std::vector<SegmentVoxelRigidity> voxel_rigidity;  // per segment, when labels were warped
  double bone_voxel_deviation_mm = 0.0;              // max over segments
  std::vector<BoneOverlap> bone_overlaps;
  std::vector<JointRegionChange> joint_regions;      // around each joint the pose moves, at 50 and 100 mm
  std::vector<JointPastRange> past_range;            // moved joints turned past where their bones meet
  std::vector<std::string> warnings;                 // figures over WarningThresholds, in words
  std::vector<std::pair<std::string, double>> stage_seconds;
};

// Fills report.warnings from its figures. `voxel_mm`: the source grid's smallest spacing.
void add_warnings(QualityReport& report, double voxel_mm, const WarningThresholds& thresholds = {});

std::string to_json(const QualityReport& report);

}  // namespace posewarp::report
