// ITK's own resampler, as the reference the warp is tested and benchmarked against (ITK stays inside io/src).
#pragma once

#include <array>
#include <vector>

#include "posewarp/common/result.h"
#include "posewarp/common/volume.h"

namespace posewarp::io {

// ResampleImageFilter with a rigid transform: output point x samples the source at R^T (x - t), i.e. the source
// moved by p' = R p + t. rotation is row-major. Labels use nearest neighbour, background 0.
Result<LabelVolume> itk_resample_rigid_labels(const LabelVolume& source, const std::array<double, 9>& rotation,
                                              const std::array<double, 3>& translation, const ImageGeometry& output);

// ResampleImageFilter through a DisplacementFieldTransform on the output grid (field: 3 floats per output voxel,
// x_source - x_output in mm), linear interpolation, on the thread count in force.
Result<IntensityVolume> itk_resample_with_field(const IntensityVolume& source, const std::vector<float>& field,
                                                const ImageGeometry& output, float background);

// The same for labels with a nearest-neighbour interpolator.
Result<LabelVolume> itk_resample_labels_with_field(const LabelVolume& source, const std::vector<float>& field,
                                                   const ImageGeometry& output);

// Writes a displacement field (3 floats per voxel, mm) as an ITK vector image (.nii.gz, .nrrd, .mha): what ITK's
// DisplacementFieldTransform, ANTs and elastix read.
Status write_displacement_field(const std::vector<float>& field, const ImageGeometry& geometry, const std::string& path);

// ITK's own ImageFileWriter (NiftiImageIO for .nii and .nii.gz, zlib's default level), the voxels rounded to `type`
// as write_volume stores them: the reference posewarp's NIfTI writer is tested and benchmarked against.
Status itk_write_volume(const IntensityVolume& volume, PixelType type, const std::string& path);

}  // namespace posewarp::io
