// Reading and writing label and intensity volumes: NIfTI, NRRD, MetaImage and DICOM series.
#pragma once

#include <cstdint>
#include <optional>
#include <string>
#include <string_view>

#include "posewarp/common/result.h"
#include "posewarp/common/volume.h"

namespace posewarp::io {

enum class VolumeFormat { kNifti, kNrrd, kMetaImage, kDicomSeries };

std::string_view format_name(VolumeFormat format);

// The format a path names: .nii/.nii.gz, .nrrd/.nhdr, .mha/.mhd, or an existing directory (a DICOM series).
// For writing, a path that does not exist yet and has no known extension is an error.
Result<VolumeFormat> format_from_path(const std::string& path);

// Limits checked against the header before any voxel is allocated.
struct ReadOptions {
  // Largest voxel count accepted (default 512 Mi voxels: 2 GiB of int32 labels).
  int64_t max_voxels = int64_t{1} << 29;
  // How the voxel limit is named to the caller in the message that refuses a volume over it (the command line's
  // flag by default; a server names its own option).
  std::string voxel_limit_name = "--max-voxels";
  // Largest size along any one axis.
  int64_t max_dimension = 65536;
  // For a directory holding several DICOM series: the SeriesInstanceUID to read. Empty: the directory must
  // hold exactly one series.
  std::string dicom_series_uid;
  // Only self-contained files: NIfTI (.nii, .nii.gz), NRRD with its data inline and MetaImage with
  // ElementDataFile = LOCAL. A header naming a detached data file (.nhdr, .mhd) and a DICOM directory are refused
  // (INVALID_ARGUMENT) before anything else is read: a server's uploads must never read a file they did not send.
  bool inline_data_only = false;
};

// What the header says, read without loading the voxels.
struct VolumeHeader {
  VolumeFormat format = VolumeFormat::kNifti;
  ImageGeometry geometry;
  PixelType pixel_type = PixelType::kFloat32;
  int components = 1;
};

// Reads and validates the header only: dimensions, spacing, direction, pixel type and the voxel limit.
Result<VolumeHeader> read_header(const std::string& path, const ReadOptions& options = {});

// Reads a label volume. Integer types are taken as they are; a floating-point file is accepted only if every
// value is an integer that fits int32. source_type() of the result is the type on disk.
Result<LabelVolume> read_label_volume(const std::string& path, const ReadOptions& options = {});

// Reads an intensity volume (CT in HU, MRI) as float. source_type() of the result is the type on disk.
Result<IntensityVolume> read_intensity_volume(const std::string& path, const ReadOptions& options = {});

struct WriteOptions {
  // Voxel type on disk; default: the volume's source_type(). Values that do not fit are an error, never clipped.
  std::optional<PixelType> pixel_type;
  // gzip/zlib compression where the format has it (.nii.gz always compresses, .nii never).
  bool compress = true;
  // DICOM only: Modality (0008,0060). Default "CT": series are stored as CT Image Storage, whose position and
  // orientation every reader honours (labels too; their series description says "posewarp labels").
  std::string dicom_modality;
};

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
