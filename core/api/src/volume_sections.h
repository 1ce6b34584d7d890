// A rig's label and CT volumes as rig file sections.
//
// Format 2 (written): the grid (size, spacing, origin, direction), the source type, the type the samples are
// stored in (the source's when every value converts to it exactly: uint8 labels, int16 CT; otherwise the volume's
// own int32 or float32), the samples per chunk, the chunk count and each chunk's compressed size, then the chunks,
// each deflated on its own (zlib format) so that a volume is compressed and inflated on every thread.
// Format 1 (read only): the grid, the source type, then the volume's own samples as one zlib stream.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>

#include "posewarp/common/compact_intensities.h"
#include "posewarp/common/result.h"
#include "posewarp/common/volume.h"

namespace posewarp::api::internal {

template <typename T>
std::string volume_section(const Volume<T>& volume);

// DATA_LOSS naming the section (`name`) for a damaged payload, refused before the volume is allocated when its
// grid claims more voxels than its bytes can hold.
template <typename T>
Status read_volume_section(std::string_view payload, const std::string& name, uint32_t format, Volume<T>& volume);

// The CT's section: written as the float volume it holds the values of would be (the same bytes, so the same rig
// hash), read into int16 when its samples are int16, uint8 or int8 (no float copy on the way), else into float,
// narrowed when every value fits.
std::string intensity_section(const CompactIntensities& intensities);
Status read_intensity_section(std::string_view payload, const std::string& name, uint32_t format,
                              CompactIntensities& intensities);

}  // namespace posewarp::api::internal
