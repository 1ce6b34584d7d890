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
#include <vector>

#include "posewarp/common/parallel.h"

namespace posewarp::weights {
namespace {

using Corners = std::array<int32_t, 4>;

// Row `local` of a tet's element matrix V_t G_t^T G_t (mm). With edges e_i = p_i - p_0 and det = e1 . (e2 x e3),
// the barycentric gradients are (e2 x e3, e3 x e1, e1 x e2) / det for corners 1..3 and minus their sum for corner
// 0, and V_t = det / 6, so the entries are (c_a . c_b) / (6 det) with c the unscaled gradients.
std::array<double, 4> element_row(const std::vector<Eigen::Vector3d>& points, const Corners& tet, int local) {
  const Eigen::Vector3d& p0 = points[tet[0]];
  const Eigen::Vector3d e1 = points[tet[1]] - p0;
  const Eigen::Vector3d e2 = points[tet[2]] - p0;
  const Eigen::Vector3d e3 = points[tet[3]] - p0;
  std::array<Eigen::Vector3d, 4> c;
  c[1] = e2.cross(e3);
  c[2] = e3.cross(e1);
  c[3] = e1.cross(e2);
  c[0] = -(c[1] + c[2] + c[3]);
  const double scale = 1.0 / (6.0 * e1.dot(c[1]));
  std::array<double, 4> row{};
  for (int b = 0; b < 4; ++b) row[b] = scale * c[local].dot(c[b]);
  return row;
}

// Chunks of rows large enough that each worker's vertex-sized scratch arrays are set up only a few times.
int64_t row_grain(int64_t vertex_count) {
  return std::max<int64_t>(4096, vertex_count / 16);
}

}  // namespace

Eigen::SparseMatrix<double> fem_laplacian(const TetMesh& mesh) {
  const int64_t vertex_count = mesh.vertices.rows();
  const int64_t tet_count = mesh.tets.rows();
  Eigen::SparseMatrix<double> stiffness(vertex_count, vertex_count);
  if (vertex_count == 0 || mesh.vertices.cols() != 3 || mesh.tets.cols() != 4) return stiffness;
  if (vertex_count > std::numeric_limits<int32_t>::max() || tet_count >= (int64_t{1} << 29)) throw std::bad_alloc();

  // Row-major copies: a tet's corners and a vertex's coordinates each in one cache line, not spread over the
  // column-major Eigen arrays. Unusable tets (bad index, non-positive or non-finite volume) get corner -1.
  std::vector<Eigen::Vector3d> points(static_cast<size_t>(vertex_count));
  parallel_for(0, vertex_count, 16384, [&](int64_t begin, int64_t end) {
    for (int64_t v = begin; v < end; ++v) points[v] = mesh.vertices.row(v).transpose();
  });
  std::vector<Corners> corners(static_cast<size_t>(tet_count));
  parallel_for(0, tet_count, 16384, [&](int64_t begin, int64_t end) {
    for (int64_t t = begin; t < end; ++t) {
      Corners& tet = corners[t];
      bool usable = true;
      for (int a = 0; a < 4; ++a) {
        tet[a] = mesh.tets(t, a);
        usable = usable && tet[a] >= 0 && tet[a] < vertex_count;
      }
      if (usable) {
        const Eigen::Vector3d e1 = points[tet[1]] - points[tet[0]];
        const double det = e1.dot((points[tet[2]] - points[tet[0]]).cross(points[tet[3]] - points[tet[0]]));
        usable = std::isfinite(det) && det > 0.0;
      }
      if (!usable) tet[0] = -1;
    }
  });

  // Vertex -> incident usable tets, packed as 4 * tet + local corner, in tet order so every row sums in a fixed
  // order whatever the thread count.
  std::vector<int64_t> first(static_cast<size_t>(vertex_count) + 1, 0);
  for (const Corners& tet : corners) {
    if (tet[0] < 0) continue;
    for (int a = 0; a < 4; ++a) ++first[tet[a] + 1];
  }
  for (int64_t v = 0; v < vertex_count; ++v) first[v + 1] += first[v];
  std::vector<uint32_t> incident(static_cast<size_t>(first[vertex_count]));
  {
    std::vector<int64_t> cursor(first.begin(), first.end() - 1);
    for (int64_t t = 0; t < tet_count; ++t) {
      if (corners[t][0] < 0) continue;
      for (int a = 0; a < 4; ++a) incident[cursor[corners[t][a]]++] = static_cast<uint32_t>(4 * t + a);
    }
  }

  // K is symmetric, so row v assembled in sorted column order is also column v of the column-major result.
  // Pass 1 counts the distinct neighbours of each vertex (itself included), pass 2 fills the values. Each chunk
  // keeps a vertex-sized stamp array to recognise neighbours already seen, without sorting.
  std::vector<int32_t> row_size(static_cast<size_t>(vertex_count), 0);
  parallel_for(0, vertex_count, row_grain(vertex_count), [&](int64_t begin, int64_t end) {
    std::vector<int32_t> seen_by(static_cast<size_t>(vertex_count), -1);
    for (int64_t v = begin; v < end; ++v) {
      int32_t size = 0;
      for (int64_t k = first[v]; k < first[v + 1]; ++k) {
        for (const int32_t u : corners[incident[k] / 4]) {
          if (seen_by[u] != v) {
            seen_by[u] = static_cast<int32_t>(v);
            ++size;
          }
        }
      }
      row_size[v] = size;
    }
  });

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
  std::vector<int32_t>().swap(row_size);

  parallel_for(0, vertex_count, row_grain(vertex_count), [&](int64_t begin, int64_t end) {
    std::vector<int32_t> seen_by(static_cast<size_t>(vertex_count), -1);
    std::vector<int32_t> slot(static_cast<size_t>(vertex_count), 0);  // position of column u within the row
    for (int64_t v = begin; v < end; ++v) {
      int* row_columns = inner + outer[v];
      int size = 0;
      for (int64_t k = first[v]; k < first[v + 1]; ++k) {
        for (const int32_t u : corners[incident[k] / 4]) {
          if (seen_by[u] != v) {
            seen_by[u] = static_cast<int32_t>(v);
            row_columns[size++] = u;
          }
        }
      }
      std::sort(row_columns, row_columns + size);
      for (int i = 0; i < size; ++i) slot[row_columns[i]] = i;
      double* row_values = values + outer[v];
      std::fill(row_values, row_values + size, 0.0);
      for (int64_t k = first[v]; k < first[v + 1]; ++k) {
        const Corners& tet = corners[incident[k] / 4];
        const std::array<double, 4> row = element_row(points, tet, static_cast<int>(incident[k] % 4));
        for (int b = 0; b < 4; ++b) row_values[slot[tet[b]]] += row[b];
      }
    }
  });
  return stiffness;
}

}  // namespace posewarp::weights
