// The engine's tables (engine_tables.h) as rig file sections, and their checks: what the rig file reader needs of them
// (no stage but for headers, so the rig file fuzzer compiles it alone).
#pragma once

#include <string>
#include <string_view>
#include <vector>

#include "posewarp/api/rig.h"

namespace posewarp::api::internal {

// DATA_LOSS unless the tables a rig file gave are one value per source voxel, each within its range (a tet of the
// mesh, its shell or none; a segment of the skeleton or -1), and substitutes of ascending voxels by voxels of the
// grid: the warp indexes with them. Likewise the engine's summary, when the file has one: a region per tet of the
// mesh (a segment or -1), label counts that add up to the labels' voxels, and a lowest value where there is a CT.
Status check_engine_tables(const Rig& rig);

// The tables as rig file sections (runs of equal values, deflated) and back. `grid` and `voxels` are the rig's grid
// (source_geometry; voxels -1 and a size of 0 for a grid that is not one): a table of another size, or a damaged
// payload, is DATA_LOSS before anything large is allocated. The owner and region tables are read straight onto their
// rows' spans (fill -1).
std::string owner_section(const RowPacked<int32_t>& owner);
std::string region_section(const RowPacked<int16_t>& region);
std::string substitute_section(const BoneSubstitutes& substitutes, int64_t voxels);  // as offsets, 0 but at bones
Status read_owner_section(std::string_view payload, const Index3& grid, RowPacked<int32_t>& owner);
Status read_region_section(std::string_view payload, const Index3& grid, RowPacked<int16_t>& region);
Status read_substitute_section(std::string_view payload, int64_t voxels, BoneSubstitutes& substitutes);

// The engine's summary (rig.tet_region, rest_label_counts, ct_lowest) as a rig file section (ENGN) and back: the
// label counts as (value, count) pairs, the CT's lowest value when the rig has a CT, then the tets' regions, deflated.
// A damaged payload is DATA_LOSS before anything large is allocated; check_engine_tables checks the summary against
// the mesh and volumes once every section is read.
std::string summary_section(const Rig& rig);
Status read_summary_section(std::string_view payload, Rig& rig);

// zlib-format data inflated into `out` (exactly out_bytes), as libdeflate does it: twice zlib's speed, for the rig's
// volume sections too. False when the data is damaged or does not fill `out` exactly.
bool inflate_exactly(std::string_view packed, void* out, size_t out_bytes);

}  // namespace posewarp::api::internal
