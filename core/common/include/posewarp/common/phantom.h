// Phantoms: synthetic studies with known joints (a bar, a mannequin, a realistic body) and their knobs. Making
// them: phantom/.
#pragma once

#include <array>
#include <cstdint>
#include <string>
#include <utility>
#include <vector>

#include "posewarp/common/image_geometry.h"
#include "posewarp/common/label_map.h"
#include "posewarp/common/volume.h"

namespace posewarp {

// A joint whose centre is known by construction.
struct JointTruth {
  std::string name;
  std::string parent_segment;  // the segment nearer the root
  std::string child_segment;
  Vec3 centre_mm{};            // LPS, mm
  // "ball" (a sphere in a socket; the centre is the sphere's), "hinge" (a transverse cylinder in a notch or under
  // a flat end; the centre is the midpoint of its axis) or "plane" (bone ends facing across a soft gap; the centre
  // is the middle of the gap)
  std::string kind;
  Vec3 axis{};  // hinges: the unit hinge axis in LPS, pointing to the patient's left; zero for other kinds
};

struct Phantom {
  std::string name;
  LabelVolume labels;
  IntensityVolume ct;  // Hounsfield units, same grid as labels
  LabelMap label_map;
  std::string root_segment;
  std::vector<JointTruth> joints;
  double joint_gap_mm = 0.0;
  // Body parts whose skins touch or overlap by construction, so the body mask is one piece there (e.g.
  // {"arm_left", "trunk"}); empty for phantoms whose limbs stand free.
  std::vector<std::pair<std::string, std::string>> skin_contacts;
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

// A supine body as CT shows it, in LPS (x = patient left, y = posterior, z = superior), feet near z = 0, every
// length scaled by height / 1700 mm. Skin: elliptic trunk, shoulders, neck, head, thighs whose skins overlap at
// the midline, legs and feet pointing anteriorly, upper arms whose skin overlaps the trunk's, forearms along the
// flank and hands resting on the lateral thighs; a subcutaneous fat shell, a liver and a brain.
// Bones and joints (the true centres in Phantom::joints; default gap = 1.2 voxel diagonals):
// - pelvis (sacrum, hip_left/right halves) with hemispherical acetabula; hips are balls (femoral head r 24) in
//   them; femur with neck at 130 degrees to the shaft, greater trochanter, shaft inclined medially, transverse
//   condyle cylinder (r 22, 70 long): the knee is a hinge over a flat tibial plateau; a patella in front of the
//   condyles; ankle = hinge (talar dome, a transverse cylinder r 18, under a concave tibial mortise with a
//   medial malleolus); a foot pointing anteriorly;
// - lumbar vertebrae L5..L1 and the thorax (thoracic spine, rib shell, sternum), cervical spine, skull: flat
//   ends across soft gaps;
// - clavicles (sternoclavicular and acromioclavicular gaps), scapulae lying on the rib shell (touching it) with
//   an acromion and a shallow glenoid cup (half-angle 35 degrees) holding the humeral head (r 22); elbow = hinge
//   (trochlea, a transverse cylinder r 13, in the forearm's notch, a coronoid fossa in front of it); wrist = ball
//   (the proximal carpal row's head, r 10, in the radius's cup).
// Label values, names (TotalSegmentator-like) and segments are in the phantom's label map; the root is pelvis.
struct BodyPhantomParams {
  // Voxel spacing along the index axes (i, j in-plane, k between slices), mm.
  Vec3 spacing_mm{2.5, 2.5, 5.0};
  double height_mm = 1700.0;  // standing height; every length scales with it
  double joint_gap_mm = 0.0;  // soft gap at every joint; 0 = 1.2 voxel diagonals (a soft voxel in every direction)
  double fat_mm = 10.0;       // subcutaneous fat thickness at 1700 mm height
  // The skin grown outwards by this much at 1700 mm height (the fat shell with it): a heavier body on the same
  // skeleton, whose soft tissue differs from the default's while every bone and joint stays where it is.
  double skin_offset_mm = 0.0;
  double margin_mm = 12.0;    // air around the body
  double noise_hu = 5.0;      // amplitude of deterministic CT noise
  uint64_t seed = 1;
  // Grid direction (row-major, columns = index axes in LPS); must be a rotation. Default: oblique, 8 degrees
  // about the tilted axis (1, 2, 6).
  std::array<double, 9> direction = rotation_direction({1.0, 2.0, 6.0}, 8.0);
};

}  // namespace posewarp
