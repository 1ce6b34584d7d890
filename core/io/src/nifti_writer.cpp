// NIfTI-1 single files written in parallel: ITK 5.2's header, the voxels in members deflated by libdeflate.
#include "nifti_writer.h"

#include <nifti1_io.h>

#include <libdeflate.h>

#include <atomic>

#include <algorithm>
#include <cstring>
#include <memory>
#include <vector>

#include "file_checks.h"
#include "posewarp/common/atomic_file.h"
#include "posewarp/common/parallel.h"

namespace posewarp::io::detail {
namespace {

// Bytes of voxels per gzip member: large enough that a member's 18 bytes of framing and its fresh dictionary cost
// nothing, small enough that two members per thread keep every core busy on a small volume.
constexpr int64_t kMemberBytes = int64_t{4} << 20;
// libdeflate's fastest level: a CT deflates at about 160 MB/s a core, 6% larger than zlib's default level.
constexpr int kLevel = 1;

int nifti_datatype(PixelType type) {
  switch (type) {
    case PixelType::kUInt8: return NIFTI_TYPE_UINT8;
    case PixelType::kInt8: return NIFTI_TYPE_INT8;
    case PixelType::kUInt16: return NIFTI_TYPE_UINT16;
    case PixelType::kInt16: return NIFTI_TYPE_INT16;
    case PixelType::kUInt32: return NIFTI_TYPE_UINT32;
    case PixelType::kInt32: return NIFTI_TYPE_INT32;
    case PixelType::kUInt64: return NIFTI_TYPE_UINT64;
    case PixelType::kInt64: return NIFTI_TYPE_INT64;
    case PixelType::kFloat32: return NIFTI_TYPE_FLOAT32;
    case PixelType::kFloat64: return NIFTI_TYPE_FLOAT64;
  }
  return NIFTI_TYPE_UINT8;
}

// ITK's NiftiImageIO::SetNIfTIOrientationFromImageIO: LPS to RAS on the direction (float), the origin's x and y
// negated, the quaternion from niftilib, the sform scaled by the spacing.
void set_orientation(nifti_image& nim, const ImageGeometry& g) {
  float axis[3][3];  // axis[a]: the direction of index axis a, RAS
  for (int a = 0; a < 3; ++a) {
    for (int c = 0; c < 3; ++c) axis[a][c] = static_cast<float>(-g.direction[static_cast<size_t>(3 * c + a)]);
    axis[a][2] = -axis[a][2];
  }
  mat44 matrix = nifti_make_orthog_mat44(axis[0][0], axis[0][1], axis[0][2], axis[1][0], axis[1][1], axis[1][2],
                                         axis[2][0], axis[2][1], axis[2][2]);
  mat44 transposed;
  for (int r = 0; r < 4; ++r) {
    for (int c = 0; c < 4; ++c) transposed.m[r][c] = matrix.m[c][r];
  }
  matrix = transposed;
  matrix.m[0][3] = static_cast<float>(-g.origin[0]);
  matrix.m[1][3] = static_cast<float>(-g.origin[1]);
  matrix.m[2][3] = static_cast<float>(g.origin[2]);
  nifti_mat44_to_quatern(matrix, &nim.quatern_b, &nim.quatern_c, &nim.quatern_d, &nim.qoffset_x, &nim.qoffset_y,
                         &nim.qoffset_z, nullptr, nullptr, nullptr, &nim.qfac);
  nim.qto_xyz = matrix;
  nim.sto_xyz = matrix;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) nim.sto_xyz.m[r][c] *= static_cast<float>(g.spacing[static_cast<size_t>(c)]);
  }
  nim.sto_ijk = nifti_mat44_inverse(nim.sto_xyz);
  nim.qto_ijk = nifti_mat44_inverse(nim.qto_xyz);
  nim.pixdim[0] = nim.qfac;
  nim.qform_code = NIFTI_XFORM_SCANNER_ANAT;
  nim.sform_code = NIFTI_XFORM_SCANNER_ANAT;
}

struct NiftiImageFree {
  void operator()(nifti_image* nim) const { nifti_image_free(nim); }
};

// One member of a multi-member gzip, or the raw bytes for .nii.
std::string pack(const char* bytes, size_t size, bool gzip) {
  if (!gzip) return std::string(bytes, size);
  const std::unique_ptr<libdeflate_compressor, decltype(&libdeflate_free_compressor)> compressor(
      libdeflate_alloc_compressor(kLevel), &libdeflate_free_compressor);
  if (!compressor) throw std::bad_alloc();
  std::string packed(libdeflate_gzip_compress_bound(compressor.get(), size), '\0');
  packed.resize(libdeflate_gzip_compress(compressor.get(), bytes, size, packed.data(), packed.size()));
  return packed;
}

}  // namespace

std::string nifti_header(const ImageGeometry& g, PixelType type) {
  const std::unique_ptr<nifti_image, NiftiImageFree> nim(nifti_simple_init_nim());
  if (!nim) throw std::bad_alloc();
  // NiftiImageIO::WriteImageInformation for a 3-D scalar image in a single .nii file.
  nim->nifti_type = NIFTI_FTYPE_NIFTI1_1;
  nim->xyz_units = static_cast<int>(NIFTI_UNITS_MM | NIFTI_UNITS_SEC);
  for (int d = 4; d <= 7; ++d) nim->dim[d] = 1;
  nim->nt = nim->nu = nim->nv = nim->nw = 1;
  nim->dim[1] = nim->nx = static_cast<int>(g.size[0]);
  nim->dim[2] = nim->ny = static_cast<int>(g.size[1]);
  nim->dim[3] = nim->nz = static_cast<int>(g.size[2]);
  nim->pixdim[1] = nim->dx = static_cast<float>(g.spacing[0]);
  nim->pixdim[2] = nim->dy = static_cast<float>(g.spacing[1]);
  nim->pixdim[3] = nim->dz = static_cast<float>(g.spacing[2]);
  nim->nvox = static_cast<size_t>(g.voxel_count());
  nim->ndim = nim->dim[0] = 3;
  nim->datatype = nifti_datatype(type);
  nim->nbyper = pixel_type_bytes(type);
  nim->scl_slope = 1.0f;
  nim->scl_inter = 0.0f;
  set_orientation(*nim, g);
  nifti_set_iname_offset(nim.get());
  const nifti_1_header header = nifti_convert_nim2nhdr(nim.get());
  std::string bytes(reinterpret_cast<const char*>(&header), sizeof(header));
  bytes.append(4, '\0');  // the extension block's flag: no extensions
  return bytes;
}

std::string gzip_members(std::string_view bytes) {
  const auto size = static_cast<int64_t>(bytes.size());
  const int64_t members = std::max<int64_t>(1, (size + kMemberBytes - 1) / kMemberBytes);
  std::vector<std::string> packed(static_cast<size_t>(members));
  parallel_for(0, members, 1, [&](int64_t begin, int64_t end) {
    for (int64_t m = begin; m < end; ++m) {
      const int64_t from = m * kMemberBytes;
      packed[static_cast<size_t>(m)] =
          pack(bytes.data() + from, static_cast<size_t>(std::min(kMemberBytes, size - from)), true);
    }
  });
  std::string out;
  size_t total = 0;
  for (const std::string& member : packed) total += member.size();
  out.reserve(total);
  for (const std::string& member : packed) out += member;
  return out;
}

Status write_nifti(const ImageGeometry& g, PixelType type, const ConvertVoxels& convert, const std::string& path,
                   bool gzip) {
  for (int a = 0; a < 3; ++a) {
    if (g.size[static_cast<size_t>(a)] > 32767) {
      return invalid_argument_error("NIfTI-1 holds at most 32767 voxels along an axis; " + in_quotes(path) +
                                    " would need " + std::to_string(g.size[static_cast<size_t>(a)]) +
                                    ": write NRRD or MetaImage");
    }
  }
  POSEWARP_ASSIGN_OR_RETURN(AtomicFile file, AtomicFile::create(path, "volume"));
  POSEWARP_RETURN_IF_ERROR(file.write(pack(nifti_header(g, type).data(), 352, gzip)));
  const int64_t bytes_per_voxel = pixel_type_bytes(type);
  const int64_t member_voxels = std::max<int64_t>(1, kMemberBytes / bytes_per_voxel);
  const int64_t voxels = g.voxel_count();
  const int64_t members = (voxels + member_voxels - 1) / member_voxels;
  // Members are made a batch at a time, in parallel, and written in order: memory stays a few members per thread.
  const int64_t batch = 2 * static_cast<int64_t>(std::max(1, thread_count()));
  std::vector<std::string> packed;
  std::atomic<bool> fits{true};
  for (int64_t first = 0; first < members; first += batch) {
    const int64_t count = std::min(batch, members - first);
    packed.assign(static_cast<size_t>(count), std::string());
    parallel_for(0, count, 1, [&](int64_t begin, int64_t end) {
      std::vector<char> raw;
      for (int64_t m = begin; m < end; ++m) {
        const int64_t from = (first + m) * member_voxels;
        const int64_t n = std::min(member_voxels, voxels - from);
        raw.resize(static_cast<size_t>(n * bytes_per_voxel));
        if (!convert(from, n, raw.data())) fits = false;
        packed[static_cast<size_t>(m)] = pack(raw.data(), raw.size(), gzip);
      }
    });
    // The values are checked as they are converted: a file with one that does not fit is never committed.
    if (!fits) return out_of_range_error("values of the volume do not fit " + std::string(pixel_type_name(type)));
    for (const std::string& member : packed) POSEWARP_RETURN_IF_ERROR(file.write(member));
  }
  return file.commit();
}

}  // namespace posewarp::io::detail
