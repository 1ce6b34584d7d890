// MetaImage (.mha, .mhd) header and completeness checks (no ITK here): ITK's MetaIO spins forever or overflows
// buffers on damaged headers, and reads short data with only a warning.
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
#include <optional>
#include <set>
#include <sstream>
#include <vector>

#include "file_checks.h"
#include "posewarp/common/result.h"

namespace posewarp::io::detail {

namespace fs = std::filesystem;

namespace {

using HeaderFields = std::map<std::string, std::string>;

// INVALID_ARGUMENT for the MetaImage header of `path`; `what` says what is wrong with it.
Status corrupt_header(const std::string& path, const std::string& what) {
  return invalid_argument_error(in_quotes(path) + " has a MetaImage header that " + what +
                                "; the file is damaged or not MetaImage");
}

// The header's key = value lines up to and including ElementDataFile, each key and value checked for size.
Result<HeaderFields> read_header_fields(std::ifstream& in, const std::string& path) {
  HeaderFields fields;
  std::string line;
  int64_t header_bytes = 0;
  bool ended = false;
  while (std::getline(in, line)) {
    header_bytes += static_cast<int64_t>(line.size()) + 1;
    if (header_bytes > (int64_t{1} << 20)) {
      return corrupt_header(path, "runs past 1 MB without its ElementDataFile line");
    }
    if (!line.empty() && line.back() == '\r') line.pop_back();
    if (line.find_first_not_of(" \t") == std::string::npos) continue;
    const size_t eq = line.find('=');
    if (eq == std::string::npos) return corrupt_header(path, "has a line without '=' before its data");
    std::string key = line.substr(0, eq);
    key.erase(key.find_last_not_of(" \t") + 1);
    key.erase(0, key.find_first_not_of(" \t"));
    if (key.empty() || !std::all_of(key.begin(), key.end(), [](char c) {
          return std::isalnum(static_cast<unsigned char>(c)) || c == '_' || c == '-';
        })) {
      return corrupt_header(path, "has a malformed key");
    }
    // MetaIO copies each key into a 255-byte field name and each text value (ObjectType, ElementType, Name, ...)
    // into a 255-byte buffer: a longer one overflowed them (found by fuzzing). Keys are short names; only number
    // lists (a transform's nine numbers at full precision) may run past 254 characters.
    if (key.size() > 64) return corrupt_header(path, "has a key of " + std::to_string(key.size()) + " characters");
    std::string value = line.substr(eq + 1);
    value.erase(0, value.find_first_not_of(" \t"));
    value.erase(value.find_last_not_of(" \t") + 1);
    static const std::set<std::string> number_lists{"TransformMatrix", "Rotation", "Orientation", "Offset",
                                                     "Position", "Origin", "CenterOfRotation", "ElementSpacing",
                                                     "ElementSize", "DimSize"};
    if (value.size() > (number_lists.count(key) ? size_t{1024} : size_t{254})) {
      return corrupt_header(path,
                            "has a " + key.substr(0, 32) + " value of " + std::to_string(value.size()) + " characters");
    }
    // MetaIO acts on the first of two equal keys, a map on the last: one of each only (found by fuzzing).
    if (!fields.emplace(key, value).second) return corrupt_header(path, "has the key " + key + " twice");
    if (key == "ElementDataFile") {
      ended = true;
      break;
    }
  }
  if (!ended) return corrupt_header(path, "does not end with an ElementDataFile line");
  return fields;
}

// Whether text holds exactly `expected` finite numbers of magnitude at most 1e9 (whole numbers if `whole`).
bool holds_numbers(const std::string& text, int expected, bool whole) {
  std::istringstream stream(text);
  std::string token;
  int count = 0;
  while (stream >> token) {
    char* end = nullptr;
    const double v = std::strtod(token.c_str(), &end);
    if (end == token.c_str() || *end != '\0' || !std::isfinite(v) || std::abs(v) > 1e9 ||
        (whole && v != std::floor(v))) {
      return false;
    }
    ++count;
  }
  return count == expected;
}

// Checks NDims, and that DimSize and every per-axis or per-matrix field holds as many numbers as NDims asks.
Status check_dimension_fields(HeaderFields& fields, const std::string& path) {
  // NDims and the counted fields are what MetaIO loops over; a negative or absurd count made it spin forever
  // (found by fuzzing).
  const std::string& ndims_text = fields["NDims"];
  if (ndims_text.size() != 1 || ndims_text[0] < '1' || ndims_text[0] > '4') {
    return corrupt_header(path, "declares NDims '" + ndims_text + "' (posewarp reads 3-dimensional images)");
  }
  const int ndims = ndims_text[0] - '0';
  if (!holds_numbers(fields["DimSize"], ndims, true)) {
    return corrupt_header(path, "needs DimSize as " + ndims_text + " whole numbers");
  }
  const std::pair<const char*, int> counted[] = {{"ElementSpacing", ndims},
                                                 {"ElementSize", ndims},
                                                 {"Offset", ndims},
                                                 {"Position", ndims},
                                                 {"Origin", ndims},
                                                 {"CenterOfRotation", ndims},
                                                 {"TransformMatrix", ndims * ndims},
                                                 {"Rotation", ndims * ndims},
                                                 {"Orientation", ndims * ndims}};
  for (const auto& [key, count] : counted) {
    if (fields.count(key) && !holds_numbers(fields[key], count, false)) {
      return corrupt_header(path, "needs " + std::string(key) + " as " + std::to_string(count) + " finite numbers");
    }
  }
  return ok_status();
}

// The index and value of the first number in text that is not `good`, or (-1, 0).
template <typename Predicate>
std::pair<int, double> first_not(const std::string& text, Predicate good) {
  std::istringstream stream(text);
  double value = 0.0;
  for (int i = 0; stream >> value; ++i) {
    if (!good(value)) return std::make_pair(i, value);
  }
  return std::make_pair(-1, 0.0);
}

// Checks that every DimSize is at least 1 and every ElementSpacing and ElementSize positive, naming the axis.
Status check_sizes_and_spacings(HeaderFields& fields, const std::string& path) {
  // Sizes and spacings, named by field: ITK turns a zero or negative spacing into "orthonormal direction cosines".
  if (const auto [axis, size] = first_not(fields["DimSize"], [](double v) { return v >= 1.0; }); axis >= 0) {
    std::ostringstream out;
    out << in_quotes(path) << " has DimSize " << fields["DimSize"] << " in its MetaImage header: DimSize[" << axis
        << "] = " << size << ", but every size must be at least 1 (fix DimSize in the header)";
    return invalid_argument_error(out.str());
  }
  for (const char* key : {"ElementSpacing", "ElementSize"}) {
    if (!fields.count(key)) continue;
    if (const auto [axis, spacing] = first_not(fields[key], [](double v) { return v > 0.0; }); axis >= 0) {
      std::ostringstream out;
      out << in_quotes(path) << " has " << key << " " << fields[key] << " in its MetaImage header: " << key << "["
          << axis << "] = " << spacing << " mm, but every spacing must be positive (fix " << key << " in the header)";
      return invalid_argument_error(out.str());
    }
  }
  return ok_status();
}

// Checks HeaderSize, CompressedDataSize and ElementNumberOfChannels: one whole number each, in a usable range.
Status check_data_size_fields(HeaderFields& fields, const std::string& path) {
  for (const char* key : {"HeaderSize", "CompressedDataSize", "ElementNumberOfChannels"}) {
    if (fields.count(key) && !holds_numbers(fields[key], 1, true)) {
      return corrupt_header(path, "needs " + std::string(key) + " as a number");
    }
  }
  // MetaIO allocates CompressedDataSize bytes as given: a negative size became a 2^64-byte allocation (found by
  // fuzzing). HeaderSize -1 means "the data ends the file"; other negative sizes mean nothing.
  if (fields.count("CompressedDataSize") && std::atof(fields["CompressedDataSize"].c_str()) < 0) {
    return corrupt_header(path, "declares a negative CompressedDataSize");
  }
  if (fields.count("HeaderSize") && std::atof(fields["HeaderSize"].c_str()) < -1) {
    return corrupt_header(path, "declares a negative HeaderSize other than -1");
  }
  if (fields.count("ElementNumberOfChannels") && std::abs(std::atof(fields["ElementNumberOfChannels"].c_str())) > 16) {
    return corrupt_header(path, "declares more than 16 channels per voxel");
  }
  return ok_status();
}

}  // namespace

Status check_metaimage_header(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return not_found_error("cannot open " + in_quotes(path));
  POSEWARP_ASSIGN_OR_RETURN(HeaderFields fields, read_header_fields(in, path));
  POSEWARP_RETURN_IF_ERROR(check_dimension_fields(fields, path));
  POSEWARP_RETURN_IF_ERROR(check_sizes_and_spacings(fields, path));
  POSEWARP_RETURN_IF_ERROR(check_data_size_fields(fields, path));
  // The data is inline (.mha) or one plain file beside the header (.mhd): never a path elsewhere, which MetaIO
  // would read as voxels (a directory made it allocate without bound; an uploaded header could name any file on the
  // server).
  POSEWARP_RETURN_IF_ERROR(check_data_file_name(path, fields["ElementDataFile"], "ElementDataFile", "LOCAL"));
  return ok_status();
}

Status check_metaimage_file(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return not_found_error("cannot open " + in_quotes(path));
  std::map<std::string, std::string> fields;
  std::string line;
  std::streamoff data_offset = -1;
  while (std::getline(in, line)) {
    const size_t eq = line.find('=');
    if (eq == std::string::npos) continue;
    auto trim = [](std::string s) {
      s.erase(0, s.find_first_not_of(" \t\r"));
      s.erase(s.find_last_not_of(" \t\r") + 1);
      return s;
    };
    const std::string key = trim(line.substr(0, eq));
    fields[key] = trim(line.substr(eq + 1));
    if (key == "ElementDataFile") {
      data_offset = in.eof() ? -1 : static_cast<std::streamoff>(in.tellg());  // no newline: the header never ends
      break;
    }
  }
  if (data_offset < 0 || !fields.count("DimSize") || !fields.count("ElementType")) {
    return invalid_argument_error(in_quotes(path) + " is not a complete MetaImage header (it needs DimSize, " +
                                  "ElementType and an ElementDataFile line ending the header); the file is damaged");
  }
  static const std::map<std::string, int> kElementBytes{{"MET_UCHAR", 1},  {"MET_CHAR", 1},       {"MET_USHORT", 2},
                                                        {"MET_SHORT", 2},  {"MET_UINT", 4},       {"MET_INT", 4},
                                                        {"MET_FLOAT", 4},  {"MET_ULONG", 8},      {"MET_LONG", 8},
                                                        {"MET_DOUBLE", 8}, {"MET_ULONG_LONG", 8}, {"MET_LONG_LONG", 8}};
  auto element = kElementBytes.find(fields["ElementType"]);
  if (element == kElementBytes.end()) return ok_status();
  int64_t voxels = 1;
  {
    std::istringstream dims(fields["DimSize"]);
    int64_t size = 0;
    while (dims >> size) {
      if (size < 1) {
        return invalid_argument_error(in_quotes(path) + " declares DimSize " + fields["DimSize"] +
                                      "; every dimension must be at least 1 (corrupt header)");
      }
      if (size > (int64_t{1} << 40) / voxels) {  // the product would overflow; no file holds a trillion voxels
        return invalid_argument_error(in_quotes(path) + " declares DimSize " + fields["DimSize"] +
                                      ", more than 2^40 voxels (corrupt header)");
      }
      voxels *= size;
    }
  }
  int channels = 1;
  if (fields.count("ElementNumberOfChannels")) {
    channels = std::clamp(std::atoi(fields["ElementNumberOfChannels"].c_str()), 1, 1024);
  }
  if (fields.count("ElementSpacing")) {
    std::istringstream spacings(fields["ElementSpacing"]);
    double spacing = 0.0;
    while (spacings >> spacing) {
      if (!(spacing > 0.0) || !std::isfinite(spacing)) {
        return invalid_argument_error(in_quotes(path) + " declares ElementSpacing " + fields["ElementSpacing"] +
                                      "; spacing must be positive");
      }
    }
  }
  const std::string data_file = fields["ElementDataFile"];
  // One data file only: a file list ("LIST", or a printf pattern with a range) goes through MetaIO code that
  // overflows a buffer on a crafted header (found by fuzzing), and no study needs it.
  const bool printable = std::all_of(data_file.begin(), data_file.end(),
                                     [](char c) { return static_cast<unsigned char>(c) >= 0x20 && c != 0x7f; });
  if (data_file.empty() || data_file == "LIST" || data_file.find('%') != std::string::npos ||
      data_file.find(' ') != std::string::npos || !printable) {
    return invalid_argument_error(in_quotes(path) + " names its voxel data as a list of files or an unusual name (" +
                                  "ElementDataFile); posewarp reads MetaImage with its data inline (LOCAL, .mha) or " +
                                  "in one file beside the header (.mhd + .raw/.zraw)");
  }
  int64_t available = 0;
  std::error_code ec;
  if (data_file == "LOCAL") {
    available = static_cast<int64_t>(fs::file_size(path, ec)) - static_cast<int64_t>(data_offset);
  } else {
    const fs::path data_path = fs::path(path).parent_path() / data_file;
    if (!fs::exists(data_path, ec)) {
      return not_found_error(in_quotes(path) + " names its data file " + in_quotes(data_path.string()) +
                             ", which does not exist; keep the .mhd and its data file together");
    }
    available = static_cast<int64_t>(fs::file_size(data_path, ec));
  }
  const bool compressed = fields["CompressedData"] == "True" || fields["CompressedData"] == "true";
  if (compressed) {
    // The stream must inflate to every voxel the header promises, checked before anything is allocated: ITK
    // allocates the whole grid first and only prints "Uncompress failed" when the data runs out.
    const int64_t promised = voxels * channels * element->second;
    const std::string data_path = data_file == "LOCAL" ? path : (fs::path(path).parent_path() / data_file).string();
    const int64_t inflated =
        inflated_size(data_path, data_file == "LOCAL" ? static_cast<int64_t>(data_offset) : 0, promised);
    if (inflated < 0) {
      return data_loss_error("the compressed data of " + in_quotes(path) +
                             " is corrupt or truncated; copy the file again");
    }
    if (inflated < promised) {
      return data_loss_error("the compressed data of " + in_quotes(path) + " holds " + std::to_string(inflated) +
                             " bytes, but its header promises " + std::to_string(promised) + " (DimSize " +
                             fields["DimSize"] + "); the file is damaged or not what it claims");
    }
  }
  const int64_t needed = compressed && fields.count("CompressedDataSize")
                             ? std::atoll(fields["CompressedDataSize"].c_str())
                             : (compressed ? 0 : voxels * channels * element->second);
  if (available < needed) {
    return data_loss_error(in_quotes(path) + " is truncated: its header promises " + std::to_string(needed) +
                           " bytes of data but " + std::to_string(std::max<int64_t>(available, 0)) +
                           " are there; copy the file again");
  }
  return ok_status();
}

}  // namespace posewarp::io::detail
