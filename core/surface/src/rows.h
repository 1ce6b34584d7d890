// Row-major lists of numbers, as the mesh file readers collect them, into a SurfaceMesh's matrices. Private to
// core/surface.
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <vector>

namespace posewarp::surface::detail {

// #V x 3 vertices from x, y, z of each vertex in turn.
inline Eigen::MatrixXd vertex_rows(const std::vector<double>& xyz) {
  const auto count = static_cast<Eigen::Index>(xyz.size() / 3);
  return Eigen::Map<const Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>>(xyz.data(), count, 3);
}

}  // namespace posewarp::surface::detail
