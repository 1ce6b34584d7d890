// Structured tet meshes for the weights tests: cubes split into 6 Kuhn tets, classes set by position.
#pragma once

#include <Eigen/Core>

#include <array>
#include <functional>
#include <random>
#include <utility>
#include <vector>

#include "posewarp/common/tet_mesh.h"

namespace posewarp::weights::testing {

// Class of the cube whose centre is given (mm); 0 leaves the cube out.
using CubeClass = std::function<int(const Eigen::Vector3d& centre_mm)>;

// nx x ny x nz cubes of edge h mm from the origin, each split into the 6 tets around its main diagonal (the same
// split in every cube, so faces match). Vertices of left-out cubes are dropped. `jitter` moves every vertex by up
// to jitter * h per axis (seeded), which makes some tets obtuse.
inline TetMesh grid_mesh(int nx, int ny, int nz, double h, const CubeClass& class_of, int segment_count,
                         double jitter = 0.0, unsigned seed = 1) {
  const auto grid_index = [&](int i, int j, int k) { return i + (nx + 1) * (j + (ny + 1) * k); };
  const int grid_vertices = (nx + 1) * (ny + 1) * (nz + 1);
  std::vector<std::array<int, 4>> tets;
  std::vector<int> classes;
  const std::array<std::array<int, 3>, 6> permutations = {
      {{0, 1, 2}, {0, 2, 1}, {1, 0, 2}, {1, 2, 0}, {2, 0, 1}, {2, 1, 0}}};
  for (int k = 0; k < nz; ++k) {
    for (int j = 0; j < ny; ++j) {
      for (int i = 0; i < nx; ++i) {
        const int cls = class_of(Eigen::Vector3d((i + 0.5) * h, (j + 0.5) * h, (k + 0.5) * h));
        if (cls == 0) continue;
        for (const auto& p : permutations) {
          std::array<int, 3> corner = {i, j, k};
          std::array<int, 4> tet{};
          tet[0] = grid_index(corner[0], corner[1], corner[2]);
          for (int step = 0; step < 3; ++step) {
            ++corner[p[step]];
            tet[step + 1] = grid_index(corner[0], corner[1], corner[2]);
          }
          // Odd permutations give negatively oriented tets.
          const bool odd = (p[0] == 0 && p[1] == 2) || (p[0] == 1 && p[1] == 0) || (p[0] == 2 && p[1] == 1);
          if (odd) std::swap(tet[2], tet[3]);
          tets.push_back(tet);
          classes.push_back(cls);
        }
      }
    }
  }
  std::vector<int> compact(grid_vertices, -1);
  int used = 0;
  for (const auto& tet : tets) {
    for (const int v : tet) {
      if (compact[v] < 0) compact[v] = used++;
    }
  }
  TetMesh mesh;
  mesh.segment_count = segment_count;
  mesh.vertices.resize(used, 3);
  std::mt19937 rng(seed);
  std::uniform_real_distribution<double> offset(-jitter * h, jitter * h);
  for (int k = 0; k <= nz; ++k) {
    for (int j = 0; j <= ny; ++j) {
      for (int i = 0; i <= nx; ++i) {
        const int v = compact[grid_index(i, j, k)];
        if (v < 0) continue;
        mesh.vertices.row(v) << i * h, j * h, k * h;
        if (jitter > 0.0) mesh.vertices.row(v) += Eigen::RowVector3d(offset(rng), offset(rng), offset(rng));
      }
    }
  }
  mesh.tets.resize(static_cast<Eigen::Index>(tets.size()), 4);
  mesh.tet_class.resize(static_cast<Eigen::Index>(tets.size()));
  for (size_t t = 0; t < tets.size(); ++t) {
    for (int a = 0; a < 4; ++a) mesh.tets(static_cast<Eigen::Index>(t), a) = compact[tets[t][a]];
    mesh.tet_class[static_cast<Eigen::Index>(t)] = classes[t];
  }
  return mesh;
}

// A bar along x of `length` cubes (edge 1 mm, cross-section 3 x 3) with bone segment 0 on x < bone_length, bone
// segment 1 on x > length - bone_length and soft tissue between.
inline TetMesh two_bone_bar(int length = 12, int bone_length = 3, double jitter = 0.0) {
  return grid_mesh(
      length, 3, 3, 1.0,
      [=](const Eigen::Vector3d& c) {
        if (c.x() < bone_length) return kFirstBoneClass;
        if (c.x() > length - bone_length) return kFirstBoneClass + 1;
        return kSoftTissueClass;
      },
      2, jitter);
}

// A 4 x 4 x 21 mm bar along z with three bones (z in [0, 3), [9, 12), [18, 21)) in soft tissue.
inline TetMesh three_bone_bar(double jitter = 0.0, unsigned seed = 1) {
  return grid_mesh(
      4, 4, 21, 1.0,
      [](const Eigen::Vector3d& c) {
        if (c.z() < 3) return kFirstBoneClass;
        if (c.z() > 9 && c.z() < 12) return kFirstBoneClass + 1;
        if (c.z() > 18) return kFirstBoneClass + 2;
        return kSoftTissueClass;
      },
      3, jitter, seed);
}

}  // namespace posewarp::weights::testing
