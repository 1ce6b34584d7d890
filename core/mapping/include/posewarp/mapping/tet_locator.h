// Point location in a tet mesh through a spatial hash (Teschner et al. 2003, "Optimized spatial hashing for
// collision detection of deformable objects"), and the barycentric embedding of surface vertices in the rest tets
// that carries them into the posed mesh (Sujar et al. 2018 section 3.4).
#pragma once

#include <Eigen/Core>

#include <cstdint>
#include <vector>

#include "posewarp/common/progress.h"
#include "posewarp/common/result.h"
#include "posewarp/common/tet_mesh.h"

namespace posewarp::mapping {

// Tets hashed into the cells of a uniform grid that they overlap (by bounding box); a cell (i, j, k) goes to bucket
// (i * 73856093 xor j * 19349663 xor k * 83492791) mod n, n prime (Teschner 2003, section 4), so memory grows with
// the number of tets and never with the extent of the mesh. The locator copies what it needs from the mesh.
class TetLocator {
 public:
  // `mesh` holds #V x 3 vertices (LPS mm) and #T x 4 tets. cell_mm = 0 picks the mean tet edge length.
  // INVALID_ARGUMENT for an empty mesh, bad shapes or indices, non-finite vertices, or no tet with volume;
  // RESOURCE_EXHAUSTED when cell_mm is so small that the hash would not fit in memory.
  static Result<TetLocator> build(const TetMesh& mesh, double cell_mm = 0.0);

  struct Location {
    int32_t tet = -1;                                       // -1 only for a non-finite point
    Eigen::Vector4d barycentric = Eigen::Vector4d::Zero();  // weights of tets(tet, 0..3); sum to 1
    bool inside = false;                                    // every barycentric >= -1e-9
    double distance_mm = 0.0;                               // 0 inside, else from the point to the tet
  };

  // The tet containing p (barycentrics all >= -1e-9). If there is none, the nearest tet by the distance from p to
  // the tet, with its extrapolated barycentrics (they still reproduce p) and inside = false; ties go to the lower
  // tet index. The search walks outward through rings of cells until no unvisited cell can hold a nearer tet.
  // Thread-safe.
  Location locate(const Eigen::Vector3d& p) const;

  // The hash cell of p as one number (x fastest), or -1 when p lies outside the grid or is not finite. Points sorted
  // by it are located with the same few tets in cache.
  int64_t cell_of(const Eigen::Vector3d& p) const;

  double cell_mm() const { return cell_mm_; }
  // Tets left out of the hash because they have no volume.
  int64_t degenerate_tet_count() const { return degenerate_count_; }

 private:
  // Affine frame of one tet: barycentrics (b1, b2, b3) = inverse * (p - origin), b0 = 1 - b1 - b2 - b3.
  struct TetFrame {
    double origin[3];
    double inverse[9];  // row-major
  };

  TetLocator() = default;
  Eigen::Vector4d barycentric(int32_t tet, const Eigen::Vector3d& p) const;
  double distance_to_tet(int32_t tet, const Eigen::Vector3d& p, const Eigen::Vector4d& barycentric) const;
  double squared_distance_to_box(int32_t tet, const Eigen::Vector3d& p) const;
  int64_t bucket_of(int64_t i, int64_t j, int64_t k) const;
  int64_t cell_key(int64_t i, int64_t j, int64_t k) const { return i + dims_[0] * (j + dims_[1] * k); }

  double cell_mm_ = 1.0;
  Eigen::Vector3d grid_origin_ = Eigen::Vector3d::Zero();  // lower corner of cell (0, 0, 0), mm
  int64_t dims_[3] = {1, 1, 1};                            // cells per axis over the bounding box of the tets
  int64_t degenerate_count_ = 0;

  std::vector<TetFrame> frames_;  // #T
  std::vector<float> boxes_;      // #T x 6: bounding box (lo xyz, hi xyz), rounded outward
  std::vector<double> vertices_;  // #V x 3, row-major copy of the mesh vertices
  std::vector<int32_t> tets_;     // #T x 4, row-major copy of the mesh tets
  // The hash table in CSR form: the entries of bucket b are [bucket_start_[b], bucket_start_[b + 1]); an entry is a
  // (cell key, tet) pair, and cells that collide in a bucket are told apart by their key.
  std::vector<int32_t> bucket_start_;
  std::vector<int64_t> entry_cell_;
  std::vector<int32_t> entry_tet_;
};

using posewarp::Embedding;  // posewarp/common/tet_mesh.h

// Embeds points (#P x 3, LPS mm, in rest space) in the rest mesh, in parallel (posewarp::parallel_for).
// INVALID_ARGUMENT for points that are not #P x 3 or not finite, or a mesh TetLocator::build refuses; CANCELLED when
// the hooks ask.
Result<Embedding> embed_points(const TetMesh& rest, const Eigen::MatrixXd& points, const ProgressHooks& hooks);

// Posed positions, row p = sum_i barycentric(p, i) * posed_vertices(rest.tets(tet(p), i)): #P x 3, LPS mm.
// posed_vertices is #V x 3 (the rest mesh's vertices after skinning). A row whose tet or vertices do not exist in
// `rest` / `posed_vertices` comes out NaN rather than reading out of bounds.
Eigen::MatrixXd deform_points(const Embedding& embedding, const TetMesh& rest, const Eigen::MatrixXd& posed_vertices);

}  // namespace posewarp::mapping
