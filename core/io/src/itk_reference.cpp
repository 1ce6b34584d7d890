// ITK reference resamplers and displacement-field output.
#include "posewarp/common/atomic_file.h"
#include "posewarp/io/itk_reference.h"

#include <itkDisplacementFieldTransform.h>
#include <itkEuler3DTransform.h>
#include <itkImage.h>
#include <itkImageFileWriter.h>
#include <itkLinearInterpolateImageFunction.h>
#include <itkMetaImageIO.h>
#include <itkNiftiImageIO.h>
#include <itkNrrdImageIO.h>
#include <itkMultiThreaderBase.h>
#include <itkNearestNeighborInterpolateImageFunction.h>
#include <itkResampleImageFilter.h>
#include <itkVector.h>
#include <itkVersorRigid3DTransform.h>

#include <algorithm>
#include <filesystem>


#include "itk_geometry.h"
#include "posewarp/common/parallel.h"

namespace posewarp::io {
namespace {

template <typename Pixel>
using Image3 = itk::Image<Pixel, 3>;
using FieldImage = itk::Image<itk::Vector<double, 3>, 3>;

template <typename Pixel>
typename Image3<Pixel>::Pointer to_image(const Volume<Pixel>& volume) {
  auto image = Image3<Pixel>::New();
  detail::set_itk_geometry(image.GetPointer(), volume.geometry());
  image->Allocate();
  std::copy_n(volume.data(), volume.voxel_count(), image->GetBufferPointer());
  return image;
}

FieldImage::Pointer field_image(const std::vector<float>& field, const ImageGeometry& g) {
  auto image = FieldImage::New();
  detail::set_itk_geometry(image.GetPointer(), g);
  image->Allocate();
  auto* out = image->GetBufferPointer();
  for (int64_t v = 0; v < g.voxel_count(); ++v) {
    for (unsigned a = 0; a < 3; ++a) out[v][a] = field[static_cast<size_t>(3 * v + a)];
  }
  return image;
}

template <typename Pixel, typename Interpolator>
Result<Volume<Pixel>> resample(const Volume<Pixel>& source, const itk::Transform<double, 3, 3>* transform,
                               const ImageGeometry& output, Pixel background) {
  try {
    itk::MultiThreaderBase::SetGlobalDefaultNumberOfThreads(static_cast<itk::ThreadIdType>(thread_count()));
    auto filter = itk::ResampleImageFilter<Image3<Pixel>, Image3<Pixel>, double>::New();
    filter->SetInput(to_image(source));
    filter->SetTransform(transform);
    filter->SetInterpolator(Interpolator::New());
    filter->SetDefaultPixelValue(background);
    auto reference = Image3<Pixel>::New();
    detail::set_itk_geometry(reference.GetPointer(), output);
    filter->SetUseReferenceImage(true);
    filter->SetReferenceImage(reference);
    filter->SetNumberOfWorkUnits(static_cast<itk::ThreadIdType>(thread_count()));
    filter->Update();
    Volume<Pixel> out(output);
    std::copy_n(filter->GetOutput()->GetBufferPointer(), out.voxel_count(), out.data());
    out.set_source_type(source.source_type());
    return out;
  } catch (const itk::ExceptionObject& error) {
    return internal_error(std::string("ITK resampling failed: ") + error.GetDescription());
  }
}

}  // namespace

Result<LabelVolume> itk_resample_rigid_labels(const LabelVolume& source, const std::array<double, 9>& rotation,
                                              const std::array<double, 3>& translation, const ImageGeometry& output) {
  // ITK maps output points to input points: p_in = R^T (p_out - t) = R^T p_out - R^T t.
  auto transform = itk::VersorRigid3DTransform<double>::New();
  itk::Matrix<double, 3, 3> m;
  itk::Vector<double, 3> offset;
  for (unsigned r = 0; r < 3; ++r) {
    offset[r] = 0.0;
    for (unsigned c = 0; c < 3; ++c) m(r, c) = rotation[3 * c + r];
  }
  for (unsigned r = 0; r < 3; ++r) {
    for (unsigned c = 0; c < 3; ++c) offset[r] -= m(r, c) * translation[c];
  }
  try {
    transform->SetMatrix(m, 1e-6);
  } catch (const itk::ExceptionObject& error) {
    return invalid_argument_error(std::string("not a rotation: ") + error.GetDescription());
  }
  transform->SetOffset(offset);
  return resample<Label, itk::NearestNeighborInterpolateImageFunction<Image3<Label>, double>>(source, transform.GetPointer(),
                                                                                              output, 0);
}

Result<IntensityVolume> itk_resample_with_field(const IntensityVolume& source, const std::vector<float>& field,
                                                const ImageGeometry& output, float background) {
  if (static_cast<int64_t>(field.size()) != 3 * output.voxel_count()) {
    return invalid_argument_error("the displacement field does not match the output grid");
  }
  auto transform = itk::DisplacementFieldTransform<double, 3>::New();
  transform->SetDisplacementField(field_image(field, output));
  return resample<float, itk::LinearInterpolateImageFunction<Image3<float>, double>>(source, transform.GetPointer(), output,
                                                                                     background);
}

Result<LabelVolume> itk_resample_labels_with_field(const LabelVolume& source, const std::vector<float>& field,
                                                   const ImageGeometry& output) {
  if (static_cast<int64_t>(field.size()) != 3 * output.voxel_count()) {
    return invalid_argument_error("the displacement field does not match the output grid");
  }
  auto transform = itk::DisplacementFieldTransform<double, 3>::New();
  transform->SetDisplacementField(field_image(field, output));
  return resample<Label, itk::NearestNeighborInterpolateImageFunction<Image3<Label>, double>>(source, transform.GetPointer(),
                                                                                              output, 0);
}

Status write_displacement_field(const std::vector<float>& field, const ImageGeometry& geometry, const std::string& path) {
  if (static_cast<int64_t>(field.size()) != 3 * geometry.voxel_count()) {
    return invalid_argument_error("the displacement field does not match its grid");
  }
  using FloatField = itk::Image<itk::Vector<float, 3>, 3>;
  auto image = FloatField::New();
  detail::set_itk_geometry(image.GetPointer(), geometry);
  image->Allocate();
  std::copy_n(field.data(), field.size(), reinterpret_cast<float*>(image->GetBufferPointer()));
  const std::string name = std::filesystem::path(path).filename().string();
  POSEWARP_ASSIGN_OR_RETURN(AtomicFile file, AtomicFile::create(path, "displacement field"));
  try {
    auto writer = itk::ImageFileWriter<FloatField>::New();
    auto ends = [&name](const std::string& suffix) {
      return name.size() >= suffix.size() && name.compare(name.size() - suffix.size(), suffix.size(), suffix) == 0;
    };
    if (ends(".nii") || ends(".nii.gz")) {
      writer->SetImageIO(itk::NiftiImageIO::New());
    } else if (ends(".nrrd") || ends(".nhdr")) {
      writer->SetImageIO(itk::NrrdImageIO::New());
    } else if (ends(".mha") || ends(".mhd")) {
      writer->SetImageIO(itk::MetaImageIO::New());
    } else {
      return invalid_argument_error("cannot tell the format of displacement field '" + path +
                                    "': use .nii.gz, .nrrd or .mha");
    }
    writer->SetInput(image);
    writer->SetFileName(file.partial_path());
    writer->SetUseCompression(true);
    writer->Update();
  } catch (const itk::ExceptionObject& error) {
    return invalid_argument_error("writing displacement field '" + path + "' failed: " + error.GetDescription() +
                                  " (use .nii.gz, .nrrd or .mha)");
  }
  return file.commit();
}

namespace {

template <typename Out>
Status itk_write_as(const IntensityVolume& volume, PixelType type, const std::string& path) {
  auto image = Image3<Out>::New();
  detail::set_itk_geometry(image.GetPointer(), volume.geometry());
  image->Allocate();
  if (!convert_samples(volume.data(), volume.voxel_count(), type, reinterpret_cast<char*>(image->GetBufferPointer()))) {
    return out_of_range_error("values do not fit " + std::string(pixel_type_name(type)));
  }
  try {
    auto writer = itk::ImageFileWriter<Image3<Out>>::New();
    writer->SetImageIO(itk::NiftiImageIO::New());
    writer->SetInput(image);
    writer->SetFileName(path);
    writer->SetUseCompression(true);
    writer->Update();
  } catch (const itk::ExceptionObject& error) {
    return invalid_argument_error("ITK could not write '" + path + "': " + error.GetDescription());
  }
  return ok_status();
}

}  // namespace

Status itk_write_volume(const IntensityVolume& volume, PixelType type, const std::string& path) {
  switch (type) {
    case PixelType::kUInt8: return itk_write_as<uint8_t>(volume, type, path);
    case PixelType::kInt8: return itk_write_as<int8_t>(volume, type, path);
    case PixelType::kUInt16: return itk_write_as<uint16_t>(volume, type, path);
    case PixelType::kInt16: return itk_write_as<int16_t>(volume, type, path);
    case PixelType::kUInt32: return itk_write_as<uint32_t>(volume, type, path);
    case PixelType::kInt32: return itk_write_as<int32_t>(volume, type, path);
    case PixelType::kUInt64: return itk_write_as<uint64_t>(volume, type, path);
    case PixelType::kInt64: return itk_write_as<int64_t>(volume, type, path);
    case PixelType::kFloat32: return itk_write_as<float>(volume, type, path);
    case PixelType::kFloat64: return itk_write_as<double>(volume, type, path);
  }
  return internal_error("unhandled voxel type");
}

}  // namespace posewarp::io
