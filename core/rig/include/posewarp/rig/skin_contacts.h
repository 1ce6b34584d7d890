// Body parts that touch at rest (an arm against the trunk, thigh against thigh, a hand on the thigh) are joined in
// the body mask, so one tet mesh would tie their soft tissue together and posing would tear a web of tissue between
// them. The body is cut along such skin contacts before meshing: each soft voxel belongs to the region of its
// nearest bone, and where two regions that must move apart meet near the skin, the voxels on both sides leave the
// mesh (the warp's skin shell still maps them).
#pragma once

#include <cstdint>
#include <vector>

#include "posewarp/common/result.h"
#include "posewarp/common/rig_params.h"
#include "posewarp/common/tet_mesh.h"
#include "posewarp/common/volume.h"
#include "posewarp/rig/skeleton.h"

namespace posewarp::rig {

using posewarp::SkinContactParams;  // posewarp/common/rig_params.h

Status validate(const SkinContactParams& params);

// Per voxel of the labels' grid: the bone segment whose voxels are nearest through the body (-1 outside it) and the
// depth below the skin (mm; 0 outside), both from 26-neighbour chamfer distances (within about 8%). A limb's region
// goes no deeper below the skin than the bone voxel it comes from (give or take half a voxel): a limb resting
// against the trunk takes none of the trunk's tissue beyond the contact.
struct BodyRegions {
  std::vector<int16_t> segment;
  std::vector<float> depth_mm;
};

Result<BodyRegions> body_regions(const Skeleton& skeleton, const LabelVolume& labels, const LabelVolume& body);

// Per segment: 1 in a limb (below a ball joint whose child is on one side: hip, shoulder; without declared kinds, a
// sphere-fitted joint), 0 in the trunk.
std::vector<uint8_t> limb_segments(const Skeleton& skeleton);

// separated[a * n + b]: regions a and b must not share soft tissue where they meet near the skin. A limb is the
// subtree below a ball joint whose child is on one side (hip, shoulder; without declared kinds, a sphere-fitted
// joint). Two limbs are separated (thigh against thigh, hand on thigh); a limb is separated from the trunk except
// from the bone it hangs from and that bone's lateral ancestors (scapula, clavicle); the trunk is never cut.
std::vector<uint8_t> separated_segments(const Skeleton& skeleton);

struct SkinContactCut {
  int64_t voxels = 0;                                // soft voxels taken out of the mesher classes
  std::vector<std::pair<int, int>> segment_pairs;    // the separated regions that touched, (a < b)
};

// Sets to 0 (outside) the soft-tissue mesher classes (1) on both sides of every skin contact.
SkinContactCut cut_skin_contacts(LabelVolume& classes, const Skeleton& skeleton, const BodyRegions& regions,
                                 const SkinContactParams& params);

// Per mesh vertex: the region of the voxel it lies in, or of the nearest voxel with one within two voxels; -1.
std::vector<int> vertex_regions(const TetMesh& mesh, const BodyRegions& regions, const ImageGeometry& grid);

// Keeps each vertex's weights within its body part: a bone separated from the vertex's region (the other thigh, the
// arm for the trunk's flank) loses its weight there, the rest are renormalized (a vertex left with none follows its
// region's own bone). Laplace weights otherwise diffuse from one thigh through the groin into the other. Returns the
// number of vertices changed.
int64_t keep_weights_within_regions(SkinWeights& weights, const std::vector<int>& vertex_region,
                                    const Skeleton& skeleton);

// Tears the mesh along skin contacts: removes the soft-tissue tets whose vertices lie in separated regions (the
// mesher bridges a cut thinner than its cells), and the vertices no tet uses any more. `regions` is on `grid`.
// Returns the number of tets removed.
int64_t tear_skin_contacts(TetMesh& mesh, const Skeleton& skeleton, const BodyRegions& regions, const ImageGeometry& grid);

}  // namespace posewarp::rig
