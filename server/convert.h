// proto <-> core: the one place where posewarp.v1 messages meet the engine's types.
#pragma once

#include <string>

#include "posewarp/api/files.h"
#include "posewarp/api/pose_engine.h"
#include "posewarp/v1/posewarp.pb.h"
#include "store.h"

namespace posewarp::server {

void put_grid(const ImageGeometry& geometry, v1::Grid* grid);
// A client's grid, checked (3 sizes, spacings and origins, 9 direction entries, a valid geometry).
Result<ImageGeometry> grid_from(const v1::Grid& grid);

skinning::Method method_of(v1::Method method);
// The extension a stored upload of `format` gets, or nullptr for a format that is not a file.
const char* extension_of(v1::FileFormat format);
// RAW samples -> the pixel type, or nullopt.
std::optional<PixelType> pixel_type_of(v1::PixelType type);
// The pixel type on the wire; UNSPECIFIED for 64-bit integers, which the proto does not carry.
v1::PixelType wire_pixel_type(PixelType type);
// A client's mesh, checked (whole vertices and triangles, finite coordinates, indices in range).
Result<surface::SurfaceMesh> surface_from(const v1::Surface& message);

// The rig's description: the index row, the skeleton, mesh size and provenance.
void put_rig(const RigRecord& record, const api::Rig& rig, v1::Rig* message);
void put_rig_row(const RigRecord& record, v1::Rig* message);
void put_skeleton(const api::Rig& rig, v1::Skeleton* skeleton);
void put_surface(const surface::SurfaceMesh& mesh, bool with_vertices, v1::Surface* message);
void put_report(const report::QualityReport& report, v1::QualityReport* message);

// Operations between the index's rows and the wire.
v1::Operation operation_from(const OperationRecord& record);
OperationRecord record_from(const v1::Operation& operation, const v1::BuildRigRequest& request);
std::string state_name(v1::Operation::State state);
bool is_final(v1::Operation::State state);

// The samples of a RAW upload as a volume of the named type on `grid` (little-endian, x fastest).
Result<LabelVolume> labels_from_raw(std::string_view bytes, PixelType type, const ImageGeometry& grid);
Result<IntensityVolume> intensity_from_raw(std::string_view bytes, PixelType type, const ImageGeometry& grid);

}  // namespace posewarp::server
