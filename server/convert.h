// proto <-> core: the one place where posewarp.v1 messages meet the engine's types.
#pragma once

#include <string>

#include "posewarp/api/files.h"
#include "posewarp/api/match.h"
#include "posewarp/api/pose_engine.h"
#include "posewarp/v1/posewarp.pb.h"
#include "requests.h"
#include "store.h"

namespace posewarp::server {

void put_grid(const ImageGeometry& geometry, v1::Grid* grid);

// A checked method (requests.h: method_from) as the engine names it.
api::Method method_of(v1::Method method);
// The pixel type on the wire; UNSPECIFIED for 64-bit integers, which the proto does not carry.
v1::PixelType wire_pixel_type(PixelType type);

// The rig's description: the index row, the skeleton, mesh size and provenance.
void put_rig(const RigRecord& record, const api::Rig& rig, v1::Rig* message);
void put_rig_row(const RigRecord& record, v1::Rig* message);
void put_skeleton(const api::Rig& rig, v1::Skeleton* skeleton);
void put_surface(const SurfaceMesh& mesh, bool with_vertices, v1::Surface* message);
void put_report(const QualityReport& report, v1::QualityReport* message);
// A pose as the typed message: anatomical angles where the pose has them, else the joint's quaternion.
void put_pose(const api::Pose& pose, v1::Pose* message);
void put_segment_match(const api::SegmentMatch& match, v1::SegmentMatch* message);

// Operations between the index's rows and the wire.
v1::Operation operation_from(const OperationRecord& record);
OperationRecord record_from(const v1::Operation& operation, const v1::BuildRigRequest& request);
std::string state_name(v1::Operation::State state);
bool is_final(v1::Operation::State state);

// The samples of a RAW upload as a volume of the named type on `grid` (little-endian, x fastest).
Result<LabelVolume> labels_from_raw(std::string_view bytes, PixelType type, const ImageGeometry& grid);
Result<IntensityVolume> intensity_from_raw(std::string_view bytes, PixelType type, const ImageGeometry& grid);

}  // namespace posewarp::server
