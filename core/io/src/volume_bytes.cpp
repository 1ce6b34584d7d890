// Volumes as the bytes of a NIfTI-1 or NRRD file, made in memory (no ITK: the layouts are small and fixed).
#include <zlib.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <string>

#include "posewarp/io/volume_io.h"

namespace posewarp::io {
namespace {

// NIfTI-1 datatype codes.
int16_t nifti_datatype(PixelType type) {
  switch (type) {
    case PixelType::kUInt8: return 2;
    case PixelType::kInt16: return 4;
    case PixelType::kInt32: return 8;
    case PixelType::kFloat32: return 16;
    case PixelType::kFloat64: return 64;
    case PixelType::kInt8: return 256;
    case PixelType::kUInt16: return 512;
    case PixelType::kUInt32: return 768;
    case PixelType::kInt64: return 1024;
    case PixelType::kUInt64: return 1280;
  }
  return 0;
}

// NRRD's type names are ours but for the floating types.
std::string_view nrrd_type(PixelType type) {
  if (type == PixelType::kFloat32) return "float";
  if (type == PixelType::kFloat64) return "double";
  return pixel_type_name(type);
}

template <typename T>
void put(std::string& header, size_t offset, T value) {
  std::memcpy(header.data() + offset, &value, sizeof(T));
}

// The 348-byte NIfTI-1 header and its 4-byte extension flag. The grid's LPS geometry becomes RAS (NIfTI's
// convention) in both the quaternion form (qform) and the affine rows (sform), both "scanner anatomical".
std::string nifti_header(const ImageGeometry& g, PixelType type) {
  std::string h(352, '\0');
  put<int32_t>(h, 0, 348);
  h[38] = 'r';
  put<int16_t>(h, 40, 3);
  for (int a = 0; a < 3; ++a) put<int16_t>(h, 42 + 2 * a, static_cast<int16_t>(g.size[static_cast<size_t>(a)]));
  for (int a = 3; a < 8; ++a) put<int16_t>(h, 42 + 2 * a, 1);
  put<int16_t>(h, 70, nifti_datatype(type));
  put<int16_t>(h, 72, static_cast<int16_t>(8 * pixel_type_bytes(type)));
  // R: the direction in RAS (x and y negated); a left-handed grid stores qfac = -1 and its third column negated.
  double r[3][3];
  for (int row = 0; row < 3; ++row)
    for (int c = 0; c < 3; ++c) r[row][c] = (row < 2 ? -1.0 : 1.0) * g.direction[static_cast<size_t>(3 * row + c)];
  const double det = r[0][0] * (r[1][1] * r[2][2] - r[1][2] * r[2][1]) - r[0][1] * (r[1][0] * r[2][2] - r[1][2] * r[2][0]) +
                     r[0][2] * (r[1][0] * r[2][1] - r[1][1] * r[2][0]);
  const double qfac = det < 0.0 ? -1.0 : 1.0;
  put<float>(h, 76, static_cast<float>(qfac));
  for (int a = 0; a < 3; ++a) put<float>(h, 80 + 4 * a, static_cast<float>(g.spacing[static_cast<size_t>(a)]));
  for (int a = 4; a < 8; ++a) put<float>(h, 76 + 4 * a, 1.0f);
  put<float>(h, 108, 352.0f);  // vox_offset
  put<float>(h, 112, 1.0f);    // scl_slope
  h[123] = 2;                   // xyzt_units: mm
  std::snprintf(h.data() + 148, 80, "posewarp");
  put<int16_t>(h, 252, 1);  // qform_code: scanner anatomical
  put<int16_t>(h, 254, 1);  // sform_code
  // The quaternion of the proper rotation (nifti1_io's mat44_to_quatern).
  double q[3][3];
  for (int row = 0; row < 3; ++row)
    for (int c = 0; c < 3; ++c) q[row][c] = c == 2 ? qfac * r[row][c] : r[row][c];
  double a = q[0][0] + q[1][1] + q[2][2] + 1.0, b = 0.0, c = 0.0, d = 0.0;
  if (a > 0.5) {
    a = 0.5 * std::sqrt(a);
    b = 0.25 * (q[2][1] - q[1][2]) / a;
    c = 0.25 * (q[0][2] - q[2][0]) / a;
    d = 0.25 * (q[1][0] - q[0][1]) / a;
  } else {
    const double xd = 1.0 + q[0][0] - (q[1][1] + q[2][2]);
    const double yd = 1.0 + q[1][1] - (q[0][0] + q[2][2]);
    const double zd = 1.0 + q[2][2] - (q[0][0] + q[1][1]);
    if (xd > 1.0) {
      b = 0.5 * std::sqrt(xd);
      c = 0.25 * (q[0][1] + q[1][0]) / b;
      d = 0.25 * (q[0][2] + q[2][0]) / b;
      a = 0.25 * (q[2][1] - q[1][2]) / b;
    } else if (yd > 1.0) {
      c = 0.5 * std::sqrt(yd);
      b = 0.25 * (q[0][1] + q[1][0]) / c;
      d = 0.25 * (q[1][2] + q[2][1]) / c;
      a = 0.25 * (q[0][2] - q[2][0]) / c;
    } else {
      d = 0.5 * std::sqrt(zd);
      b = 0.25 * (q[0][2] + q[2][0]) / d;
      c = 0.25 * (q[1][2] + q[2][1]) / d;
      a = 0.25 * (q[1][0] - q[0][1]) / d;
    }
    if (a < 0.0) b = -b, c = -c, d = -d;
  }
  put<float>(h, 256, static_cast<float>(b));
  put<float>(h, 260, static_cast<float>(c));
  put<float>(h, 264, static_cast<float>(d));
  const double origin[3] = {-g.origin[0], -g.origin[1], g.origin[2]};
  for (int row = 0; row < 3; ++row) {
    put<float>(h, 268 + 4 * static_cast<size_t>(row), static_cast<float>(origin[row]));
    for (int col = 0; col < 3; ++col) {
      put<float>(h, 280 + 16 * static_cast<size_t>(row) + 4 * static_cast<size_t>(col),
                 static_cast<float>(r[row][col] * g.spacing[static_cast<size_t>(col)]));
    }
    put<float>(h, 280 + 16 * static_cast<size_t>(row) + 12, static_cast<float>(origin[row]));
  }
  std::memcpy(h.data() + 344, "n+1\0", 4);
  return h;
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
  std::string header = format == VolumeFormat::kNifti ? nifti_header(volume.geometry(), type)
                                                      : nrrd_header(volume.geometry(), type, gzip);
  // NIfTI compresses the whole file (.nii.gz), NRRD its data only (encoding: gzip).
  const bool whole_file = format == VolumeFormat::kNifti;
  std::string raw = whole_file || !gzip ? std::move(header) : std::string();
  const size_t at = raw.size();
  raw.resize(at + static_cast<size_t>(n * pixel_type_bytes(type)));
  if (!convert_samples(volume.data(), n, type, raw.data() + at)) {
    return out_of_range_error("the volume's values do not fit " + std::string(pixel_type_name(type)) +
                              "; choose a wider voxel type");
  }
  if (!gzip) return raw;
  std::string out = whole_file ? std::string() : std::move(header);
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
