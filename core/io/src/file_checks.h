// Checks ITK does not make: raw header values it silently "repairs" and data it silently reads short.
#pragma once

#include <string>

#include "posewarp/common/status.h"
#include "posewarp/io/volume_io.h"

namespace posewarp::io::detail {

// ReadOptions::inline_data_only, before anything else reads the file: the file must hold its own voxels. A NRRD
// header with a "data file" (or "datafile") field, a MetaImage header whose ElementDataFile is not LOCAL, a NIfTI
// header that is not a single file (magic other than "n+1": an .hdr/.img pair or ANALYZE) and a DICOM series (a
// directory) are INVALID_ARGUMENT with a message that says how to send the voxels inline.
Status check_inline_data(const std::string& path, VolumeFormat format);

// NIfTI-1 (.nii, .nii.gz): dimensions and spacings in the raw header must be positive (niftilib replaces bad ones
// with 1), and the file must hold every voxel byte the header promises (a .nii.gz is inflated up to that many bytes and
// no further, so a gzip bomb costs no more than the voxels it claims; a corrupt stream before that point is DATA_LOSS).
// Float voxels must be finite: ITK's reader turns NaN into 0.
Status check_nifti_file(const std::string& path);

// NIfTI-1, before ITK reads the header: dim[0] in 1..7 and dim[1..dim[0]] at least 1, pixdim[1..3] positive, each
// named by field in the message; every geometry field finite (pixdim, quatern_*, qoffset_*, srow_*: a NaN
// in the sform aborts inside ITK's SVD), vox_offset finite and not negative, and the qform or sform in use a real
// orientation (an infinite or all-zero sform cannot place a voxel).
Status check_nifti_geometry_fields(const std::string& path);

// NRRD (.nrrd, .nhdr) with gzip encoding: the stream (inline or in the data file) must inflate to every byte the
// header promises, checked before anything is allocated (ITK allocates the grid, then fails).
Status check_nrrd_file(const std::string& path);

// MetaImage (.mha, .mhd), before ITK reads the header: "Key = Value" lines up to ElementDataFile, NDims 1..4 and
// every counted field (DimSize, spacing, offset, matrix) with that many finite numbers, every DimSize at least 1 and
// every ElementSpacing (ElementSize) positive, each named by field. ITK's MetaIO spins forever on
// a negative NDims and overflows buffers on other damage.
Status check_metaimage_header(const std::string& path);
// MetaImage (.mha, .mhd): the data (inline or in the named file) must hold every byte the header promises,
// compressed or not (ITK's reader only prints a warning when it reads short).
Status check_metaimage_file(const std::string& path);

// Shared by the checks: a path in quotes for a message; the bytes a zlib or gzip stream in `path` from `offset`
// inflates to, reading at most until `limit` bytes came out (-1 when corrupt or truncated); a detached data file named
// in a header, `inline_word` (LOCAL) or a plain file name beside the header.
std::string in_quotes(const std::string& path);
int64_t inflated_size(const std::string& path, int64_t offset, int64_t limit);
Status check_data_file_name(const std::string& path, const std::string& name, const char* field,
                            const char* inline_word);

}  // namespace posewarp::io::detail
