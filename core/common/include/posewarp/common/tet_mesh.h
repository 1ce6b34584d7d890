// TetMesh and SkinWeights: the plain-array shapes every rig stage passes along (libigl style).
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <vector>

namespace posewarp {

// Mesher classes: 0 outside the body, 1 soft tissue, 2 + k bone segment k.
constexpr int kOutsideClass = 0;
constexpr int kSoftTissueClass = 1;
constexpr int kFirstBoneClass = 2;

// A tetrahedral mesh of the body in physical space.
struct TetMesh {
  Eigen::MatrixXd vertices;   // #V x 3, LPS mm
  Eigen::MatrixXi tets;       // #T x 4 vertex indices, positively oriented (det[v1-v0, v2-v0, v3-v0] > 0)
  Eigen::VectorXi tet_class;  // #T, 1 soft tissue or 2 + k for bone segment k
  int segment_count = 0;      // bone segments k = 0 .. segment_count - 1

  int64_t vertex_count() const { return vertices.rows(); }
  int64_t tet_count() const { return tets.rows(); }
};

// Sparse skinning weights: at most `influences` bone segments per vertex, largest first, summing to 1.
struct SkinWeights {
  int influences = 0;  // columns of the two arrays
  int segment_count = 0;
  // #V x influences segment indices; -1 marks an unused slot (its weight is 0).
  Eigen::Matrix<int32_t, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> segment;
  // #V x influences weights in [0, 1], descending along each row.
  Eigen::Matrix<float, Eigen::Dynamic, Eigen::Dynamic, Eigen::RowMajor> weight;

  int64_t vertex_count() const { return segment.rows(); }
};

// Centres of rotation per vertex (Le & Hodgins 2016, Sujar et al. 2018 eq. 6-7).
struct RotationCentres {
  Eigen::MatrixXd centre;      // #V x 3, LPS mm; for rigid vertices, the vertex itself
  std::vector<uint8_t> rigid;  // #V, 1 where one segment dominates and no centre is needed
};

// Barycentric embedding of points in the rest mesh.
struct Embedding {
  Eigen::VectorXi tet;                   // #P, the containing (or nearest) rest tet
  Eigen::MatrixXd barycentric;           // #P x 4, weights of that tet's vertices (extrapolated outside the mesh)
  std::vector<uint8_t> inside;           // #P, 1 where the point lies in its tet
  int64_t outside_count = 0;             // points outside the mesh, placed by their nearest tet
  double max_outside_distance_mm = 0.0;  // the farthest of them from its tet
};

}  // namespace posewarp
