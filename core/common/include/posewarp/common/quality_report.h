// The quality report of a pose (DESIGN.md section 9), as data: what the report stage measures and the api hands its
// callers (the engine fills it; posewarp::report computes its figures and writes it as JSON). Vocabulary, like
// TetMesh: stages and the api share it, so it lives here.
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <utility>
#include <vector>

#include "posewarp/common/volume.h"

namespace posewarp {

struct MeshChange {
  int64_t inverted_tets = 0;               // det(A_t) <= 0
  double det_min = 1.0, det_max = 1.0;     // range of det(A_t) over all tets
  double soft_tissue_volume_change = 0.0;  // posed / rest soft-tissue mesh volume - 1
  double body_volume_change = 0.0;
  // Volume-weighted mean of |det(A_t) - 1| over soft-tissue tets: local squashing and bulging, which cancel in
  // the total (DQS bulges on one side of a bend and pinches on the other).
  double soft_tissue_local_volume_error = 0.0;
};

struct SegmentRigidity {
  std::string segment;
  double max_error_mm = 0.0;  // largest distance of a bone vertex from its segment's rigid transform
};

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

// Bone rigidity measured on the output voxels that hold a bone's value (TetWarp::warp_labels, bone_deviation_mm).
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
  std::string motion;                             // "flexion" or "abduction"
  double angle_deg = 0.0;                         // the pose's angle of that motion
  double negative_deg = 0.0, positive_deg = 0.0;  // the measured range: -negative_deg .. positive_deg
};

struct LabelChange {
  std::map<Label, std::pair<int64_t, int64_t>> voxels;  // label -> (before, after)
  std::vector<Label> vanished;                          // present before, absent after
  std::vector<Label> appeared;                          // absent before, present after (must stay empty)
};

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
  std::vector<JointRegionChange> joint_regions;  // around each joint the pose moves, at 50 and 100 mm
  std::vector<JointPastRange> past_range;        // moved joints turned past where their bones meet
  std::vector<std::string> warnings;             // figures over WarningThresholds, in words
  std::vector<std::pair<std::string, double>> stage_seconds;
};

}  // namespace posewarp
