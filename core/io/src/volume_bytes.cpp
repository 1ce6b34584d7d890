// Volumes as the bytes of a NIfTI-1 or NRRD file, made in memory (the NIfTI header is ITK's, nifti_writer.h).
#include <zlib.h>

#include <atomic>
#include <cstdio>
#include <cstring>
#include <string>

#include "nifti_writer.h"
#include "posewarp/common/parallel.h"
#include "posewarp/io/volume_io.h"

namespace posewarp::io {
namespace {

// NRRD's type names are ours but for the floating types.
std::string_view nrrd_type(PixelType type) {
  if (type == PixelType::kFloat32) return "float";
  if (type == PixelType::kFloat64) return "double";
  return pixel_type_name(type);
}

std::string nrrd_header(const ImageGeometry& g, PixelType type, bool gzip) {
  std::string h = "NRRD0004\n# posewarp\ntype: " + std::string(nrrd_type(type)) + "\ndimension: 3\n" +
                  "space: left-posterior-superior\nsizes: " + std::to_string(g.size[0]) + " " +
                  std::to_string(g.size[1]) + " " + std::to_string(g.size[2]) + "\nspace directions:";
  char number[32];
  auto num = [&](double value) {
    std::snprintf(number, sizeof number, "%.17g", value);
    return std::string(number);
  };
  for (int c = 0; c < 3; ++c) {
    const double s = g.spacing[static_cast<size_t>(c)];
    h += " (" + num(g.direction[static_cast<size_t>(c)] * s) + "," + num(g.direction[static_cast<size_t>(3 + c)] * s) +
         "," + num(g.direction[static_cast<size_t>(6 + c)] * s) + ")";
  }
  h += "\nkinds: domain domain domain\nendian: little\nencoding: " + std::string(gzip ? "gzip" : "raw") +
       "\nspace origin: (" + num(g.origin[0]) + "," + num(g.origin[1]) + "," + num(g.origin[2]) + ")\n\n";
  return h;
}

// gzip of `in` (level 1: a server encodes while the client waits), appended to out.
Status gzip_append(std::string_view in, std::string& out) {
  z_stream z{};
  if (deflateInit2(&z, 1, Z_DEFLATED, 15 + 16, 8, Z_DEFAULT_STRATEGY) != Z_OK) {
    return internal_error("zlib could not start a gzip stream");
  }
  const size_t start = out.size();
  out.resize(start + deflateBound(&z, static_cast<uLong>(in.size())));
  z.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(in.data()));
  z.avail_in = static_cast<uInt>(in.size());
  z.next_out = reinterpret_cast<Bytef*>(out.data() + start);
  z.avail_out = static_cast<uInt>(out.size() - start);
  const int done = deflate(&z, Z_FINISH);
  out.resize(start + z.total_out);
  deflateEnd(&z);
  if (done != Z_STREAM_END) return internal_error("zlib could not compress the volume");
  return ok_status();
}

template <typename In>
Result<std::string> encode(const Volume<In>& volume, VolumeFormat format, bool gzip, std::optional<PixelType> wanted) {
  if (volume.empty()) return invalid_argument_error("refusing to encode an empty volume");
  POSEWARP_RETURN_IF_ERROR(volume.geometry().validate().with_context("encoding a volume"));
  if (format != VolumeFormat::kNifti && format != VolumeFormat::kNrrd) {
    return invalid_argument_error("volumes are encoded in memory as NIfTI or NRRD; " + std::string(format_name(format)) +
                                  " is written to files only");
  }
  const PixelType type = wanted.value_or(volume.source_type());
  const int64_t n = volume.voxel_count();
  if (n > (int64_t{1} << 32) / pixel_type_bytes(type)) {
    return resource_exhausted_error("a volume encoded in memory holds at most 4 GiB of voxels");
  }
  std::string header = format == VolumeFormat::kNifti ? detail::nifti_header(volume.geometry(), type)
                                                      : nrrd_header(volume.geometry(), type, gzip);
  // NIfTI compresses the whole file (.nii.gz), NRRD its data only (encoding: gzip).
  const bool whole_file = format == VolumeFormat::kNifti;
  std::string raw = whole_file || !gzip ? std::move(header) : std::string();
  const size_t at = raw.size();
  raw.resize(at + static_cast<size_t>(n * pixel_type_bytes(type)));
  // Converted on every thread, as the file writer does (a CT's 20M voxels are 90 ms on one).
  std::atomic<bool> fits{true};
  const int64_t sample = pixel_type_bytes(type);
  parallel_for(0, n, int64_t{1} << 20, [&](int64_t begin, int64_t end) {
    if (!convert_samples(volume.data() + begin, end - begin, type, raw.data() + at + begin * sample)) fits = false;
  });
  if (!fits) {
    return out_of_range_error("the volume's values do not fit " + std::string(pixel_type_name(type)) +
                              "; choose a wider voxel type");
  }
  if (!gzip) return raw;
  // A .nii.gz in members deflated in parallel, as write_volume writes it; NRRD's data in one zlib stream.
  if (whole_file) {  // the header a member of its own, as in the file
    const std::string_view bytes(raw);
    return detail::gzip_members(bytes.substr(0, at)) + detail::gzip_members(bytes.substr(at));
  }
  std::string out = std::move(header);
  POSEWARP_RETURN_IF_ERROR(gzip_append(raw, out));
  return out;
}

}  // namespace

Result<std::string> encode_volume(const LabelVolume& volume, VolumeFormat format, bool gzip,
                                  std::optional<PixelType> type) {
  return encode(volume, format, gzip, type);
}

Result<std::string> encode_volume(const IntensityVolume& volume, VolumeFormat format, bool gzip,
                                  std::optional<PixelType> type) {
  return encode(volume, format, gzip, type);
}

}  // namespace posewarp::io
