// fem_laplacian: row-parallel assembly of the linear-FEM stiffness matrix from a vertex -> tet incidence.
#include "posewarp/weights/fem_laplacian.h"

#include <Eigen/Geometry>

#include <algorithm>
#include <array>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <limits>
#include <new>
#include <utility>
#include <vector>

#include "posewarp/common/parallel.h"

namespace posewarp::weights {
namespace {

// Row `local` of tet t's element matrix V_t G_t^T G_t (mm). With edges e_i = p_i - p_0 and det = e1 . (e2 x e3),
// the barycentric gradients are (e2 x e3, e3 x e1, e1 x e2) / det for corners 1..3 and minus their sum for corner
// 0, and V_t = det / 6, so the entries are (c_a . c_b) / (6 det) with c the unscaled gradients.
std::array<double, 4> element_row(const Eigen::MatrixXd& vertices, const Eigen::MatrixXi& tets, int64_t t, int local) {
  const Eigen::Vector3d p0 = vertices.row(tets(t, 0)).transpose();
  const Eigen::Vector3d e1 = vertices.row(tets(t, 1)).transpose() - p0;
  const Eigen::Vector3d e2 = vertices.row(tets(t, 2)).transpose() - p0;
  const Eigen::Vector3d e3 = vertices.row(tets(t, 3)).transpose() - p0;
  std::array<Eigen::Vector3d, 4> c;
  c[1] = e2.cross(e3);
  c[2] = e3.cross(e1);
  c[3] = e1.cross(e2);
  c[0] = -(c[1] + c[2] + c[3]);
  const double det = e1.dot(c[1]);
  const double scale = 1.0 / (6.0 * det);
  std::array<double, 4> row{};
  for (int b = 0; b < 4; ++b) row[b] = scale * c[local].dot(c[b]);
  return row;
}

bool tet_is_usable(const Eigen::MatrixXd& vertices, const Eigen::MatrixXi& tets, int64_t t) {
  const int64_t n = vertices.rows();
  for (int a = 0; a < 4; ++a) {
    if (tets(t, a) < 0 || tets(t, a) >= n) return false;
  }
  const Eigen::Vector3d p0 = vertices.row(tets(t, 0)).transpose();
  const Eigen::Vector3d e1 = vertices.row(tets(t, 1)).transpose() - p0;
  const Eigen::Vector3d e2 = vertices.row(tets(t, 2)).transpose() - p0;
  const Eigen::Vector3d e3 = vertices.row(tets(t, 3)).transpose() - p0;
  const double det = e1.dot(e2.cross(e3));
  return std::isfinite(det) && det > 0.0;
}

}  // namespace

Eigen::SparseMatrix<double> fem_laplacian(const TetMesh& mesh) {
  const Eigen::MatrixXd& vertices = mesh.vertices;
  const Eigen::MatrixXi& tets = mesh.tets;
  const int64_t vertex_count = vertices.rows();
  const int64_t tet_count = tets.rows();
  Eigen::SparseMatrix<double> stiffness(vertex_count, vertex_count);
  if (vertex_count == 0 || vertices.cols() != 3 || tets.cols() != 4) return stiffness;

  // Vertex -> incident usable tets, as (tet, local corner) in tet order, so every row sums in a fixed order.
  std::vector<uint8_t> usable(static_cast<size_t>(tet_count), 0);
  parallel_for(0, tet_count, 4096, [&](int64_t begin, int64_t end) {
    for (int64_t t = begin; t < end; ++t) usable[t] = tet_is_usable(vertices, tets, t) ? 1 : 0;
  });
  std::vector<int64_t> first(static_cast<size_t>(vertex_count) + 1, 0);
  for (int64_t t = 0; t < tet_count; ++t) {
    if (!usable[t]) continue;
    for (int a = 0; a < 4; ++a) ++first[tets(t, a) + 1];
  }
  for (int64_t v = 0; v < vertex_count; ++v) first[v + 1] += first[v];
  std::vector<std::pair<int32_t, int8_t>> incident(static_cast<size_t>(first[vertex_count]));
  {
    std::vector<int64_t> cursor(first.begin(), first.end() - 1);
    for (int64_t t = 0; t < tet_count; ++t) {
      if (!usable[t]) continue;
      for (int a = 0; a < 4; ++a) incident[cursor[tets(t, a)]++] = {static_cast<int32_t>(t), static_cast<int8_t>(a)};
    }
  }
  std::vector<uint8_t>().swap(usable);

  // K is symmetric, so row v assembled in sorted column order is also column v of the column-major result.
  // Pass 1 counts the distinct neighbours of each vertex (itself included), pass 2 fills the values.
  std::atomic<bool> out_of_memory{false};
  std::vector<int64_t> row_size(static_cast<size_t>(vertex_count), 0);
  parallel_for(0, vertex_count, 1024, [&](int64_t begin, int64_t end) {
    try {
      std::vector<int32_t> neighbours;
      for (int64_t v = begin; v < end; ++v) {
        neighbours.clear();
        for (int64_t k = first[v]; k < first[v + 1]; ++k) {
          for (int b = 0; b < 4; ++b) neighbours.push_back(tets(incident[k].first, b));
        }
        std::sort(neighbours.begin(), neighbours.end());
        row_size[v] = std::unique(neighbours.begin(), neighbours.end()) - neighbours.begin();
      }
    } catch (const std::bad_alloc&) {
      out_of_memory = true;
    }
  });
  if (out_of_memory) throw std::bad_alloc();

  int64_t nonzeros = 0;
  for (int64_t v = 0; v < vertex_count; ++v) nonzeros += row_size[v];
  // Eigen's default StorageIndex is int (and CHOLMOD's int interface needs it so); larger meshes cannot be held.
  if (nonzeros > std::numeric_limits<int>::max()) throw std::bad_alloc();
  stiffness.resizeNonZeros(static_cast<Eigen::Index>(nonzeros));
  int* outer = stiffness.outerIndexPtr();
  int* inner = stiffness.innerIndexPtr();
  double* values = stiffness.valuePtr();
  outer[0] = 0;
  for (int64_t v = 0; v < vertex_count; ++v) outer[v + 1] = static_cast<int>(outer[v] + row_size[v]);
  std::vector<int64_t>().swap(row_size);

  parallel_for(0, vertex_count, 1024, [&](int64_t begin, int64_t end) {
    try {
      std::vector<std::pair<int32_t, double>> entries;
      for (int64_t v = begin; v < end; ++v) {
        entries.clear();
        for (int64_t k = first[v]; k < first[v + 1]; ++k) {
          const auto [t, local] = incident[k];
          const std::array<double, 4> row = element_row(vertices, tets, t, local);
          for (int b = 0; b < 4; ++b) entries.emplace_back(tets(t, b), row[b]);
        }
        // Stable, so equal columns are summed in tet order whatever the sort's internals.
        std::stable_sort(entries.begin(), entries.end(),
                         [](const auto& x, const auto& y) { return x.first < y.first; });
        int64_t out = outer[v] - 1;
        int32_t last_column = -1;
        for (const auto& [column, value] : entries) {
          if (column != last_column) {
            ++out;
            inner[out] = column;
            values[out] = 0.0;
            last_column = column;
          }
          values[out] += value;
        }
      }
    } catch (const std::bad_alloc&) {
      out_of_memory = true;
    }
  });
  if (out_of_memory) throw std::bad_alloc();
  return stiffness;
}

}  // namespace posewarp::weights
