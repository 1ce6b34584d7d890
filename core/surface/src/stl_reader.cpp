// STL, binary and ASCII, with coincident vertices merged.
#include "stl_reader.h"

#include <cmath>
#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <array>
#include <map>
#include <sstream>
#include <tuple>
#include <vector>

namespace posewarp::surface::detail {
namespace {

class Merger {
 public:
  int32_t index(float x, float y, float z) {
    const auto [it, fresh] = index_.emplace(std::make_tuple(x, y, z), static_cast<int32_t>(points_.size()));
    if (fresh) points_.push_back({x, y, z});
    return it->second;
  }
  SurfaceMesh mesh(const std::vector<int32_t>& corners) const {
    SurfaceMesh m;
    m.vertices.resize(static_cast<Eigen::Index>(points_.size()), 3);
    for (size_t i = 0; i < points_.size(); ++i) {
      for (int a = 0; a < 3; ++a) m.vertices(static_cast<Eigen::Index>(i), a) = points_[i][static_cast<size_t>(a)];
    }
    m.triangles.resize(static_cast<Eigen::Index>(corners.size() / 3), 3);
    for (size_t c = 0; c < corners.size(); ++c) {
      m.triangles(static_cast<Eigen::Index>(c / 3), static_cast<Eigen::Index>(c % 3)) = corners[c];
    }
    return m;
  }

 private:
  std::map<std::tuple<float, float, float>, int32_t> index_;
  std::vector<std::array<float, 3>> points_;
};

}  // namespace

Result<SurfaceMesh> parse_stl(const std::string& bytes, const std::string& path) {
  const std::string where = "cannot read '" + path + "' as STL: ";
  Merger merger;
  std::vector<int32_t> corners;
  uint32_t declared = 0;
  if (bytes.size() >= 84) std::memcpy(&declared, bytes.data() + 80, 4);
  if (bytes.size() >= 84 && uint64_t{84} + uint64_t{50} * declared == bytes.size()) {
    corners.reserve(size_t{3} * declared);
    for (uint32_t t = 0; t < declared; ++t) {
      const char* facet = bytes.data() + 84 + size_t{50} * t + 12;  // after the normal
      for (int c = 0; c < 3; ++c) {
        float p[3];
        std::memcpy(p, facet + 12 * c, sizeof p);
        if (!std::isfinite(p[0]) || !std::isfinite(p[1]) || !std::isfinite(p[2])) {
          return invalid_argument_error(where + "triangle " + std::to_string(t) + " has a non-finite vertex");
        }
        corners.push_back(merger.index(p[0], p[1], p[2]));
      }
    }
    return merger.mesh(corners);
  }
  const size_t start = bytes.find_first_not_of(" \t\r\n");
  if (start == std::string::npos || bytes.compare(start, 5, "solid") != 0) {
    return invalid_argument_error(where + "it is neither binary STL (84 bytes + 50 per triangle: its header declares " +
                                  std::to_string(declared) + " triangles, which does not match its " +
                                  std::to_string(bytes.size()) + " bytes) nor ASCII STL (starting with 'solid')");
  }
  std::istringstream in(bytes);
  std::string token;
  int64_t line_vertices = 0;
  while (in >> token) {
    if (token != "vertex") continue;
    std::string text[3];
    float p[3];
    for (int a = 0; a < 3; ++a) {
      char* end = nullptr;
      if (!(in >> text[a])) return invalid_argument_error(where + "a vertex has fewer than 3 coordinates");
      p[a] = std::strtof(text[a].c_str(), &end);
      if (end == text[a].c_str() || *end != '\0' || !std::isfinite(p[a])) {
        return invalid_argument_error(where + "vertex " + std::to_string(line_vertices) + " has a coordinate '" +
                                      text[a].substr(0, 40) + "' that is not a finite number");
      }
    }
    corners.push_back(merger.index(p[0], p[1], p[2]));
    ++line_vertices;
  }
  if (corners.size() % 3 != 0) {
    return invalid_argument_error(where + std::to_string(corners.size()) +
                                  " vertices do not make whole triangles (three per facet)");
  }
  return merger.mesh(corners);
}

}  // namespace posewarp::surface::detail
