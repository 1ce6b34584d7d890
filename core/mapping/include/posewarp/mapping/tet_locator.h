// Point location in a tet mesh through a spatial hash (Teschner et al. 2003, "Optimized spatial hashing for
// collision detection of deformable objects"), and the embedding of surface vertices in rest tets
// (Sujar et al. 2018 section 3.4).
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <vector>

#include "posewarp/common/progress.h"
#include "posewarp/common/result.h"
#include "posewarp/common/tet_mesh.h"

namespace posewarp::mapping {

class TetLocator {
 public:
  // cell_mm = 0 picks the mean tet bounding-box edge. The mesh must outlive the locator.
  static Result<TetLocator> build(const TetMesh& mesh, double cell_mm = 0.0);

  struct Location {
    int32_t tet = -1;
    Eigen::Vector4d barycentric = Eigen::Vector4d::Zero();
    bool inside = false;
    double distance_mm = 0.0;  // 0 inside; else the distance from the point to the tet
  };
  // The tet containing p; if none, the nearest tet with its (extrapolated) barycentrics.
  Location locate(const Eigen::Vector3d& p) const;

 private:
  TetLocator() = default;
  int64_t cell_of(int64_t x, int64_t y, int64_t z) const { return x + dims_[0] * (y + dims_[1] * z); }
  bool barycentric(int32_t tet, const Eigen::Vector3d& p, Eigen::Vector4d& b) const;
  double distance(int32_t tet, const Eigen::Vector3d& p) const;

  const TetMesh* mesh_ = nullptr;
  Eigen::Vector3d origin_ = Eigen::Vector3d::Zero();
  double cell_ = 1.0;
  int64_t dims_[3] = {1, 1, 1};
  std::vector<int64_t> start_;    // CSR: tets of cell c are tets_[start_[c] .. start_[c + 1])
  std::vector<int32_t> tets_;
  std::vector<double> inverse_;   // 9 per tet: inverse edge matrix, row-major
};

// Barycentric embedding of points (#P x 3, rest space) in the rest mesh.
struct Embedding {
  Eigen::VectorXi tet;               // #P
  Eigen::MatrixXd barycentric;       // #P x 4
  std::vector<uint8_t> inside;       // #P
  int64_t outside_count = 0;
  double max_outside_distance_mm = 0.0;
};

Result<Embedding> embed_points(const TetMesh& rest, const Eigen::MatrixXd& points, const ProgressHooks& hooks);

// Posed positions sum_i b_i * posed_vertices(tet_i): #P x 3.
Eigen::MatrixXd deform_points(const Embedding& embedding, const TetMesh& rest, const Eigen::MatrixXd& posed_vertices);

}  // namespace posewarp::mapping
