// Volume reading and writing through ITK (NIfTI, NRRD, MetaImage) and GDCM (DICOM series).
// This is the only translation unit that sees ITK; nothing here includes Eigen.
#include "posewarp/io/volume_io.h"

#include <itkGDCMImageIO.h>
#include <itkGDCMSeriesFileNames.h>
#include <itkImage.h>
#include <itkImageFileReader.h>
#include <itkImageFileWriter.h>
#include <itkImageSeriesReader.h>
#include <itkImageSeriesWriter.h>
#include <itkMetaDataObject.h>
#include <itkMetaImageIO.h>
#include <itkNiftiImageIO.h>
#include <itkNrrdImageIO.h>

#include <gdcmTrace.h>
#include <gdcmUIDGenerator.h>

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <iomanip>
#include <limits>
#include <memory>
#include <sstream>
#include <system_error>
#include <vector>

#include <unistd.h>

#include "file_checks.h"
#include "posewarp/common/atomic_file.h"
#include "posewarp/common/exception_wall.h"
#include "posewarp/common/input_file.h"
#include "itk_geometry.h"
#include "nifti_writer.h"

namespace posewarp::io {
namespace fs = std::filesystem;

namespace {

bool ends_with(const std::string& text, std::string_view suffix) {
  if (text.size() < suffix.size()) return false;
  return std::equal(suffix.rbegin(), suffix.rend(), text.rbegin(),
                    [](char a, char b) { return a == std::tolower(static_cast<unsigned char>(b)); });
}

std::string in_quotes(const std::string& path) { return "'" + path + "'"; }

// The first line of an ITK exception's description, without the file/line noise ITK puts in front.
std::string itk_reason(const itk::ExceptionObject& error) {
  std::string text = error.GetDescription();
  while (!text.empty() && (text.back() == '\n' || text.back() == ' ')) text.pop_back();
  return text;
}

itk::ImageIOBase::Pointer make_file_io(VolumeFormat format) {
  switch (format) {
    case VolumeFormat::kNifti: return itk::NiftiImageIO::New().GetPointer();
    case VolumeFormat::kNrrd: return itk::NrrdImageIO::New().GetPointer();
    case VolumeFormat::kMetaImage: return itk::MetaImageIO::New().GetPointer();
    case VolumeFormat::kDicomSeries: return itk::GDCMImageIO::New().GetPointer();
  }
  return nullptr;
}

Result<PixelType> pixel_type_from_itk(itk::IOComponentEnum component, const std::string& path) {
  using C = itk::IOComponentEnum;
  switch (component) {
    case C::UCHAR: return PixelType::kUInt8;
    case C::CHAR: return PixelType::kInt8;
    case C::USHORT: return PixelType::kUInt16;
    case C::SHORT: return PixelType::kInt16;
    case C::UINT: return PixelType::kUInt32;
    case C::INT: return PixelType::kInt32;
    case C::ULONG:
    case C::ULONGLONG: return PixelType::kUInt64;
    case C::LONG:
    case C::LONGLONG: return PixelType::kInt64;
    case C::FLOAT: return PixelType::kFloat32;
    case C::DOUBLE: return PixelType::kFloat64;
    default: break;
  }
  return invalid_argument_error(in_quotes(path) + " has a voxel type posewarp cannot read (" +
                                itk::ImageIOBase::GetComponentTypeAsString(component) +
                                "); convert it to an integer or float scalar image");
}

// Checks a header's numbers before anything is allocated.
Status validate_header(const VolumeHeader& header, const ReadOptions& options, const std::string& path) {
  const ImageGeometry& g = header.geometry;
  if (header.components != 1) {
    return invalid_argument_error(in_quotes(path) + " has " + std::to_string(header.components) +
                                  " components per voxel (a vector or colour image); posewarp needs a scalar "
                                  "label or intensity volume");
  }
  for (int a = 0; a < 3; ++a) {
    if (g.size[a] <= 0 || g.size[a] > options.max_dimension) {
      return invalid_argument_error(in_quotes(path) + " claims " + std::to_string(g.size[0]) + " x " +
                                    std::to_string(g.size[1]) + " x " + std::to_string(g.size[2]) +
                                    " voxels; each dimension must lie in 1.." + std::to_string(options.max_dimension) +
                                    " (corrupt header?)");
    }
  }
  const int64_t voxels = g.voxel_count();
  if (voxels > options.max_voxels) {
    return resource_exhausted_error(in_quotes(path) + " holds " + std::to_string(voxels) +
                                    " voxels, over the limit of " + std::to_string(options.max_voxels) +
                                    "; crop or downsample the volume, or raise the voxel limit" +
                                    (options.voxel_limit_name.empty() ? "" : " (" + options.voxel_limit_name + ")"));
  }
  Status geometry = g.validate();
  if (!geometry.ok()) return geometry.with_context(in_quotes(path));
  return ok_status();
}

// Fills an ImageGeometry from an ITK IO's header, which may describe 2 to 4 dimensions.
Result<ImageGeometry> geometry_from_io(itk::ImageIOBase& io, const std::string& path) {
  const unsigned dims = io.GetNumberOfDimensions();
  if (dims < 2 || dims > 4) {
    return invalid_argument_error(in_quotes(path) + " has " + std::to_string(dims) +
                                  " dimensions; posewarp reads 3D volumes (2D slices and 4D with one frame too)");
  }
  if (dims == 4 && io.GetDimensions(3) != 1) {
    return invalid_argument_error(in_quotes(path) + " is a 4D series with " + std::to_string(io.GetDimensions(3)) +
                                  " frames; extract the one 3D frame to re-pose first");
  }
  ImageGeometry g;
  for (unsigned a = 0; a < 3; ++a) {
    if (a < dims) {
      g.size[a] = static_cast<int64_t>(io.GetDimensions(a));
      g.spacing[a] = io.GetSpacing(a);
      g.origin[a] = io.GetOrigin(a);
    } else {
      g.size[a] = 1;
      g.spacing[a] = 1.0;
      g.origin[a] = 0.0;
    }
  }
  for (unsigned c = 0; c < 3; ++c) {
    for (unsigned r = 0; r < 3; ++r) {
      double value = r == c ? 1.0 : 0.0;
      if (c < dims) {
        const std::vector<double> column = io.GetDirection(c);
        value = r < column.size() ? column[r] : 0.0;
      }
      g.direction[3 * r + c] = value;
    }
  }
  return g;
}

struct DicomSeries {
  std::vector<std::string> files;
  std::string uid;
};

// GDCM prints a warning per slice for tags it defaults; posewarp reports its own errors instead.
void quiet_gdcm() {
  static const bool silenced = [] {
    gdcm::Trace::WarningOff();
    return true;
  }();
  (void)silenced;
}

Result<DicomSeries> find_dicom_series(const std::string& directory, const ReadOptions& options) {
  quiet_gdcm();
  std::error_code ec;
  if (!fs::is_directory(directory, ec)) {
    return not_found_error("cannot read " + in_quotes(directory) +
                           ": no such directory (a path without a known extension is read as a DICOM series)");
  }
  try {
    auto names = itk::GDCMSeriesFileNames::New();
    names->SetUseSeriesDetails(false);
    names->SetDirectory(directory);
    const std::vector<std::string>& uids = names->GetSeriesUIDs();
    if (uids.empty()) {
      return not_found_error("no DICOM series found in directory " + in_quotes(directory) +
                             "; point to a directory of DICOM files, or to a .nii.gz/.nrrd/.mha file");
    }
    std::string uid = options.dicom_series_uid;
    if (uid.empty()) {
      if (uids.size() > 1) {
        std::string list;
        for (const std::string& u : uids) list += "\n  " + u;
        return invalid_argument_error("directory " + in_quotes(directory) + " holds " + std::to_string(uids.size()) +
                                      " DICOM series; name the one to read (--series-uid):" + list);
      }
      uid = uids.front();
    } else if (std::find(uids.begin(), uids.end(), uid) == uids.end()) {
      return not_found_error("DICOM series " + uid + " is not in directory " + in_quotes(directory));
    }
    DicomSeries series{names->GetFileNames(uid), uid};
    if (series.files.empty()) return not_found_error("DICOM series " + uid + " in " + in_quotes(directory) + " is empty");
    return series;
  } catch (const itk::ExceptionObject& error) {
    return invalid_argument_error("cannot list DICOM files in " + in_quotes(directory) + ": " + itk_reason(error));
  }
}

Result<VolumeHeader> read_dicom_header(const std::string& directory, const ReadOptions& options,
                                       DicomSeries* series_out) {
  POSEWARP_ASSIGN_OR_RETURN(DicomSeries series, find_dicom_series(directory, options));
  auto io = itk::GDCMImageIO::New();
  try {
    io->SetFileName(series.files.front());
    io->ReadImageInformation();
  } catch (const itk::ExceptionObject& error) {
    return invalid_argument_error("cannot read DICOM header of " + in_quotes(series.files.front()) + ": " +
                                  itk_reason(error));
  }
  VolumeHeader header;
  header.format = VolumeFormat::kDicomSeries;
  header.components = static_cast<int>(io->GetNumberOfComponents());
  POSEWARP_ASSIGN_OR_RETURN(header.pixel_type, pixel_type_from_itk(io->GetComponentType(), directory));
  POSEWARP_ASSIGN_OR_RETURN(header.geometry, geometry_from_io(*io, series.files.front()));
  // A slice file reports its own in-plane size; the series depth is the number of files.
  if (header.geometry.size[2] == 1) header.geometry.size[2] = static_cast<int64_t>(series.files.size());
  POSEWARP_RETURN_IF_ERROR(validate_header(header, options, directory));
  if (series_out) *series_out = std::move(series);
  return header;
}

Result<VolumeHeader> read_file_header(const std::string& path, VolumeFormat format, const ReadOptions& options) {
  POSEWARP_RETURN_IF_ERROR(check_input_file(path, "volume"));
  std::error_code ec;
  if (fs::file_size(path, ec) == 0) {
    return invalid_argument_error(in_quotes(path) + " is empty (0 bytes); the file was not written completely");
  }
  // Fields ITK would choke on (a NaN in the sform aborts inside its SVD) are refused before ITK sees them.
  if (format == VolumeFormat::kNifti) POSEWARP_RETURN_IF_ERROR(detail::check_nifti_geometry_fields(path));
  if (format == VolumeFormat::kMetaImage) POSEWARP_RETURN_IF_ERROR(detail::check_metaimage_header(path));
  itk::ImageIOBase::Pointer io = make_file_io(format);
  try {
    if (!io->CanReadFile(path.c_str())) {
      return invalid_argument_error(in_quotes(path) + " is not a readable " + std::string(format_name(format)) +
                                    " file (bad or truncated header); check the file or its extension");
    }
    io->SetFileName(path);
    io->ReadImageInformation();
  } catch (const itk::ExceptionObject& error) {
    return invalid_argument_error("cannot read the header of " + in_quotes(path) + ": " + itk_reason(error));
  }
  VolumeHeader header;
  header.format = format;
  header.components = static_cast<int>(io->GetNumberOfComponents());
  POSEWARP_ASSIGN_OR_RETURN(header.pixel_type, pixel_type_from_itk(io->GetComponentType(), path));
  POSEWARP_ASSIGN_OR_RETURN(header.geometry, geometry_from_io(*io, path));
  POSEWARP_RETURN_IF_ERROR(validate_header(header, options, path));
  // After the voxel limit (so an absurd header is reported as such), before any voxel is read.
  if (format == VolumeFormat::kNifti) POSEWARP_RETURN_IF_ERROR(detail::check_nifti_file(path));
  if (format == VolumeFormat::kMetaImage) POSEWARP_RETURN_IF_ERROR(detail::check_metaimage_file(path));
  if (format == VolumeFormat::kNrrd) POSEWARP_RETURN_IF_ERROR(detail::check_nrrd_file(path));
  return header;
}

template <typename Pixel>
using Image3 = itk::Image<Pixel, 3>;

// Reads the whole volume into an ITK image of the requested pixel type (ITK converts on the fly).
template <typename Pixel>
Result<typename Image3<Pixel>::Pointer> read_itk_image(const std::string& path, const VolumeHeader& header,
                                                       const DicomSeries& series) {
  try {
    if (header.format == VolumeFormat::kDicomSeries) {
      auto reader = itk::ImageSeriesReader<Image3<Pixel>>::New();
      reader->SetImageIO(itk::GDCMImageIO::New());
      reader->SetFileNames(series.files);
      reader->Update();
      return typename Image3<Pixel>::Pointer(reader->GetOutput());
    }
    auto reader = itk::ImageFileReader<Image3<Pixel>>::New();
    reader->SetImageIO(make_file_io(header.format));
    reader->SetFileName(path);
    reader->Update();
    return typename Image3<Pixel>::Pointer(reader->GetOutput());
  } catch (const itk::ExceptionObject& error) {  // ITK's word for a damaged file (its out of memory passes on)
    return data_loss_error("cannot read the voxels of " + in_quotes(path) + " (truncated or corrupt file?): " +
                           itk_reason(error));
  }
}

template <typename Pixel>
ImageGeometry geometry_from_image(const Image3<Pixel>& image) {
  ImageGeometry g;
  const auto region = image.GetLargestPossibleRegion();
  for (unsigned a = 0; a < 3; ++a) {
    g.size[a] = static_cast<int64_t>(region.GetSize(a));
    g.spacing[a] = image.GetSpacing()[a];
    g.origin[a] = image.GetOrigin()[a];
    for (unsigned c = 0; c < 3; ++c) g.direction[3 * a + c] = image.GetDirection()(a, c);
  }
  return g;
}

Result<std::pair<VolumeHeader, DicomSeries>> open_volume(const std::string& path, const ReadOptions& options) {
  POSEWARP_ASSIGN_OR_RETURN(const VolumeFormat format, format_from_path(path));
  if (options.inline_data_only) {
    // A regular file first: the check reads it (a FIFO would block).
    if (format != VolumeFormat::kDicomSeries) POSEWARP_RETURN_IF_ERROR(check_input_file(path, "volume"));
    POSEWARP_RETURN_IF_ERROR(detail::check_inline_data(path, format));
  }
  DicomSeries series;
  if (format == VolumeFormat::kDicomSeries) {
    POSEWARP_ASSIGN_OR_RETURN(VolumeHeader header, read_dicom_header(path, options, &series));
    return std::make_pair(header, series);
  }
  POSEWARP_ASSIGN_OR_RETURN(VolumeHeader header, read_file_header(path, format, options));
  return std::make_pair(header, series);
}

// ---- writing ------------------------------------------------------------------------------------------------

template <typename In>
std::pair<double, double> value_range(const Volume<In>& volume) {
  if (volume.empty()) return {0.0, 0.0};
  const auto [lo, hi] = std::minmax_element(volume.voxels().begin(), volume.voxels().end());
  return {static_cast<double>(*lo), static_cast<double>(*hi)};
}

template <typename Out, typename In>
typename Image3<Out>::Pointer to_itk_image(const Volume<In>& volume) {
  auto image = Image3<Out>::New();
  detail::set_itk_geometry(image.GetPointer(), volume.geometry());
  image->Allocate();
  Out* out = image->GetBufferPointer();
  const In* in = volume.data();
  const int64_t n = volume.voxel_count();
  for (int64_t v = 0; v < n; ++v) {
    if constexpr (std::is_integral_v<Out> && std::is_floating_point_v<In>) {
      out[v] = static_cast<Out>(std::lround(in[v]));
    } else {
      out[v] = static_cast<Out>(in[v]);
    }
  }
  return image;
}

std::string format_number(double value) {
  std::ostringstream out;
  out << std::setprecision(10) << value;
  return out.str();
}

std::string new_uid() {
  gdcm::UIDGenerator generator;
  return generator.Generate();
}

template <typename Out>
Status write_dicom_series(const typename Image3<Out>::Pointer& image, const ImageGeometry& g, const std::string& dir,
                          const std::string& modality, const std::string& series_description) {
  const double* d = g.direction.data();
  // DICOM's slice normal is row x column; a left-handed grid cannot be stored without reordering slices.
  const double normal[3] = {d[3] * d[7] - d[6] * d[4], d[6] * d[1] - d[0] * d[7], d[0] * d[4] - d[3] * d[1]};
  const double handedness = normal[0] * d[2] + normal[1] * d[5] + normal[2] * d[8];
  if (handedness < 0.0) {
    return invalid_argument_error(
        "the volume's grid is left-handed (its slice axis points against row x column), which a DICOM series "
        "cannot store without reordering slices; write NIfTI, NRRD or MetaImage instead");
  }
  std::error_code ec;
  if (fs::exists(dir, ec) && !fs::is_empty(dir, ec)) {
    return already_exists_error("DICOM output directory " + in_quotes(dir) +
                                " exists and is not empty; choose a new directory so series are not mixed");
  }
  fs::create_directories(dir, ec);
  if (ec) return invalid_argument_error("cannot create directory " + in_quotes(dir) + ": " + ec.message());

  quiet_gdcm();
  const std::string study_uid = new_uid();
  const std::string series_uid = new_uid();
  const std::string frame_uid = new_uid();
  std::ostringstream orientation;
  orientation << std::setprecision(10) << d[0] << "\\" << d[3] << "\\" << d[6] << "\\" << d[1] << "\\" << d[4] << "\\"
              << d[7];
  std::vector<itk::MetaDataDictionary> dictionaries(static_cast<size_t>(g.size[2]));
  std::vector<itk::MetaDataDictionary*> dictionary_pointers;
  std::vector<std::string> files;
  for (int64_t k = 0; k < g.size[2]; ++k) {
    itk::MetaDataDictionary& dict = dictionaries[static_cast<size_t>(k)];
    const Vec3 position = g.index_to_physical({0.0, 0.0, static_cast<double>(k)});
    auto put = [&dict](const char* tag, const std::string& value) {
      itk::EncapsulateMetaData<std::string>(dict, tag, value);
    };
    const std::string sop_uid = new_uid();
    // CT Image Storage: GDCM ignores position and orientation of Secondary Capture images.
    put("0008|0016", "1.2.840.10008.5.1.4.1.1.2");
    put("0008|0018", sop_uid);
    put("0002|0003", sop_uid);
    put("0008|0060", modality);
    put("0008|0064", "WSD");
    put("0020|000d", study_uid);
    put("0020|000e", series_uid);
    put("0020|0052", frame_uid);
    put("0020|0011", "1");
    put("0020|0013", std::to_string(k + 1));
    put("0020|0032", format_number(position[0]) + "\\" + format_number(position[1]) + "\\" +
                         format_number(position[2]));
    put("0020|0037", orientation.str());
    put("0028|0030", format_number(g.spacing[1]) + "\\" + format_number(g.spacing[0]));
    put("0018|0050", format_number(g.spacing[2]));
    put("0018|0088", format_number(g.spacing[2]));
    put("0008|103e", series_description);
    put("0028|0004", "MONOCHROME2");
    dictionary_pointers.push_back(&dict);
    char name[32];
    std::snprintf(name, sizeof(name), "IM%05lld.dcm", static_cast<long long>(k + 1));
    files.push_back((fs::path(dir) / name).string());
  }
  try {
    auto io = itk::GDCMImageIO::New();
    io->KeepOriginalUIDOn();
    auto writer = itk::ImageSeriesWriter<Image3<Out>, itk::Image<Out, 2>>::New();
    writer->SetInput(image);
    writer->SetImageIO(io);
    writer->SetFileNames(files);
    writer->SetMetaDataDictionaryArray(&dictionary_pointers);
    writer->Update();
  } catch (const itk::ExceptionObject& error) {
    return internal_error("writing DICOM series to " + in_quotes(dir) + " failed: " + itk_reason(error));
  }
  return ok_status();
}

template <typename Out>
Status write_file(const typename Image3<Out>::Pointer& image, const std::string& path, VolumeFormat format,
                  bool compress) {
  auto run_writer = [&](const std::string& file_name) -> Status {
    try {
      auto writer = itk::ImageFileWriter<Image3<Out>>::New();
      itk::ImageIOBase::Pointer io = make_file_io(format);
      writer->SetImageIO(io);
      writer->SetInput(image);
      writer->SetFileName(file_name);
      writer->SetUseCompression(format == VolumeFormat::kNifti ? ends_with(path, ".gz") : compress);
      writer->Update();
    } catch (const itk::ExceptionObject& error) {
      return invalid_argument_error("writing " + in_quotes(path) + " failed: " + itk_reason(error));
    }
    return ok_status();
  };
  // Detached-header formats name their data file inside the header, so they cannot be renamed afterwards.
  if (ends_with(path, ".nhdr") || ends_with(path, ".mhd")) return run_writer(path);
  // The partial file is created before ITK runs: ITK does not always say when it cannot create a file (its NIfTI
  // writer goes through znzlib), and commit() notices a file ITK left empty.
  POSEWARP_ASSIGN_OR_RETURN(AtomicFile file, AtomicFile::create(path, "volume"));
  POSEWARP_RETURN_IF_ERROR(run_writer(file.partial_path()));
  return file.commit();
}

template <typename Out, typename In>
Status write_as(const Volume<In>& volume, const std::string& path, VolumeFormat format, const WriteOptions& options,
                const std::string& modality) {
  // write_volume() runs this behind the exception wall ("writing 'path'").
  const typename Image3<Out>::Pointer image = to_itk_image<Out>(volume);
  if (format == VolumeFormat::kDicomSeries) {
    return write_dicom_series<Out>(image, volume.geometry(), path, modality,
                                   std::is_same_v<In, Label> ? "posewarp labels" : "posewarp");
  }
  return write_file<Out>(image, path, format, options.compress);
}

template <typename In>
Status write_any(const Volume<In>& volume, const std::string& path, const WriteOptions& options,
                 const std::string& default_modality) {
  if (volume.empty()) return invalid_argument_error("refusing to write an empty volume to " + in_quotes(path));
  POSEWARP_RETURN_IF_ERROR(volume.geometry().validate().with_context("writing " + in_quotes(path)));
  POSEWARP_ASSIGN_OR_RETURN(const VolumeFormat format, format_from_path(path));
  const PixelType type = options.pixel_type.value_or(volume.source_type());
  // Values must fit the type on disk; clipping would silently change labels or intensities. NIfTI checks them as it
  // converts them (one pass less over the volume), the other writers before.
  auto does_not_fit = [&]() -> Status {
    const auto [lo, hi] = value_range(volume);
    if (std::round(lo) < pixel_type_min(type) || std::round(hi) > pixel_type_max(type)) {
      return out_of_range_error("values of the volume span " + format_number(lo) + ".." + format_number(hi) +
                                ", which does not fit " + std::string(pixel_type_name(type)) + " for " +
                                in_quotes(path) + "; choose a wider voxel type (--pixel-type)");
    }
    return out_of_range_error("the volume holds values that are not numbers (NaN), which " +
                              std::string(pixel_type_name(type)) + " cannot hold, for " + in_quotes(path) +
                              "; write it as float32 (--pixel-type float32)");
  };
  const bool nifti = format == VolumeFormat::kNifti && (ends_with(path, ".nii") || ends_with(path, ".nii.gz"));
  if (!is_floating(type) && !nifti) {
    const auto [lo, hi] = value_range(volume);
    if (std::round(lo) < pixel_type_min(type) || std::round(hi) > pixel_type_max(type)) return does_not_fit();
  }
  if (format == VolumeFormat::kDicomSeries && (is_floating(type) || type == PixelType::kUInt64 ||
                                               type == PixelType::kInt64)) {
    return invalid_argument_error("DICOM series store integer voxels of up to 32 bits; " +
                                  std::string(pixel_type_name(type)) + " cannot be written to " + in_quotes(path) +
                                  ". Write NIfTI/NRRD/MetaImage, or choose an integer --pixel-type");
  }
  if (nifti) {
    const detail::ConvertVoxels convert = [&](int64_t first, int64_t count, char* out) {
      return convert_samples(volume.data() + first, count, type, out);
    };
    Status written = detail::write_nifti(volume.geometry(), type, convert, path, ends_with(path, ".gz"));
    return written.code() == StatusCode::kOutOfRange ? does_not_fit() : written;
  }
  const std::string modality = options.dicom_modality.empty() ? default_modality : options.dicom_modality;
  switch (type) {
    case PixelType::kUInt8: return write_as<uint8_t>(volume, path, format, options, modality);
    case PixelType::kInt8: return write_as<int8_t>(volume, path, format, options, modality);
    case PixelType::kUInt16: return write_as<uint16_t>(volume, path, format, options, modality);
    case PixelType::kInt16: return write_as<int16_t>(volume, path, format, options, modality);
    case PixelType::kUInt32: return write_as<uint32_t>(volume, path, format, options, modality);
    case PixelType::kInt32: return write_as<int32_t>(volume, path, format, options, modality);
    case PixelType::kUInt64: return write_as<uint64_t>(volume, path, format, options, modality);
    case PixelType::kInt64: return write_as<int64_t>(volume, path, format, options, modality);
    case PixelType::kFloat32: return write_as<float>(volume, path, format, options, modality);
    case PixelType::kFloat64: return write_as<double>(volume, path, format, options, modality);
  }
  return internal_error("unhandled voxel type");
}

}  // namespace

std::string_view format_name(VolumeFormat format) {
  switch (format) {
    case VolumeFormat::kNifti: return "NIfTI";
    case VolumeFormat::kNrrd: return "NRRD";
    case VolumeFormat::kMetaImage: return "MetaImage";
    case VolumeFormat::kDicomSeries: return "DICOM series";
  }
  return "unknown";
}

Result<VolumeFormat> format_from_path(const std::string& path) {
  if (path.empty()) return invalid_argument_error("empty volume path");
  if (ends_with(path, ".nii") || ends_with(path, ".nii.gz")) return VolumeFormat::kNifti;
  if (ends_with(path, ".nrrd") || ends_with(path, ".nhdr")) return VolumeFormat::kNrrd;
  if (ends_with(path, ".mha") || ends_with(path, ".mhd")) return VolumeFormat::kMetaImage;
  std::error_code ec;
  if (fs::is_directory(path, ec) || ends_with(path, "/") || !fs::path(path).has_extension()) {
    return VolumeFormat::kDicomSeries;
  }
  if (ends_with(path, ".dcm")) {
    return invalid_argument_error(in_quotes(path) + " is a single DICOM file; pass the directory holding the series");
  }
  return invalid_argument_error("cannot tell the format of " + in_quotes(path) +
                                ": use .nii/.nii.gz (NIfTI), .nrrd/.nhdr (NRRD), .mha/.mhd (MetaImage) or a "
                                "directory (DICOM series)");
}

static Result<VolumeHeader> read_header_unguarded(const std::string& path, const ReadOptions& options) {
  POSEWARP_ASSIGN_OR_RETURN(auto opened, open_volume(path, options));
  return opened.first;
}

Result<VolumeHeader> read_header(const std::string& path, const ReadOptions& options) {
  return guarded("reading " + in_quotes(path), [&] { return read_header_unguarded(path, options); });
}

static Result<LabelVolume> read_label_volume_unguarded(const std::string& path, const ReadOptions& options) {
  POSEWARP_ASSIGN_OR_RETURN(auto opened, open_volume(path, options));
  const VolumeHeader& header = opened.first;  // named, not bound: a lambda below captures them
  const DicomSeries& series = opened.second;
  const PixelType type = header.pixel_type;
  const bool exact_as_int32 = type == PixelType::kUInt8 || type == PixelType::kInt8 || type == PixelType::kUInt16 ||
                              type == PixelType::kInt16 || type == PixelType::kInt32;
  return guarded("reading " + in_quotes(path) + " (" + header.geometry.describe() + ")", [&]() -> Result<LabelVolume> {
    LabelVolume labels;
    if (exact_as_int32) {
      POSEWARP_ASSIGN_OR_RETURN(auto image, read_itk_image<int32_t>(path, header, series));
      labels = LabelVolume(geometry_from_image(*image));
      std::copy_n(image->GetBufferPointer(), labels.voxel_count(), labels.data());
    } else {
      // Floating or wide integer labels: read as double, then every value must be an integer within int32.
      POSEWARP_ASSIGN_OR_RETURN(auto image, read_itk_image<double>(path, header, series));
      labels = LabelVolume(geometry_from_image(*image));
      const double* in = image->GetBufferPointer();
      for (int64_t v = 0; v < labels.voxel_count(); ++v) {
        const double value = in[v];
        if (!std::isfinite(value) || value != std::floor(value) ||
            value < static_cast<double>(std::numeric_limits<Label>::min()) ||
            value > static_cast<double>(std::numeric_limits<Label>::max())) {
          return invalid_argument_error(
              in_quotes(path) + " is a " + std::string(pixel_type_name(type)) + " image with the value " +
              format_number(value) + " at voxel " + std::to_string(v) +
              ", which is not an integer label; pass a label (segmentation) volume, not an intensity image");
        }
        labels.data()[v] = static_cast<Label>(value);
      }
    }
    labels.set_source_type(type);
    return labels;
  });
}

Result<LabelVolume> read_label_volume(const std::string& path, const ReadOptions& options) {
  return guarded("reading " + in_quotes(path), [&] { return read_label_volume_unguarded(path, options); });
}

static Result<IntensityVolume> read_intensity_volume_unguarded(const std::string& path, const ReadOptions& options) {
  POSEWARP_ASSIGN_OR_RETURN(auto opened, open_volume(path, options));
  const VolumeHeader& header = opened.first;  // named, not bound: a lambda below captures them
  const DicomSeries& series = opened.second;
  return guarded("reading " + in_quotes(path) + " (" + header.geometry.describe() + ")",
                 [&]() -> Result<IntensityVolume> {
    IntensityVolume intensities;
    POSEWARP_ASSIGN_OR_RETURN(auto image, read_itk_image<float>(path, header, series));
    intensities = IntensityVolume(geometry_from_image(*image));
    std::copy_n(image->GetBufferPointer(), intensities.voxel_count(), intensities.data());
    // A NaN would spread through every interpolated voxel near it (NIfTI's are caught before ITK hides them).
    const float* first = intensities.data();
    const float* bad = std::find_if(first, first + intensities.voxel_count(), [](float v) { return !std::isfinite(v); });
    if (bad != first + intensities.voxel_count()) {
      return invalid_argument_error(in_quotes(path) + " holds a NaN or infinite value at voxel " +
                                    std::to_string(bad - first) +
                                    "; a voxel must be a number (replace them, e.g. with the background value)");
    }
    intensities.set_source_type(header.pixel_type);
    return intensities;
  });
}

Result<IntensityVolume> read_intensity_volume(const std::string& path, const ReadOptions& options) {
  return guarded("reading " + in_quotes(path), [&] { return read_intensity_volume_unguarded(path, options); });
}

Status write_volume(const LabelVolume& volume, const std::string& path, const WriteOptions& options) {
  return guarded("writing " + in_quotes(path), [&] { return write_any(volume, path, options, "CT"); });
}

Status write_volume(const IntensityVolume& volume, const std::string& path, const WriteOptions& options) {
  return guarded("writing " + in_quotes(path), [&] { return write_any(volume, path, options, "CT"); });
}

}  // namespace posewarp::io
