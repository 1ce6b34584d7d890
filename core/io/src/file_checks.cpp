// NIfTI, NRRD and inline-data checks (no ITK here), and the helpers every format's checks share; MetaImage's are
// metaimage_checks.cpp.
#include "file_checks.h"

#include "posewarp/common/result.h"

#include <zlib.h>

#include <algorithm>
#include <cctype>
#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>
#include <set>
#include <optional>
#include <sstream>
#include <vector>

namespace posewarp::io::detail {
namespace {

namespace fs = std::filesystem;

template <typename T>
T read_field(const unsigned char* header, size_t offset, bool swap) {
  unsigned char bytes[sizeof(T)];
  std::memcpy(bytes, header + offset, sizeof(T));
  if (swap) std::reverse(bytes, bytes + sizeof(T));
  T value;
  std::memcpy(&value, bytes, sizeof(T));
  return value;
}

// Bytes per voxel of a NIfTI datatype code; 0 when unknown.
int nifti_bits(int16_t datatype) {
  switch (datatype) {
    case 2:
    case 256: return 8;  // uint8, int8
    case 4:
    case 512: return 16;  // int16, uint16
    case 8:
    case 16:
    case 768: return 32;  // int32, float32, uint32
    case 64:
    case 1024:
    case 1280:
    case 32: return 64;    // float64, int64, uint64, complex64
    case 128: return 24;   // rgb24
    case 2304: return 32;  // rgba32
    default: return 0;
  }
}

// Counts the bytes a (possibly gzip-compressed) file decompresses to, reading at most until `limit` bytes came out
// (a small file can inflate to gigabytes: nothing past what the header promises is worth the time); -1 when the
// stream is corrupt or ends early. gzread, unlike inflate, reads every member of a multi-member gzip file.
int64_t decompressed_size(const std::string& path, int64_t limit) {
  gzFile file = gzopen(path.c_str(), "rb");
  if (!file) return -1;
  std::vector<char> buffer(1 << 18);
  int64_t total = 0;
  while (total < limit) {
    const int64_t wanted = std::min<int64_t>(static_cast<int64_t>(buffer.size()), limit - total);
    const int n = gzread(file, buffer.data(), static_cast<unsigned>(wanted));
    if (n < 0) {
      gzclose(file);
      return -1;
    }
    if (n == 0) break;
    total += n;
  }
  int err = 0;
  gzerror(file, &err);
  gzclose(file);
  return err == Z_OK || err == Z_STREAM_END ? total : -1;
}

// The 348-byte NIfTI-1 header of a .nii or .nii.gz.
Status read_nifti_header(const std::string& path, unsigned char (&header)[348]) {
  gzFile file = gzopen(path.c_str(), "rb");
  if (!file) return not_found_error("cannot open " + in_quotes(path));
  const int n = gzread(file, header, sizeof(header));
  gzclose(file);
  if (n != static_cast<int>(sizeof(header))) {
    return invalid_argument_error(in_quotes(path) + " is too short to hold a NIfTI header (" +
                                  std::to_string(std::max(n, 0)) + " bytes); the file is truncated or not NIfTI");
  }
  return ok_status();
}

// Float voxels must be finite: ITK's NIfTI reader turns a NaN into 0 without a word, which makes a NaN label
// background and a NaN CT voxel water. Streams the data once (gzread reads plain and gzip files alike).
Status check_nifti_finite(const std::string& path, int64_t offset, int64_t voxels, bool doubles, bool swap) {
  gzFile file = gzopen(path.c_str(), "rb");
  if (!file) return not_found_error("cannot open " + in_quotes(path));
  gzbuffer(file, 1 << 17);
  const int bytes = doubles ? 8 : 4;
  std::vector<unsigned char> chunk(size_t{1} << 20);
  int64_t voxel = 0;
  bool ok = gzseek(file, static_cast<z_off_t>(offset), SEEK_SET) == static_cast<z_off_t>(offset);
  while (ok && voxel < voxels) {
    const int64_t count = std::min<int64_t>(voxels - voxel, static_cast<int64_t>(chunk.size()) / bytes);
    ok = gzread(file, chunk.data(), static_cast<unsigned>(count * bytes)) == count * bytes;
    for (int64_t i = 0; ok && i < count; ++i) {
      const double value = doubles ? read_field<double>(chunk.data(), static_cast<size_t>(i * 8), swap)
                                   : read_field<float>(chunk.data(), static_cast<size_t>(i * 4), swap);
      if (!std::isfinite(value)) {
        gzclose(file);
        return invalid_argument_error(in_quotes(path) + " holds a NaN or infinite value at voxel " +
                                      std::to_string(voxel + i) +
                                      "; a voxel must be a number (replace them, e.g. with the background value)");
      }
    }
    voxel += count;
  }
  gzclose(file);
  if (!ok) return data_loss_error("cannot read the voxels of " + in_quotes(path) + "; the file is damaged");
  return ok_status();
}

// The byte order of a NIfTI-1 header (true: swapped). Anything else is refused: niftilib reads a header with a
// wrong sizeof_hdr anyway, and fuzzed ones carried a NaN past these checks into ITK's SVD, which aborts.
Result<std::optional<bool>> nifti1_byte_order(const unsigned char (&header)[348], const std::string& path) {
  if (read_field<int32_t>(header, 0, false) == 348) return std::optional<bool>(false);
  if (read_field<int32_t>(header, 0, true) == 348) return std::optional<bool>(true);
  // niftilib reads whatever it is handed; ITK then aborts on the NaN it finds in the orientation. Only NIfTI-1's
  // 348-byte header is checked here, so only it is read.
  if (read_field<int32_t>(header, 0, false) == 540 || read_field<int32_t>(header, 0, true) == 540) {
    return invalid_argument_error(in_quotes(path) +
                                  " is NIfTI-2, which posewarp does not read; save it as NIfTI-1 "
                                  "(.nii or .nii.gz)");
  }
  return invalid_argument_error(in_quotes(path) + " has a sizeof_hdr of " +
                                std::to_string(read_field<int32_t>(header, 0, false)) +
                                " (NIfTI-1's is 348); the header is corrupt or the file is not NIfTI");
}

// The first `limit` bytes of a file, as the header parsers below see them (no line of a hostile file can make them
// read more).
std::string file_head(const std::string& path, size_t limit) {
  std::ifstream in(path, std::ios::binary);
  std::string head(limit, '\0');
  in.read(head.data(), static_cast<std::streamsize>(limit));
  head.resize(static_cast<size_t>(std::max<std::streamsize>(in.gcount(), 0)));
  return head;
}

std::string trimmed(std::string text) {
  text.erase(0, text.find_first_not_of(" \t\r"));
  text.erase(text.find_last_not_of(" \t\r") + 1);
  return text;
}

// Lower case without blanks: how a field name is compared when a reader may be lenient about both.
std::string squeezed_lower(const std::string& text) {
  std::string out;
  for (const char c : text) {
    if (c != ' ' && c != '\t' && c != '\r') out += static_cast<char>(std::tolower(static_cast<unsigned char>(c)));
  }
  return out;
}

constexpr const char* kSendInline =
    "; send the voxels inline: a .nii/.nii.gz, a .nrrd with its data inline, or a .mha with ElementDataFile = LOCAL";

}  // namespace

std::string in_quotes(const std::string& path) {
  return "'" + path + "'";
}

// Bytes a zlib or gzip stream in `path` from `offset` inflates to, reading at most until `limit` bytes came out;
// -1 when the stream is corrupt or ends early (truncated).
int64_t inflated_size(const std::string& path, int64_t offset, int64_t limit) {
  std::ifstream in(path, std::ios::binary);
  if (!in || !in.seekg(offset)) return -1;
  z_stream stream{};
  if (inflateInit2(&stream, 15 + 32) != Z_OK) return -1;  // zlib or gzip header, detected
  std::vector<unsigned char> input(1 << 16), output(1 << 16);
  int64_t total = 0;
  int status = Z_OK;
  while (status != Z_STREAM_END && total <= limit) {
    if (stream.avail_in == 0) {
      in.read(reinterpret_cast<char*>(input.data()), static_cast<std::streamsize>(input.size()));
      stream.avail_in = static_cast<uInt>(in.gcount());
      stream.next_in = input.data();
      if (stream.avail_in == 0) break;  // the stream ends before its end marker
    }
    stream.next_out = output.data();
    stream.avail_out = static_cast<uInt>(output.size());
    status = inflate(&stream, Z_NO_FLUSH);
    if (status != Z_OK && status != Z_STREAM_END) break;
    total += static_cast<int64_t>(output.size() - stream.avail_out);
  }
  inflateEnd(&stream);
  return status == Z_STREAM_END || total > limit ? total : -1;
}

// A detached data file named in a header: `inline_word` (LOCAL) or a plain file name (no directory part, not "." or
// "..") of a regular file beside the header.
Status check_data_file_name(const std::string& path, const std::string& name, const char* field,
                            const char* inline_word) {
  if (name == inline_word) return ok_status();
  const bool plain = !name.empty() && name != "." && name != ".." && name.find('/') == std::string::npos &&
                     name.find('\\') == std::string::npos;
  std::error_code ec;
  if (!plain || !fs::is_regular_file(fs::path(path).parent_path() / name, ec)) {
    return invalid_argument_error(in_quotes(path) + " names its voxel data '" + name.substr(0, 80) + "' (" + field +
                                  "); posewarp reads the data inline or from one file beside the header, named "
                                  "without a directory");
  }
  return ok_status();
}

Status check_inline_data(const std::string& path, VolumeFormat format) {
  constexpr size_t kHeaderLimit = size_t{1} << 20;
  switch (format) {
    case VolumeFormat::kDicomSeries:
      return invalid_argument_error(in_quotes(path) +
                                    " names a DICOM series (a directory, or a path without a volume extension); only "
                                    "a single file holding its own voxels is read here" +
                                    kSendInline);
    case VolumeFormat::kNifti: {
      unsigned char header[348];
      if (!read_nifti_header(path, header).ok()) return ok_status();  // the reader reports it
      if (std::memcmp(header + 344, "n+1", 4) != 0) {
        return invalid_argument_error(in_quotes(path) +
                                      " is not a single-file NIfTI (its magic is not \"n+1\": a header whose voxels "
                                      "are in a separate .img file, or ANALYZE)" +
                                      kSendInline);
      }
      return ok_status();
    }
    case VolumeFormat::kNrrd: {
      const std::string head = file_head(path, kHeaderLimit);
      if (head.rfind("NRRD", 0) != 0) return ok_status();  // not NRRD: the reader reports it
      const bool cut = head.size() == kHeaderLimit;
      std::istringstream lines(head);
      std::string line;
      std::getline(lines, line);
      while (std::getline(lines, line)) {
        if (lines.eof() && cut) break;  // the last line of a cut head may be cut short: judged below
        if (!line.empty() && line.back() == '\r') line.pop_back();
        if (line.empty()) return ok_status();  // the header ended: the data is inline
        if (line[0] == '#') continue;
        // teem matches field names ignoring case and knows "data file" as "datafile" too.
        const std::string key = squeezed_lower(line.substr(0, line.find(':')));
        if (key == "datafile" || key == "datafiles") {
          const std::string value = trimmed(line.substr(std::min(line.size(), line.find(':') + 1)));
          return invalid_argument_error(in_quotes(path) + " is a NRRD header whose voxels are in a separate file ('" +
                                        value.substr(0, 80) + "', its \"data file\" field)" + kSendInline);
        }
      }
      if (!cut) return ok_status();  // a header without data: the reader reports it
      return invalid_argument_error(in_quotes(path) +
                                    " has a NRRD header that runs past 1 MB without the empty line that ends it; "
                                    "the file is damaged or not NRRD");
    }
    case VolumeFormat::kMetaImage: {
      const std::string head = file_head(path, kHeaderLimit);
      const bool cut = head.size() == kHeaderLimit;
      std::istringstream lines(head);
      std::string line;
      while (std::getline(lines, line) && !(lines.eof() && cut)) {
        const size_t eq = line.find('=');
        if (eq == std::string::npos || squeezed_lower(line.substr(0, eq)) != "elementdatafile") continue;
        const std::string value = trimmed(line.substr(eq + 1));
        if (value == "LOCAL") return ok_status();
        return invalid_argument_error(in_quotes(path) +
                                      " is a MetaImage header whose voxels are in a separate file ('" +
                                      value.substr(0, 80) + "', its ElementDataFile)" + kSendInline);
      }
      return ok_status();  // no ElementDataFile line: check_metaimage_header refuses the header
    }
  }
  return ok_status();
}

Status check_nifti_file(const std::string& path) {
  unsigned char header[348];
  POSEWARP_RETURN_IF_ERROR(read_nifti_header(path, header));
  POSEWARP_ASSIGN_OR_RETURN(const std::optional<bool> order, nifti1_byte_order(header, path));
  if (!order) return ok_status();  // NIfTI-2 or not NIfTI at all: ITK decides and reports
  const bool swap = *order;
  const int16_t ndim = read_field<int16_t>(header, 40, swap);
  if (ndim < 1 || ndim > 7) {
    return invalid_argument_error(in_quotes(path) + " declares " + std::to_string(ndim) +
                                  " dimensions (dim[0] must be 1..7); the header is corrupt");
  }
  int64_t voxels = 1;
  for (int d = 1; d <= ndim; ++d) {
    const int16_t size = read_field<int16_t>(header, 40 + 2 * static_cast<size_t>(d), swap);
    if (size < 1) {
      return invalid_argument_error(in_quotes(path) + " declares size " + std::to_string(size) + " along axis " +
                                    std::to_string(d - 1) + "; every dimension must be at least 1 (corrupt header)");
    }
    voxels *= size;
    if (voxels > (int64_t{1} << 40)) {  // 32767^7 would overflow; no file holds a trillion voxels
      return invalid_argument_error(in_quotes(path) + " declares more than 2^40 voxels; the header is corrupt");
    }
  }
  for (int d = 1; d <= std::min<int>(ndim, 3); ++d) {
    const float spacing = read_field<float>(header, 76 + 4 * static_cast<size_t>(d), swap);
    if (!(spacing > 0.0f) || !std::isfinite(spacing)) {
      std::ostringstream out;
      out << in_quotes(path) << " declares a voxel spacing of " << spacing << " mm along axis " << d - 1
          << "; spacing must be positive (fix pixdim in the header)";
      return invalid_argument_error(out.str());
    }
  }
  const int bits = nifti_bits(read_field<int16_t>(header, 70, swap));
  const float vox_offset = read_field<float>(header, 108, swap);
  if (bits == 0 || !(vox_offset >= 0.0f)) return ok_status();  // ITK reports unsupported types itself
  if (vox_offset > 1e12f) {
    return invalid_argument_error(in_quotes(path) + " has a vox_offset of " + std::to_string(vox_offset) +
                                  " bytes in its NIfTI header, beyond any file; the header is corrupt");
  }
  const int64_t needed = static_cast<int64_t>(vox_offset) + voxels * bits / 8;
  std::error_code ec;
  const bool compressed = path.size() > 3 && path.compare(path.size() - 3, 3, ".gz") == 0;
  int64_t present = 0;
  if (compressed) {
    present = decompressed_size(path, needed);
    if (present < 0) {
      return data_loss_error(in_quotes(path) + " is not a complete gzip stream (truncated or corrupt); copy it again");
    }
  } else {
    present = static_cast<int64_t>(fs::file_size(path, ec));
  }
  if (present < needed) {
    return data_loss_error(in_quotes(path) + " is truncated: its header promises " + std::to_string(needed) +
                           " bytes but it holds " + std::to_string(present) + "; copy the file again");
  }
  const int16_t datatype = read_field<int16_t>(header, 70, swap);
  if (datatype == 16 || datatype == 64) {
    return check_nifti_finite(path, static_cast<int64_t>(vox_offset), voxels, datatype == 64, swap);
  }
  return ok_status();
}

Status check_nifti_geometry_fields(const std::string& path) {
  unsigned char header[348];
  POSEWARP_RETURN_IF_ERROR(read_nifti_header(path, header));
  POSEWARP_ASSIGN_OR_RETURN(const std::optional<bool> order, nifti1_byte_order(header, path));
  if (!order) return ok_status();  // NIfTI-2 or not NIfTI: ITK decides
  const bool swap = *order;
  // The sizes, named by field: ITK only says a file with a zero size "is not recognized as a NIFTI file".
  const int16_t ndim = read_field<int16_t>(header, 40, swap);
  if (ndim < 1 || ndim > 7) {
    return invalid_argument_error(in_quotes(path) + " has dim[0] = " + std::to_string(ndim) +
                                  " in its NIfTI header (the number of dimensions must be 1..7); the header is "
                                  "corrupt (fix or regenerate the file)");
  }
  for (int d = 1; d <= ndim; ++d) {
    const int16_t size = read_field<int16_t>(header, 40 + 2 * static_cast<size_t>(d), swap);
    if (size < 1) {
      return invalid_argument_error(in_quotes(path) + " has dim[" + std::to_string(d) + "] = " + std::to_string(size) +
                                    " in its NIfTI header (the size along axis " + std::to_string(d - 1) +
                                    "); every size must be at least 1: the header is corrupt (fix or regenerate "
                                    "the file)");
    }
  }
  struct Field {
    size_t offset;
    int count;
    const char* name;
  };
  constexpr Field kFields[] = {{76, 8, "pixdim"},         {108, 1, "vox_offset"}, {256, 3, "quatern_b/c/d"},
                               {268, 3, "qoffset_x/y/z"}, {280, 4, "srow_x"},     {296, 4, "srow_y"},
                               {312, 4, "srow_z"}};
  for (const Field& field : kFields) {
    for (int i = 0; i < field.count; ++i) {
      const float value = read_field<float>(header, field.offset + 4 * static_cast<size_t>(i), swap);
      if (!std::isfinite(value)) {
        return invalid_argument_error(in_quotes(path) + " has a NaN or infinite " + field.name +
                                      " in its NIfTI header; the header is corrupt (fix or regenerate the file)");
      }
      // Finite but absurd values overflow inside ITK's orientation code (and its SVD aborts on the result): no
      // scanner is 10 km wide, and a quaternion's b, c, d lie within [-1, 1].
      const bool quaternion = field.offset == 256;
      if (std::abs(value) > (quaternion ? 1.0001f : 1e7f)) {
        return invalid_argument_error(in_quotes(path) + " has " + field.name + " = " + std::to_string(value) +
                                      " in its NIfTI header, beyond any real geometry; the header is corrupt");
      }
    }
  }
  // The spacings, named by field: ITK turns a zero or negative one into "orthonormal direction cosines".
  for (int d = 1; d <= std::min<int>(ndim, 3); ++d) {
    const float spacing = read_field<float>(header, 76 + 4 * static_cast<size_t>(d), swap);
    if (!(spacing > 0.0f)) {
      std::ostringstream out;
      out << in_quotes(path) << " has pixdim[" << d << "] = " << spacing
          << " in its NIfTI header (the voxel spacing along axis " << d - 1
          << ", mm); every spacing must be positive: fix pixdim in the header";
      return invalid_argument_error(out.str());
    }
  }
  if (read_field<float>(header, 108, swap) < 0.0f) {
    return invalid_argument_error(in_quotes(path) +
                                  " has a negative vox_offset in its NIfTI header; the header is "
                                  "corrupt (fix or regenerate the file)");
  }
  const int16_t sform_code = read_field<int16_t>(header, 254, swap);
  if (sform_code > 0) {
    double norm = 0.0;
    for (int i = 0; i < 12; ++i) {
      if (i % 4 == 3) continue;  // the offsets
      const float v = read_field<float>(header, 280 + 4 * static_cast<size_t>(i), swap);
      norm += static_cast<double>(v) * v;
    }
    if (!(norm > 0.0)) {
      return invalid_argument_error(in_quotes(path) + " has an sform (sform_code " + std::to_string(sform_code) +
                                    ") whose matrix is all zero; the header cannot place its voxels (fix the sform or "
                                    "set sform_code to 0)");
    }
  }
  return ok_status();
}

Status check_nrrd_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return not_found_error("cannot open " + in_quotes(path));
  std::map<std::string, std::string> fields;
  std::string line;
  std::getline(in, line);
  if (line.rfind("NRRD", 0) != 0) return ok_status();  // ITK reports
  while (std::getline(in, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.empty()) break;  // the data follows (inline)
    if (line[0] == '#') continue;
    const size_t colon = line.find(':');
    if (colon == std::string::npos) continue;
    std::string value = line.substr(colon + 1);
    if (!value.empty() && value[0] == '=') value.erase(0, 1);  // key:=value
    value.erase(0, value.find_first_not_of(" \t"));
    fields[line.substr(0, colon)] = value;
  }
  const std::streamoff data_offset = in.tellg();
  const std::string encoding = fields["encoding"];
  const bool gzip = encoding == "gzip" || encoding == "gz";
  if (!gzip && encoding != "raw") return ok_status();  // text, hex, bzip2: ITK reads and checks them
  static const std::map<std::string, int> kTypeBytes{
      {"uchar", 1},    {"unsigned char", 1}, {"uint8", 1},     {"uint8_t", 1},  {"signed char", 1},
      {"int8", 1},     {"int8_t", 1},        {"char", 1},      {"short", 2},    {"int16", 2},
      {"int16_t", 2},  {"ushort", 2},        {"uint16", 2},    {"uint16_t", 2}, {"unsigned short", 2},
      {"int", 4},      {"int32", 4},         {"int32_t", 4},   {"uint", 4},     {"uint32", 4},
      {"uint32_t", 4}, {"unsigned int", 4},  {"float", 4},     {"double", 8},   {"longlong", 8},
      {"int64", 8},    {"int64_t", 8},       {"ulonglong", 8}, {"uint64", 8},   {"uint64_t", 8}};
  const auto type = kTypeBytes.find(fields["type"]);
  if (type == kTypeBytes.end() || !fields.count("sizes")) return ok_status();
  int64_t promised = type->second;
  {
    std::istringstream sizes(fields["sizes"]);
    int64_t size = 0;
    while (sizes >> size) {
      if (size < 1) return ok_status();                              // the header check refuses it
      if (size > (int64_t{1} << 40) / promised) return ok_status();  // the voxel limit refuses it (no overflow here)
      promised *= size;
    }
  }
  std::string data_path = path;
  int64_t offset = static_cast<int64_t>(data_offset);
  const std::string detached = fields.count("data file") ? fields["data file"] : fields["datafile"];
  if (!detached.empty()) {
    if (detached.find(' ') != std::string::npos || detached == "LIST" || detached.find('%') != std::string::npos) {
      return invalid_argument_error(in_quotes(path) +
                                    " names its voxel data as a list of files (data file); posewarp " +
                                    "reads NRRD with its data inline (.nrrd) or in one file beside the header (.nhdr)");
    }
    POSEWARP_RETURN_IF_ERROR(check_data_file_name(path, detached, "data file", ""));
    data_path = (fs::path(path).parent_path() / detached).string();
    offset = 0;
  }
  if (!gzip) {
    std::error_code ec;
    const auto bytes = fs::file_size(data_path, ec);
    const int64_t present = ec ? 0 : static_cast<int64_t>(bytes) - offset;
    if (present < promised) {
      return data_loss_error(in_quotes(path) + " is truncated: its header promises " + std::to_string(promised) +
                             " bytes of voxels (sizes " + fields["sizes"] + ") but " +
                             (ec ? "its data file cannot be read" : "it holds " + std::to_string(present)) +
                             "; copy the file again");
    }
    return ok_status();
  }
  const int64_t inflated = inflated_size(data_path, offset, promised);
  if (inflated < 0) {
    return data_loss_error("the gzip data of " + in_quotes(path) + " is corrupt or truncated; copy the file again");
  }
  if (inflated < promised) {
    return data_loss_error("the gzip data of " + in_quotes(path) + " holds " + std::to_string(inflated) +
                           " bytes, but its header promises " + std::to_string(promised) + " (sizes " +
                           fields["sizes"] + "); the file is damaged or not what it claims");
  }
  return ok_status();
}

}  // namespace posewarp::io::detail
