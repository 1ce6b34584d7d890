// Reading and writing label and intensity volumes: NIfTI, NRRD, MetaImage and DICOM series.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include "posewarp/common/result.h"
#include "posewarp/common/volume.h"
#include "posewarp/common/volume_file.h"

namespace posewarp::io {

std::string_view format_name(VolumeFormat format);

// The format a path names: .nii/.nii.gz, .nrrd/.nhdr, .mha/.mhd, or an existing directory (a DICOM series).
// For writing, a path that does not exist yet and has no known extension is an error.
Result<VolumeFormat> format_from_path(const std::string& path);

// What a volume file holds and how to read and write it are vocabulary (posewarp/common/volume_file.h).
using posewarp::ReadOptions;
using posewarp::VolumeFormat;
using posewarp::VolumeHeader;
using posewarp::WriteOptions;

// Reads and validates the header only: dimensions, spacing, direction, pixel type and the voxel limit.
Result<VolumeHeader> read_header(const std::string& path, const ReadOptions& options = {});

// Reads a label volume. Integer types are taken as they are; a floating-point file is accepted only if every
// value is an integer that fits int32. source_type() of the result is the type on disk.
Result<LabelVolume> read_label_volume(const std::string& path, const ReadOptions& options = {});

// Reads an intensity volume (CT in HU, MRI) as float. source_type() of the result is the type on disk.
Result<IntensityVolume> read_intensity_volume(const std::string& path, const ReadOptions& options = {});

// Writes a volume. Single-file formats are written to a temporary file beside the target and renamed into place,
// so a crash never leaves a truncated file under the requested name. A DICOM path is a directory that is created
// and must not already hold a series.
Status write_volume(const LabelVolume& volume, const std::string& path, const WriteOptions& options = {});
Status write_volume(const IntensityVolume& volume, const std::string& path, const WriteOptions& options = {});

// A volume as the bytes of a file, made in memory (what a server streams to a client that asked for files): NIfTI-1
// (.nii, or .nii.gz with gzip) or NRRD with its data inline (gzip encoding with gzip). Voxels in `type`, by default
// the volume's source_type(), converted as write_volume converts them (rounded; OUT_OF_RANGE when a value does not
// fit, never clipped). Other formats are INVALID_ARGUMENT. gzip runs at level 1 (speed over size).
Result<std::string> encode_volume(const LabelVolume& volume, VolumeFormat format, bool gzip,
                                  std::optional<PixelType> type = std::nullopt);
Result<std::string> encode_volume(const IntensityVolume& volume, VolumeFormat format, bool gzip,
                                  std::optional<PixelType> type = std::nullopt);

}  // namespace posewarp::io
