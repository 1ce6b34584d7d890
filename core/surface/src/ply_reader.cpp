// parse_ply: a PLY header, then its body walked element by element with every read bounds-checked.
#include "ply_reader.h"

#include <cctype>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <sstream>
#include <vector>

#include "rows.h"

namespace posewarp::surface::detail {
namespace {

// A PLY scalar type: char, uchar, short, ushort, int, uint, float, double (or int8 ... float64).
struct ScalarType {
  int size = 0;  // bytes; 0 for an unknown type
  bool is_float = false;
  bool is_signed = false;
};

ScalarType scalar_type(const std::string& name) {
  if (name == "char" || name == "int8") return {1, false, true};
  if (name == "uchar" || name == "uint8") return {1, false, false};
  if (name == "short" || name == "int16") return {2, false, true};
  if (name == "ushort" || name == "uint16") return {2, false, false};
  if (name == "int" || name == "int32") return {4, false, true};
  if (name == "uint" || name == "uint32") return {4, false, false};
  if (name == "float" || name == "float32") return {4, true, true};
  if (name == "double" || name == "float64") return {8, true, true};
  return {};
}

// What a property is for in a surface.
enum class Role { kSkip, kX, kY, kZ, kFaceIndices };

struct Property {
  std::string name;
  bool is_list = false;
  ScalarType count;  // a list's length
  ScalarType item;   // the scalar, or each list item
  Role role = Role::kSkip;
};

struct Element {
  std::string name;
  int64_t count = 0;
  std::vector<Property> properties;
};

// Reads the body's values one at a time, ASCII or binary; every read says whether the value was there.
class BodyReader {
 public:
  BodyReader(const std::string& bytes, size_t start, bool ascii, bool big_endian)
      : bytes_(bytes), at_(start), ascii_(ascii), big_endian_(big_endian) {}

  bool read(const ScalarType& type, double* value) {
    if (ascii_) return read_word(value);
    const size_t size = static_cast<size_t>(type.size);
    if (bytes_.size() - at_ < size) return false;
    unsigned char little[8];  // the bytes in little-endian order
    for (size_t i = 0; i < size; ++i) {
      little[i] = static_cast<unsigned char>(bytes_[at_ + (big_endian_ ? size - 1 - i : i)]);
    }
    at_ += size;
    if (type.is_float) {
      const uint16_t probe = 1;
      const bool host_little = *reinterpret_cast<const unsigned char*>(&probe) == 1;
      unsigned char host[8];
      for (size_t i = 0; i < size; ++i) host[i] = little[host_little ? i : size - 1 - i];
      if (size == 4) {
        float f;
        std::memcpy(&f, host, 4);
        *value = f;
      } else {
        double d;
        std::memcpy(&d, host, 8);
        *value = d;
      }
      return true;
    }
    uint64_t u = 0;
    for (size_t i = 0; i < size; ++i) u |= static_cast<uint64_t>(little[i]) << (8 * i);
    if (type.is_signed && ((u >> (8 * size - 1)) & 1u)) {
      *value = static_cast<double>(static_cast<int64_t>(u | (~uint64_t{0} << (8 * size))));
    } else {
      *value = static_cast<double>(u);
    }
    return true;
  }

  // Skips `count` values of one type (binary only; ASCII reads them).
  bool skip(const ScalarType& type, int64_t count) {
    if (ascii_) {
      double ignored;
      for (int64_t i = 0; i < count; ++i) {
        if (!read_word(&ignored)) return false;
      }
      return true;
    }
    const uint64_t size = static_cast<uint64_t>(type.size);
    if (static_cast<uint64_t>(count) > (bytes_.size() - at_) / size) return false;
    at_ += static_cast<size_t>(static_cast<uint64_t>(count) * size);
    return true;
  }

 private:
  bool read_word(double* value) {
    while (at_ < bytes_.size() && std::isspace(static_cast<unsigned char>(bytes_[at_]))) ++at_;
    const size_t start = at_;
    while (at_ < bytes_.size() && !std::isspace(static_cast<unsigned char>(bytes_[at_]))) ++at_;
    if (at_ == start) return false;
    const std::string word = bytes_.substr(start, at_ - start);
    char* end = nullptr;
    *value = std::strtod(word.c_str(), &end);
    return end == word.c_str() + word.size();
  }

  const std::string& bytes_;
  size_t at_;
  bool ascii_;
  bool big_endian_;
};

constexpr char kTruncated[] = "the file is shorter than its header promises (truncated?)";

// The header's format and elements, with the counts of the vertex and face elements once checked.
struct PlyHeader {
  std::string format;
  std::vector<Element> elements;
  int64_t vertex_count = 0;
  int64_t face_count = 0;
};

// What the body walk reads: vertex coordinates and the triangles fanned from each face.
struct PlyBody {
  std::vector<double> vertices;  // #V x 3, row-major
  std::vector<int> triangles;    // #T x 3, row-major
};

// Reads a property line's words after "property" into p, with its role in a surface; false for an unknown type.
bool parse_property(std::istringstream& words, const std::string& element_name, Property& p) {
  std::string type;
  words >> type;
  if (type == "list") {
    std::string count_type, item_type;
    words >> count_type >> item_type >> p.name;
    p.is_list = true;
    p.count = scalar_type(count_type);
    p.item = scalar_type(item_type);
    if (p.count.size == 0 || p.item.size == 0) return false;
    if (element_name == "face" && (p.name == "vertex_indices" || p.name == "vertex_index")) p.role = Role::kFaceIndices;
    return true;
  }
  words >> p.name;
  p.item = scalar_type(type);
  if (p.item.size == 0) return false;
  if (element_name == "vertex") {
    p.role = p.name == "x" ? Role::kX : p.name == "y" ? Role::kY : p.name == "z" ? Role::kZ : Role::kSkip;
  }
  return true;
}

// The format and elements declared by the header text (everything before "end_header").
Result<PlyHeader> parse_header(const std::string& text, const std::string& where) {
  std::istringstream header(text);
  std::string line;
  PlyHeader parsed;
  while (std::getline(header, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream words(line);
    std::string keyword;
    words >> keyword;
    if (keyword == "format") {
      words >> parsed.format;
    } else if (keyword == "element") {
      Element e;
      words >> e.name >> e.count;
      if (!words || e.count < 0) return invalid_argument_error(where + "bad element line '" + line + "'");
      parsed.elements.push_back(e);
    } else if (keyword == "property") {
      if (parsed.elements.empty()) return invalid_argument_error(where + "a property comes before any element");
      Element& e = parsed.elements.back();
      Property p;
      if (!parse_property(words, e.name, p)) return invalid_argument_error(where + "bad property '" + line + "'");
      e.properties.push_back(p);
    }
  }
  return parsed;
}

// Checks the format and the vertex and face elements against a file of file_size bytes; records their counts.
Status check_header(PlyHeader& header, size_t file_size, const std::string& where) {
  const std::string& format = header.format;
  if (format != "ascii" && format != "binary_little_endian" && format != "binary_big_endian") {
    return invalid_argument_error(where + "unknown format '" + format + "'");
  }
  for (const Element& e : header.elements) {
    if (e.name == "vertex") {
      int roles = 0;
      for (const Property& p : e.properties) roles += p.role == Role::kX || p.role == Role::kY || p.role == Role::kZ;
      if (roles != 3) return invalid_argument_error(where + "its vertices lack x, y and z");
      header.vertex_count = e.count;
    }
    if (e.name == "face") header.face_count = e.count;
  }
  if (header.vertex_count == 0) return invalid_argument_error(where + "it holds no vertices");
  if (header.face_count == 0) return invalid_argument_error(where + "it holds vertices but no faces (a point cloud?)");
  // Every value takes at least one byte, so counts larger than the file are lies that must not size allocations.
  if (static_cast<uint64_t>(header.vertex_count) > file_size || static_cast<uint64_t>(header.face_count) > file_size) {
    return invalid_argument_error(where + "its header declares more elements than the file can hold (truncated?)");
  }
  return ok_status();
}

// Reads one list property: a face's vertex indices into corners (checked against vertex_count); skips other lists.
Status read_list(BodyReader& reader, const Property& p, int64_t vertex_count, const std::string& where,
                 std::vector<int64_t>& corners) {
  double length = 0.0;
  if (!reader.read(p.count, &length)) return invalid_argument_error(where + kTruncated);
  if (!(length >= 0 && length <= 1e6) || length != std::floor(length)) {
    return invalid_argument_error(where + "a list has a bad length");
  }
  const int64_t items = static_cast<int64_t>(length);
  if (p.role != Role::kFaceIndices) {
    if (!reader.skip(p.item, items)) return invalid_argument_error(where + kTruncated);
    return ok_status();
  }
  corners.clear();
  for (int64_t i = 0; i < items; ++i) {
    double index = 0.0;
    if (!reader.read(p.item, &index)) return invalid_argument_error(where + kTruncated);
    if (!(index >= 0 && index < static_cast<double>(vertex_count)) || index != std::floor(index)) {
      return invalid_argument_error(where + "a face refers to a vertex the file does not have");
    }
    corners.push_back(static_cast<int64_t>(index));
  }
  return ok_status();
}

// Walks the body that starts at bytes[start], element by element, keeping vertices and fanning faces.
Result<PlyBody> read_body(const std::string& bytes, size_t start, const PlyHeader& header, const std::string& where) {
  BodyReader reader(bytes, start, header.format == "ascii", header.format == "binary_big_endian");
  PlyBody body;
  body.vertices.reserve(static_cast<size_t>(3 * header.vertex_count));
  std::vector<int64_t> corners;
  for (const Element& e : header.elements) {
    for (int64_t n = 0; n < e.count; ++n) {
      double xyz[3] = {0.0, 0.0, 0.0};
      for (const Property& p : e.properties) {
        if (!p.is_list) {
          double value = 0.0;
          if (!reader.read(p.item, &value)) return invalid_argument_error(where + kTruncated);
          if (p.role == Role::kX) xyz[0] = value;
          if (p.role == Role::kY) xyz[1] = value;
          if (p.role == Role::kZ) xyz[2] = value;
          continue;
        }
        POSEWARP_RETURN_IF_ERROR(read_list(reader, p, header.vertex_count, where, corners));
        if (p.role != Role::kFaceIndices) continue;
        for (size_t c = 1; c + 1 < corners.size(); ++c) {
          body.triangles.insert(body.triangles.end(), {static_cast<int>(corners[0]), static_cast<int>(corners[c]),
                                                       static_cast<int>(corners[c + 1])});
        }
      }
      if (e.name == "vertex") {
        if (!std::isfinite(xyz[0]) || !std::isfinite(xyz[1]) || !std::isfinite(xyz[2])) {
          return invalid_argument_error(where + "vertex " + std::to_string(n) + " is not finite");
        }
        body.vertices.insert(body.vertices.end(), xyz, xyz + 3);
      }
    }
  }
  return body;
}

// The surface mesh of the vertices and triangles read.
SurfaceMesh to_surface_mesh(const PlyBody& body) {
  SurfaceMesh mesh;
  mesh.vertices = vertex_rows(body.vertices);
  const int64_t triangle_count = static_cast<int64_t>(body.triangles.size() / 3);
  mesh.triangles.resize(triangle_count, 3);
  for (int64_t f = 0; f < triangle_count; ++f) {
    for (int c = 0; c < 3; ++c) mesh.triangles(f, c) = body.triangles[static_cast<size_t>(3 * f + c)];
  }
  return mesh;
}

}  // namespace

Result<SurfaceMesh> parse_ply(const std::string& bytes, const std::string& path) {
  const std::string where = "cannot read '" + path + "' as PLY: ";
  const size_t header_end = bytes.find("end_header");
  if (bytes.compare(0, 3, "ply") != 0 || header_end == std::string::npos) {
    return invalid_argument_error(where + "it does not start with a complete PLY header");
  }
  size_t body_start = bytes.find('\n', header_end);
  body_start = body_start == std::string::npos ? bytes.size() : body_start + 1;

  POSEWARP_ASSIGN_OR_RETURN(PlyHeader header, parse_header(bytes.substr(0, header_end), where));
  POSEWARP_RETURN_IF_ERROR(check_header(header, bytes.size(), where));
  POSEWARP_ASSIGN_OR_RETURN(const PlyBody body, read_body(bytes, body_start, header, where));
  if (body.triangles.empty()) return invalid_argument_error(where + "its faces hold no triangles");
  return to_surface_mesh(body);
}

}  // namespace posewarp::surface::detail
