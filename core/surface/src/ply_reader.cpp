// parse_ply: a PLY header, then its body walked element by element with every read bounds-checked.
#include "ply_reader.h"

#include <cctype>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <sstream>
#include <vector>

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

}  // namespace

Result<SurfaceMesh> parse_ply(const std::string& bytes, const std::string& path) {
  const std::string where = "cannot read '" + path + "' as PLY: ";
  const size_t header_end = bytes.find("end_header");
  if (bytes.compare(0, 3, "ply") != 0 || header_end == std::string::npos) {
    return invalid_argument_error(where + "it does not start with a complete PLY header");
  }
  size_t body = bytes.find('\n', header_end);
  body = body == std::string::npos ? bytes.size() : body + 1;

  std::istringstream header(bytes.substr(0, header_end));
  std::string line, format;
  std::vector<Element> elements;
  while (std::getline(header, line)) {
    if (!line.empty() && line.back() == '\r') line.pop_back();
    std::istringstream words(line);
    std::string keyword;
    words >> keyword;
    if (keyword == "format") {
      words >> format;
    } else if (keyword == "element") {
      Element e;
      words >> e.name >> e.count;
      if (!words || e.count < 0) return invalid_argument_error(where + "bad element line '" + line + "'");
      elements.push_back(e);
    } else if (keyword == "property") {
      if (elements.empty()) return invalid_argument_error(where + "a property comes before any element");
      Element& e = elements.back();
      Property p;
      std::string type;
      words >> type;
      if (type == "list") {
        std::string count_type, item_type;
        words >> count_type >> item_type >> p.name;
        p.is_list = true;
        p.count = scalar_type(count_type);
        p.item = scalar_type(item_type);
        if (p.count.size == 0 || p.item.size == 0) return invalid_argument_error(where + "bad property '" + line + "'");
        if (e.name == "face" && (p.name == "vertex_indices" || p.name == "vertex_index")) p.role = Role::kFaceIndices;
      } else {
        words >> p.name;
        p.item = scalar_type(type);
        if (p.item.size == 0) return invalid_argument_error(where + "bad property '" + line + "'");
        if (e.name == "vertex") {
          p.role = p.name == "x" ? Role::kX : p.name == "y" ? Role::kY : p.name == "z" ? Role::kZ : Role::kSkip;
        }
      }
      e.properties.push_back(p);
    }
  }
  if (format != "ascii" && format != "binary_little_endian" && format != "binary_big_endian") {
    return invalid_argument_error(where + "unknown format '" + format + "'");
  }
  int64_t vertex_count = 0, face_count = 0;
  for (const Element& e : elements) {
    if (e.name == "vertex") {
      int roles = 0;
      for (const Property& p : e.properties) roles += p.role == Role::kX || p.role == Role::kY || p.role == Role::kZ;
      if (roles != 3) return invalid_argument_error(where + "its vertices lack x, y and z");
      vertex_count = e.count;
    }
    if (e.name == "face") face_count = e.count;
  }
  if (vertex_count == 0) return invalid_argument_error(where + "it holds no vertices");
  if (face_count == 0) return invalid_argument_error(where + "it holds vertices but no faces (a point cloud?)");
  // Every value takes at least one byte, so counts larger than the file are lies that must not size allocations.
  if (static_cast<uint64_t>(vertex_count) > bytes.size() || static_cast<uint64_t>(face_count) > bytes.size()) {
    return invalid_argument_error(where + "its header declares more elements than the file can hold (truncated?)");
  }

  const std::string truncated = "the file is shorter than its header promises (truncated?)";
  BodyReader reader(bytes, body, format == "ascii", format == "binary_big_endian");
  std::vector<double> vertices;
  vertices.reserve(static_cast<size_t>(3 * vertex_count));
  std::vector<int> triangles;
  std::vector<int64_t> corners;
  for (const Element& e : elements) {
    for (int64_t n = 0; n < e.count; ++n) {
      double xyz[3] = {0.0, 0.0, 0.0};
      for (const Property& p : e.properties) {
        if (!p.is_list) {
          double value = 0.0;
          if (!reader.read(p.item, &value)) return invalid_argument_error(where + truncated);
          if (p.role == Role::kX) xyz[0] = value;
          if (p.role == Role::kY) xyz[1] = value;
          if (p.role == Role::kZ) xyz[2] = value;
          continue;
        }
        double length = 0.0;
        if (!reader.read(p.count, &length)) return invalid_argument_error(where + truncated);
        if (!(length >= 0 && length <= 1e6) || length != std::floor(length)) {
          return invalid_argument_error(where + "a list has a bad length");
        }
        const int64_t items = static_cast<int64_t>(length);
        if (p.role != Role::kFaceIndices) {
          if (!reader.skip(p.item, items)) return invalid_argument_error(where + truncated);
          continue;
        }
        corners.clear();
        for (int64_t i = 0; i < items; ++i) {
          double index = 0.0;
          if (!reader.read(p.item, &index)) return invalid_argument_error(where + truncated);
          if (!(index >= 0 && index < static_cast<double>(vertex_count)) || index != std::floor(index)) {
            return invalid_argument_error(where + "a face refers to a vertex the file does not have");
          }
          corners.push_back(static_cast<int64_t>(index));
        }
        for (size_t c = 1; c + 1 < corners.size(); ++c) {
          triangles.insert(triangles.end(), {static_cast<int>(corners[0]), static_cast<int>(corners[c]),
                                             static_cast<int>(corners[c + 1])});
        }
      }
      if (e.name == "vertex") {
        if (!std::isfinite(xyz[0]) || !std::isfinite(xyz[1]) || !std::isfinite(xyz[2])) {
          return invalid_argument_error(where + "vertex " + std::to_string(n) + " is not finite");
        }
        vertices.insert(vertices.end(), xyz, xyz + 3);
      }
    }
  }
  if (triangles.empty()) return invalid_argument_error(where + "its faces hold no triangles");
  SurfaceMesh mesh;
  mesh.vertices.resize(vertex_count, 3);
  for (int64_t v = 0; v < vertex_count; ++v) {
    for (int a = 0; a < 3; ++a) mesh.vertices(v, a) = vertices[static_cast<size_t>(3 * v + a)];
  }
  const int64_t triangle_count = static_cast<int64_t>(triangles.size() / 3);
  mesh.triangles.resize(triangle_count, 3);
  for (int64_t f = 0; f < triangle_count; ++f) {
    for (int c = 0; c < 3; ++c) mesh.triangles(f, c) = triangles[static_cast<size_t>(3 * f + c)];
  }
  return mesh;
}

}  // namespace posewarp::surface::detail
