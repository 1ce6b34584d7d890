#include "posewarp/surface/surface_mesh.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include "test_support.h"

namespace posewarp::surface {
namespace {

using posewarp::testing::ScratchDir;
using posewarp::testing::write_bytes;

// A labelled ball of radius 12 mm (label 7) on a 1 mm grid under an oblique direction.
LabelVolume ball(const std::array<double, 9>& direction) {
  ImageGeometry g;
  g.size = {40, 40, 40};
  g.origin = {-5.0, 3.0, 10.0};
  g.direction = direction;
  LabelVolume labels(g, 0);
  for (int k = 0; k < 40; ++k)
    for (int j = 0; j < 40; ++j)
      for (int i = 0; i < 40; ++i) {
        if (std::hypot(i - 20.0, j - 20.0, k - 20.0) <= 12.0) labels.at(i, j, k) = 7;
      }
  return labels;
}

double enclosed_volume(const SurfaceMesh& m) {
  double v = 0.0;
  for (Eigen::Index f = 0; f < m.triangles.rows(); ++f) {
    const Eigen::Vector3d a = m.vertices.row(m.triangles(f, 0)), b = m.vertices.row(m.triangles(f, 1)),
                          c = m.vertices.row(m.triangles(f, 2));
    v += a.dot(b.cross(c)) / 6.0;
  }
  return v;
}

TEST(Surfaces, LabelSurfaceEnclosesTheLabelInPhysicalSpace) {
  const std::array<double, 9> oblique = posewarp::testing::oblique_direction();
  const LabelVolume labels = ball(oblique);
  SurfaceParams params;
  params.decimation = 0.3;
  Result<std::vector<SurfaceMesh>> surfaces = extract_label_surfaces(labels, {{7, "ball"}, {9, "absent"}}, params, {});
  ASSERT_TRUE(surfaces.ok()) << surfaces.status().to_string();
  ASSERT_EQ(surfaces->size(), 1u);
  const SurfaceMesh& s = surfaces->front();
  EXPECT_EQ(s.name, "ball");
  const Vec3 c = labels.geometry().index_to_physical({20.0, 20.0, 20.0});
  for (Eigen::Index v = 0; v < s.vertices.rows(); ++v) {
    const double r = (s.vertices.row(v).transpose() - Eigen::Vector3d(c[0], c[1], c[2])).norm();
    ASSERT_NEAR(r, 12.0, 1.5) << "vertex " << v;
  }
  const double expected = 4.0 / 3.0 * M_PI * 12.0 * 12.0 * 12.0;
  EXPECT_NEAR(enclosed_volume(s), expected, 0.06 * expected);  // outward triangles: positive volume
}

TEST(Surfaces, EveryFormatRoundTrips) {
  ScratchDir dir;
  SurfaceMesh tetrahedron;
  tetrahedron.vertices.resize(4, 3);
  tetrahedron.vertices << 0, 0, 0, 10, 0, 0, 0, 10, 0, 0, 0, 10;
  tetrahedron.triangles.resize(4, 3);
  tetrahedron.triangles << 0, 2, 1, 0, 1, 3, 0, 3, 2, 1, 2, 3;
  for (const std::string ext : {".stl", ".obj", ".ply", ".vtp"}) {
    const std::string path = dir.file("t" + ext);
    ASSERT_TRUE(write_surface(tetrahedron, path).ok()) << ext;
    Result<SurfaceMesh> back = read_surface(path);
    ASSERT_TRUE(back.ok()) << ext << ": " << back.status().to_string();
    EXPECT_EQ(back->triangles.rows(), 4) << ext;
    EXPECT_NEAR(std::abs(enclosed_volume(*back)), 1000.0 / 6.0, 1e-3) << ext;
  }
}

TEST(Surfaces, BadFilesAreClearErrors) {
  ScratchDir dir;
  EXPECT_EQ(read_surface(dir.file("missing.stl")).status().code(), StatusCode::kNotFound);
  write_bytes(dir.file("empty.ply"), "");
  EXPECT_EQ(read_surface(dir.file("empty.ply")).status().code(), StatusCode::kInvalidArgument);
  write_bytes(dir.file("garbage.vtp"), std::string(300, 'x'));
  EXPECT_EQ(read_surface(dir.file("garbage.vtp")).status().code(), StatusCode::kInvalidArgument);
  write_bytes(dir.file("mesh.off"), "OFF\n");
  EXPECT_EQ(read_surface(dir.file("mesh.off")).status().code(), StatusCode::kInvalidArgument);
  SurfaceMesh none;
  EXPECT_EQ(write_surface(none, dir.file("x.3ds")).code(), StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace posewarp::surface
