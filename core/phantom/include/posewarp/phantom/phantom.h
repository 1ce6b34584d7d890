// Synthetic bodies with exactly known geometry (label + CT volumes and true joint centres) for tests and benchmarks.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "posewarp/common/result.h"
#include "posewarp/common/volume.h"
#include "posewarp/labels/label_map.h"

namespace posewarp::phantom {

// A joint whose centre is known by construction.
struct JointTruth {
  std::string name;
  std::string parent_segment;  // the segment nearer the root
  std::string child_segment;
  Vec3 centre_mm{};            // LPS, mm
  std::string kind;            // "ball" (a sphere in a socket) or "plane" (two flat bone ends facing)
};

struct Phantom {
  std::string name;
  LabelVolume labels;
  IntensityVolume ct;  // Hounsfield units, same grid as labels
  labels::LabelMap label_map;
  std::string root_segment;
  std::vector<JointTruth> joints;
  double joint_gap_mm = 0.0;
};

// The paper's bar (Sujar et al. 2018, Fig. 7): a soft-tissue cylinder along +z holding a chain of bones on its
// axis, separated by soft gaps.
struct BarParams {
  double spacing_mm = 2.0;      // isotropic voxel spacing
  double length_mm = 240.0;     // cylinder length
  double radius_mm = 30.0;      // soft-tissue radius
  double bone_radius_mm = 9.0;  // bone radius
  int bone_count = 4;           // bones in the chain (2..16)
  double joint_gap_mm = 0.0;    // soft gap between bones; 0 = two voxels
  double margin_mm = 10.0;      // air around the body
  double noise_hu = 5.0;        // amplitude of deterministic CT noise
  uint64_t seed = 1;            // noise seed
  // Grid direction (row-major, columns = index axes in LPS); must be a rotation.
  std::array<double, 9> direction{1, 0, 0, 0, 1, 0, 0, 0, 1};
};

// A supine mannequin in LPS (x = patient left, y = posterior, z = superior), feet at z = 0: trunk with pelvis,
// five lumbar vertebrae and a thorax (thoracic spine, rib shell, shoulder girdle), two legs (femur, tibia), two
// arms (humerus, forearm) hanging at the sides, a head (skull with cervical spine, brain), subcutaneous fat and
// a liver. Hips and shoulders are balls in sockets; knees, elbows, the spine and the neck are flat bone ends
// facing across a soft gap. Label values and segments are in the phantom's label map.
struct MannequinParams {
  double spacing_mm = 3.0;      // isotropic voxel spacing
  double height_mm = 1700.0;    // standing height; every length scales with it
  double joint_gap_mm = 0.0;    // soft gap at every joint; 0 = two voxels
  double fat_mm = 10.0;         // subcutaneous fat thickness at 1700 mm height
  double margin_mm = 12.0;      // air around the body
  double noise_hu = 5.0;        // amplitude of deterministic CT noise
  uint64_t seed = 1;
  std::array<double, 9> direction{1, 0, 0, 0, 1, 0, 0, 0, 1};
};

Status validate(const BarParams& params);
Status validate(const MannequinParams& params);

Result<Phantom> make_bar(const BarParams& params);
Result<Phantom> make_mannequin(const MannequinParams& params);

// The isotropic spacing that gives a mannequin of about `target_voxels` voxels with the other parameters kept.
double mannequin_spacing_for_voxels(const MannequinParams& params, int64_t target_voxels);

// {"phantom": ..., "root_segment": ..., "joint_gap_mm": ..., "joints": [{"name", "parent", "child",
//  "centre_mm": [x, y, z], "kind"}]}
std::string joints_to_json(const Phantom& phantom);

}  // namespace posewarp::phantom
