// Volume files: their formats, what a header says, and the options of reading (limits checked before any voxel is
// allocated) and writing. The readers and writers: io/.
#pragma once

#include <cstdint>
#include <optional>
#include <string>

#include "posewarp/common/image_geometry.h"
#include "posewarp/common/volume.h"

namespace posewarp {

enum class VolumeFormat { kNifti, kNrrd, kMetaImage, kDicomSeries };

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

struct WriteOptions {
  // Voxel type on disk; default: the volume's source_type(). Values that do not fit are an error, never clipped.
  std::optional<PixelType> pixel_type;
  // gzip/zlib compression where the format has it (.nii.gz always compresses, .nii never).
  bool compress = true;
  // DICOM only: Modality (0008,0060). Default "CT": series are stored as CT Image Storage, whose position and
  // orientation every reader honours (labels too; their series description says "posewarp labels").
  std::string dicom_modality;
};

}  // namespace posewarp
