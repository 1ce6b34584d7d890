// NIfTI-1 single files (.nii, .nii.gz) written without ITK's writer, which deflates a CT on one thread at zlib's
// default level (6 s for a 20M-voxel body). The header is ITK 5.2's, made by the same niftilib calls
// (NiftiImageIO::WriteImageInformation), so a file differs from ITK's only in how its bytes are compressed: .nii.gz
// is a multi-member gzip (RFC 1952, section 2.2: members one after another read as one stream, as zlib's gzread,
// ITK, nibabel and gzip do), its members deflated in parallel by libdeflate.
#pragma once

#include <cstdint>
#include <functional>
#include <string>
#include <string_view>

#include "posewarp/common/image_geometry.h"
#include "posewarp/common/result.h"
#include "posewarp/common/volume_file.h"

namespace posewarp::io::detail {

// Writes voxels [first, first + count) of the volume, converted to the file's voxel type, to `out`; false where a
// value does not fit that type.
using ConvertVoxels = std::function<bool(int64_t first, int64_t count, char* out)>;

// The 352 bytes in front of the voxels (header and an empty extension block), as ITK 5.2 writes them.
std::string nifti_header(const ImageGeometry& geometry, PixelType type);

// `bytes` as a multi-member gzip, its members deflated in parallel.
std::string gzip_members(std::string_view bytes);

// Writes a scalar volume of `type` to `path` (.nii, or .nii.gz when `gzip`) through an AtomicFile; OUT_OF_RANGE,
// and nothing written, where `convert` finds a value that does not fit.
Status write_nifti(const ImageGeometry& geometry, PixelType type, const ConvertVoxels& convert, const std::string& path,
                   bool gzip);

}  // namespace posewarp::io::detail
