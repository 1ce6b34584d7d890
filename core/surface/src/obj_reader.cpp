// parse_obj: the subset of Wavefront OBJ that carries a triangle surface.
#include "obj_reader.h"

#include <charconv>
#include <cmath>
#include <cstdint>
#include <string_view>
#include <vector>

#include "rows.h"

namespace posewarp::surface::detail {
namespace {

bool is_space(char c) {
  return c == ' ' || c == '\t' || c == '\r' || c == '\v' || c == '\f';
}

// Splits a line into whitespace-separated words.
std::vector<std::string_view> words_of(std::string_view line) {
  std::vector<std::string_view> words;
  size_t at = 0;
  while (at < line.size()) {
    while (at < line.size() && is_space(line[at])) ++at;
    const size_t start = at;
    while (at < line.size() && !is_space(line[at])) ++at;
    if (at > start) words.push_back(line.substr(start, at - start));
  }
  return words;
}

bool parse_double(std::string_view word, double* value) {
  // std::from_chars for double is in libstdc++ 11+, which Debian 12 has.
  const auto [end, error] = std::from_chars(word.data(), word.data() + word.size(), *value);
  return error == std::errc() && end == word.data() + word.size() && std::isfinite(*value);
}

}  // namespace

Result<SurfaceMesh> parse_obj(const std::string& text, const std::string& path) {
  const std::string where = "cannot read '" + path + "' as OBJ: ";
  if (text.find('\0') != std::string::npos) {
    return invalid_argument_error(where + "it holds binary data, not OBJ text (corrupt or not that format)");
  }
  std::vector<double> vertices;         // 3 per vertex
  std::vector<int64_t> triangles;       // 3 per triangle, 0-based, checked at the end
  std::vector<int64_t> triangle_lines;  // the line each triangle came from, for the message
  size_t line_start = 0;
  int64_t line_number = 0;
  std::vector<int64_t> corners;
  while (line_start < text.size()) {
    size_t line_end = text.find('\n', line_start);
    if (line_end == std::string::npos) line_end = text.size();
    std::string_view line(text.data() + line_start, line_end - line_start);
    line_start = line_end + 1;
    ++line_number;
    if (const size_t hash = line.find('#'); hash != std::string_view::npos) line = line.substr(0, hash);
    const std::vector<std::string_view> words = words_of(line);
    if (words.empty()) continue;
    const std::string at_line = " (line " + std::to_string(line_number) + ")";
    if (words[0] == "v") {
      double xyz[3];
      if (words.size() < 4 || !parse_double(words[1], &xyz[0]) || !parse_double(words[2], &xyz[1]) ||
          !parse_double(words[3], &xyz[2])) {
        return invalid_argument_error(where + "a vertex needs three finite numbers" + at_line);
      }
      vertices.insert(vertices.end(), xyz, xyz + 3);
    } else if (words[0] == "f") {
      corners.clear();
      for (size_t w = 1; w < words.size(); ++w) {
        // Only the vertex index matters: the part before the first '/'.
        const std::string_view corner = words[w].substr(0, words[w].find('/'));
        int64_t index = 0;
        const auto [end, error] = std::from_chars(corner.data(), corner.data() + corner.size(), index);
        if (error != std::errc() || end != corner.data() + corner.size() || index == 0) {
          return invalid_argument_error(where + "bad face corner '" + std::string(words[w]) + "'" + at_line);
        }
        // Negative indices count back from the latest vertex.
        corners.push_back(index > 0 ? index - 1 : static_cast<int64_t>(vertices.size() / 3) + index);
      }
      if (corners.size() < 3) return invalid_argument_error(where + "a face needs three corners" + at_line);
      for (size_t c = 1; c + 1 < corners.size(); ++c) {
        triangles.insert(triangles.end(), {corners[0], corners[c], corners[c + 1]});
        triangle_lines.push_back(line_number);
      }
    }
  }
  const int64_t vertex_count = static_cast<int64_t>(vertices.size() / 3);
  if (vertex_count == 0) return invalid_argument_error(where + "it holds no vertices (corrupt or not that format)");
  if (triangles.empty()) {
    return invalid_argument_error(where + "it holds vertices but no faces (a point cloud or lines?)");
  }
  if (vertex_count > INT32_MAX) return invalid_argument_error(where + "too many vertices");
  SurfaceMesh mesh;
  mesh.vertices = vertex_rows(vertices);
  const int64_t triangle_count = static_cast<int64_t>(triangles.size() / 3);
  mesh.triangles.resize(triangle_count, 3);
  for (int64_t f = 0; f < triangle_count; ++f) {
    for (int c = 0; c < 3; ++c) {
      const int64_t index = triangles[static_cast<size_t>(3 * f + c)];
      if (index < 0 || index >= vertex_count) {
        return invalid_argument_error(where + "a face names vertex " + std::to_string(index + 1) + " of " +
                                      std::to_string(vertex_count) + " (line " +
                                      std::to_string(triangle_lines[static_cast<size_t>(f)]) + ")");
      }
      mesh.triangles(f, c) = static_cast<int>(index);
    }
  }
  return mesh;
}

}  // namespace posewarp::surface::detail
