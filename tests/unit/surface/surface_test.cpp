#include "posewarp/surface/surface_mesh.h"

#include <gtest/gtest.h>

#include <Eigen/Dense>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <functional>
#include <map>
#include <random>
#include <sstream>
#include <utility>

#include "posewarp/io/volume_io.h"
#include "test_support.h"

namespace posewarp::surface {
namespace {

using posewarp::testing::ScratchDir;
using posewarp::testing::write_bytes;

Eigen::Vector3d physical(const ImageGeometry& g, double i, double j, double k) {
  const Vec3 p = g.index_to_physical({i, j, k});
  return {p[0], p[1], p[2]};
}

// Labels `value` where `inside` holds at the voxel centre (physical mm).
LabelVolume label_where(const ImageGeometry& g, Label value, const std::function<bool(const Eigen::Vector3d&)>& inside,
                        LabelVolume labels = {}) {
  if (labels.empty()) labels = LabelVolume(g, 0);
  for (int64_t k = 0; k < g.size[2]; ++k) {
    for (int64_t j = 0; j < g.size[1]; ++j) {
      for (int64_t i = 0; i < g.size[0]; ++i) {
        if (inside(physical(g, static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)))) {
          labels.at(i, j, k) = value;
        }
      }
    }
  }
  return labels;
}

// A grid of anisotropic voxels under the oblique direction of test_support, about 50 mm across.
ImageGeometry oblique_grid() {
  ImageGeometry g;
  g.size = {50, 44, 38};
  g.spacing = {0.9, 1.1, 1.3};
  g.origin = {-40.0, 25.0, 110.0};
  g.direction = posewarp::testing::oblique_direction();
  return g;
}

Eigen::Vector3d grid_centre(const ImageGeometry& g) {
  return physical(g, (static_cast<double>(g.size[0]) - 1) / 2, (static_cast<double>(g.size[1]) - 1) / 2,
                  (static_cast<double>(g.size[2]) - 1) / 2);
}

Eigen::Vector3d corner(const SurfaceMesh& m, Eigen::Index f, int c) {
  return m.vertices.row(m.triangles(f, c)).transpose();
}

Eigen::Vector3d centroid(const SurfaceMesh& m, Eigen::Index f) {
  return (corner(m, f, 0) + corner(m, f, 1) + corner(m, f, 2)) / 3.0;
}

Eigen::Vector3d area_normal(const SurfaceMesh& m, Eigen::Index f) {
  return (corner(m, f, 1) - corner(m, f, 0)).cross(corner(m, f, 2) - corner(m, f, 0)) / 2.0;
}

double enclosed_volume(const SurfaceMesh& m) {
  double v = 0.0;
  for (Eigen::Index f = 0; f < m.triangles.rows(); ++f)
    v += corner(m, f, 0).dot(corner(m, f, 1).cross(corner(m, f, 2))) / 6.0;
  return v;
}

double area(const SurfaceMesh& m) {
  double a = 0.0;
  for (Eigen::Index f = 0; f < m.triangles.rows(); ++f) a += area_normal(m, f).norm();
  return a;
}

// Closed and consistently oriented: every directed edge appears once and its reverse once.
bool closed_and_consistent(const SurfaceMesh& m) {
  std::map<std::pair<int, int>, int> directed;
  for (Eigen::Index f = 0; f < m.triangles.rows(); ++f) {
    for (int c = 0; c < 3; ++c) ++directed[{m.triangles(f, c), m.triangles(f, (c + 1) % 3)}];
  }
  for (const auto& [edge, count] : directed) {
    if (count != 1) return false;
    const auto reverse = directed.find({edge.second, edge.first});
    if (reverse == directed.end() || reverse->second != 1) return false;
  }
  return true;
}

// Fraction of triangles whose normal points away from `centre` (times `sign`).
double fraction_facing(const SurfaceMesh& m, const Eigen::Vector3d& centre, double sign = 1.0) {
  int64_t facing = 0;
  for (Eigen::Index f = 0; f < m.triangles.rows(); ++f)
    facing += sign * area_normal(m, f).dot(centroid(m, f) - centre) > 0;
  return static_cast<double>(facing) / static_cast<double>(m.triangles.rows());
}

TEST(LabelSurfaces, ABallGivesItsVolumeAndAreaAtItsPlaceInPhysicalSpace) {
  const ImageGeometry g = oblique_grid();
  const Eigen::Vector3d centre = grid_centre(g) + Eigen::Vector3d(1.3, -0.7, 0.4);
  const double r = 14.0;
  const LabelVolume labels = label_where(g, 7, [&](const Eigen::Vector3d& p) { return (p - centre).norm() <= r; });
  Result<std::vector<SurfaceMesh>> surfaces = extract_label_surfaces(labels, {{7, "ball"}}, SurfaceParams{}, {});
  ASSERT_TRUE(surfaces.ok()) << surfaces.status().to_string();
  ASSERT_EQ(surfaces->size(), 1u);
  const SurfaceMesh& s = surfaces->front();
  EXPECT_EQ(s.name, "ball");
  EXPECT_EQ(s.label, 7);
  EXPECT_GT(s.triangles.rows(), 500);
  for (Eigen::Index v = 0; v < s.vertices.rows(); ++v) {
    ASSERT_NEAR((s.vertices.row(v).transpose() - centre).norm(), r, 0.8) << "vertex " << v;
  }
  EXPECT_NEAR(enclosed_volume(s), 4.0 / 3.0 * M_PI * r * r * r, 0.03 * 4.0 / 3.0 * M_PI * r * r * r);
  EXPECT_NEAR(area(s), 4.0 * M_PI * r * r, 0.05 * 4.0 * M_PI * r * r);
  EXPECT_EQ(fraction_facing(s, centre), 1.0);
  EXPECT_TRUE(closed_and_consistent(s));
}

TEST(LabelSurfaces, AnUnsmoothedBoxLiesHalfAVoxelOutsideItsVoxelsUnderAnObliqueDirection) {
  const ImageGeometry g = oblique_grid();
  const Index3 lo{5, 4, 3}, hi{30, 21, 17};
  LabelVolume labels(g, 0);
  for (int64_t k = lo[2]; k <= hi[2]; ++k)
    for (int64_t j = lo[1]; j <= hi[1]; ++j)
      for (int64_t i = lo[0]; i <= hi[0]; ++i) labels.at(i, j, k) = 2;
  SurfaceParams raw;
  raw.smoothing_iterations = 0;
  raw.decimation = 0.0;
  Result<std::vector<SurfaceMesh>> surfaces = extract_label_surfaces(labels, {{2, "box"}}, raw, {});
  ASSERT_TRUE(surfaces.ok()) << surfaces.status().to_string();
  ASSERT_EQ(surfaces->size(), 1u);
  const SurfaceMesh& s = surfaces->front();
  for (Eigen::Index v = 0; v < s.vertices.rows(); ++v) {
    const Vec3 index = g.physical_to_index({s.vertices(v, 0), s.vertices(v, 1), s.vertices(v, 2)});
    bool on_a_face = false;
    for (int a = 0; a < 3; ++a) {
      const double face_lo = static_cast<double>(lo[a]) - 0.5, face_hi = static_cast<double>(hi[a]) + 0.5;
      ASSERT_GE(index[static_cast<size_t>(a)], face_lo - 1e-6) << "vertex " << v << " axis " << a;
      ASSERT_LE(index[static_cast<size_t>(a)], face_hi + 1e-6) << "vertex " << v << " axis " << a;
      on_a_face = on_a_face || std::abs(index[static_cast<size_t>(a)] - face_lo) < 1e-6 ||
                  std::abs(index[static_cast<size_t>(a)] - face_hi) < 1e-6;
    }
    ASSERT_TRUE(on_a_face) << "vertex " << v;
  }
  double box_volume = 1.0;
  for (int a = 0; a < 3; ++a) box_volume *= static_cast<double>(hi[a] - lo[a] + 1) * g.spacing[static_cast<size_t>(a)];
  EXPECT_NEAR(enclosed_volume(s), box_volume, 0.04 * box_volume);  // the cut edges and corners take a little
  EXPECT_TRUE(closed_and_consistent(s));

  Result<std::vector<SurfaceMesh>> smoothed = extract_label_surfaces(labels, {{2, "box"}}, SurfaceParams{}, {});
  ASSERT_TRUE(smoothed.ok());
  EXPECT_NEAR(enclosed_volume(smoothed->front()), box_volume, 0.05 * box_volume);
}

TEST(LabelSurfaces, TheInnerWallOfAHollowLabelFacesItsCavity) {
  const ImageGeometry g = oblique_grid();
  const Eigen::Vector3d centre = grid_centre(g);
  const double inner = 7.0, outer = 15.0;
  const LabelVolume labels = label_where(g, 4, [&](const Eigen::Vector3d& p) {
    const double d = (p - centre).norm();
    return d > inner && d <= outer;
  });
  Result<std::vector<SurfaceMesh>> surfaces = extract_label_surfaces(labels, {{4, "shell"}}, SurfaceParams{}, {});
  ASSERT_TRUE(surfaces.ok());
  const SurfaceMesh& s = surfaces->front();
  int64_t inner_faces = 0, outer_faces = 0, wrong = 0;
  for (Eigen::Index f = 0; f < s.triangles.rows(); ++f) {
    const Eigen::Vector3d c = centroid(s, f);
    const bool on_inner_wall = (c - centre).norm() < (inner + outer) / 2;
    (on_inner_wall ? inner_faces : outer_faces)++;
    const double outward = area_normal(s, f).dot(c - centre);
    wrong += on_inner_wall ? outward > 0 : outward < 0;
  }
  EXPECT_GT(inner_faces, 50);
  EXPECT_GT(outer_faces, 50);
  EXPECT_EQ(wrong, 0);
  const double shell = 4.0 / 3.0 * M_PI * (outer * outer * outer - inner * inner * inner);
  EXPECT_NEAR(enclosed_volume(s), shell, 0.05 * shell);
}

TEST(LabelSurfaces, AMirroringDirectionMatrixStillGivesOutwardTriangles) {
  ImageGeometry g = oblique_grid();
  for (int r = 0; r < 3; ++r) g.direction[static_cast<size_t>(3 * r + 1)] *= -1.0;  // flip the j axis: det = -1
  const Eigen::Vector3d centre = grid_centre(g);
  const double r = 12.0;
  const LabelVolume labels = label_where(g, 1, [&](const Eigen::Vector3d& p) { return (p - centre).norm() <= r; });
  Result<std::vector<SurfaceMesh>> surfaces = extract_label_surfaces(labels, {{1, "ball"}}, SurfaceParams{}, {});
  ASSERT_TRUE(surfaces.ok());
  const SurfaceMesh& s = surfaces->front();
  EXPECT_EQ(fraction_facing(s, centre), 1.0);
  EXPECT_NEAR(enclosed_volume(s), 4.0 / 3.0 * M_PI * r * r * r, 0.03 * 4.0 / 3.0 * M_PI * r * r * r);
  for (Eigen::Index v = 0; v < s.vertices.rows(); ++v) {
    ASSERT_NEAR((s.vertices.row(v).transpose() - centre).norm(), r, 0.8);
  }
}

TEST(LabelSurfaces, OneSurfacePerWantedLabelPresentInTheOrderAsked) {
  const ImageGeometry g = oblique_grid();
  const Eigen::Vector3d a = physical(g, 12, 12, 12), b = physical(g, 36, 30, 24);
  LabelVolume labels = label_where(g, 3, [&](const Eigen::Vector3d& p) { return (p - a).norm() <= 8.0; });
  labels = label_where(
      g, 5, [&](const Eigen::Vector3d& p) { return (p - b).norm() <= 9.0; }, labels);
  Result<std::vector<SurfaceMesh>> surfaces =
      extract_label_surfaces(labels, {{5, "b"}, {9, "absent"}, {3, "a"}, {5, "b again"}}, SurfaceParams{}, {});
  ASSERT_TRUE(surfaces.ok());
  ASSERT_EQ(surfaces->size(), 2u);
  EXPECT_EQ((*surfaces)[0].name, "b");
  EXPECT_EQ((*surfaces)[0].label, 5);
  EXPECT_EQ((*surfaces)[1].name, "a");
  EXPECT_EQ((*surfaces)[1].label, 3);
  EXPECT_LT(((*surfaces)[0].vertices.colwise().mean().transpose() - b).norm(), 0.5);
  EXPECT_LT(((*surfaces)[1].vertices.colwise().mean().transpose() - a).norm(), 0.5);
}

TEST(LabelSurfaces, ALabelFillingTheWholeVolumeStillGetsAClosedSurface) {
  ImageGeometry g;
  g.size = {12, 10, 8};
  g.spacing = {2.0, 2.0, 2.0};
  const LabelVolume labels(g, 1);
  SurfaceParams raw;
  raw.smoothing_iterations = 0;
  raw.decimation = 0.0;
  Result<std::vector<SurfaceMesh>> surfaces = extract_label_surfaces(labels, {{1, "all"}}, raw, {});
  ASSERT_TRUE(surfaces.ok());
  ASSERT_EQ(surfaces->size(), 1u);
  EXPECT_TRUE(closed_and_consistent(surfaces->front()));
  EXPECT_NEAR(enclosed_volume(surfaces->front()), 24.0 * 20.0 * 16.0, 0.05 * 24.0 * 20.0 * 16.0);
}

TEST(LabelSurfaces, NoWantedLabelPresentGivesNoSurfaces) {
  const LabelVolume labels(oblique_grid(), 0);
  Result<std::vector<SurfaceMesh>> surfaces = extract_label_surfaces(labels, {{8, "absent"}}, SurfaceParams{}, {});
  ASSERT_TRUE(surfaces.ok());
  EXPECT_TRUE(surfaces->empty());
}

TEST(LabelSurfaces, BadParametersAreRefusedBeforeAnyWork) {
  EXPECT_TRUE(validate(SurfaceParams{}).ok());
  SurfaceParams p;
  p.smoothing_iterations = -1;
  EXPECT_EQ(validate(p).code(), StatusCode::kInvalidArgument);
  p = {};
  p.pass_band = 0.0;
  EXPECT_EQ(validate(p).code(), StatusCode::kInvalidArgument);
  p.pass_band = 2.5;
  EXPECT_EQ(validate(p).code(), StatusCode::kInvalidArgument);
  p = {};
  p.decimation = 1.0;
  EXPECT_EQ(validate(p).code(), StatusCode::kInvalidArgument);
  p.decimation = std::nan("");
  const Status status = extract_label_surfaces(LabelVolume(oblique_grid(), 1), {{1, "x"}}, p, {}).status();
  EXPECT_EQ(status.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(status.message().find("decimation"), std::string::npos);
}

TEST(LabelSurfaces, ExtractionStopsWhenCancelled) {
  const LabelVolume labels(oblique_grid(), 1);
  ProgressHooks hooks;
  hooks.cancel_requested = [] { return true; };
  EXPECT_EQ(extract_label_surfaces(labels, {{1, "x"}}, SurfaceParams{}, hooks).status().code(), StatusCode::kCancelled);
}

TEST(LabelSurfaces, SurfacesOfTheSampleSegmentationLieOnTheBoundaryOfTheirLabels) {
  Result<LabelVolume> seg = io::read_label_volume(std::string(POSEWARP_SAMPLE_DIR) + "/seg_total.nii.gz");
  ASSERT_TRUE(seg.ok()) << seg.status().to_string();
  const ImageGeometry& g = seg->geometry();
  SurfaceParams raw;  // unsmoothed, so that every vertex sits half-way between a label voxel and another
  raw.smoothing_iterations = 0;
  raw.decimation = 0.0;
  Result<std::vector<SurfaceMesh>> surfaces =
      extract_label_surfaces(*seg, {{5, "liver"}, {29, "vertebrae_L3"}, {77, "hip_left"}}, raw, {});
  ASSERT_TRUE(surfaces.ok()) << surfaces.status().to_string();
  ASSERT_EQ(surfaces->size(), 3u);
  for (const SurfaceMesh& s : *surfaces) {
    int64_t voxels = 0;
    for (const Label l : seg->voxels()) voxels += l == s.label;
    const double voxel_volume = g.spacing[0] * g.spacing[1] * g.spacing[2];
    EXPECT_NEAR(enclosed_volume(s), static_cast<double>(voxels) * voxel_volume,
                0.12 * static_cast<double>(voxels) * voxel_volume)
        << s.name;
    for (Eigen::Index v = 0; v < s.vertices.rows(); ++v) {
      const Vec3 index = g.physical_to_index({s.vertices(v, 0), s.vertices(v, 1), s.vertices(v, 2)});
      // A vertex lies on a voxel edge, half-way between a voxel of the label and one without it.
      bool label_near = false, other_near = false;
      for (double di : {-0.5, 0.5}) {
        for (double dj : {-0.5, 0.5}) {
          for (double dk : {-0.5, 0.5}) {
            const int64_t i = std::llround(index[0] + di * 0.999), j = std::llround(index[1] + dj * 0.999),
                          k = std::llround(index[2] + dk * 0.999);
            const bool is_label = seg->contains(i, j, k) && seg->at(i, j, k) == s.label;
            label_near = label_near || is_label;
            other_near = other_near || !is_label;
          }
        }
      }
      ASSERT_TRUE(label_near && other_near) << s.name << " vertex " << v << " is not on the label's boundary";
    }
  }
}

// A small closed mesh with coordinates that do not round to short decimals.
SurfaceMesh test_mesh() {
  const ImageGeometry g = oblique_grid();
  const Eigen::Vector3d centre = grid_centre(g);
  const LabelVolume labels = label_where(g, 1, [&](const Eigen::Vector3d& p) { return (p - centre).norm() <= 6.0; });
  Result<std::vector<SurfaceMesh>> surfaces = extract_label_surfaces(labels, {{1, "ball"}}, SurfaceParams{}, {});
  return surfaces.ok() && !surfaces->empty() ? surfaces->front() : SurfaceMesh{};
}

TEST(MeshFiles, EveryFormatRoundTripsVerticesAndTriangles) {
  ScratchDir dir;
  const SurfaceMesh mesh = test_mesh();
  ASSERT_GT(mesh.triangles.rows(), 50);
  // STL and PLY hold float32; OBJ is text; VTP keeps float64.
  const std::map<std::string, double> tolerance = {
      {".stl", 1e-4}, {".obj", 1e-4}, {".ply", 1e-4}, {".vtp", 1e-12}, {".STL", 1e-4}};
  for (const auto& [extension, tol] : tolerance) {
    const std::string path = dir.file("round_trip" + extension);
    const Status written = write_surface(mesh, path);
    ASSERT_TRUE(written.ok()) << extension << ": " << written.to_string();
    Result<SurfaceMesh> back = read_surface(path);
    ASSERT_TRUE(back.ok()) << extension << ": " << back.status().to_string();
    EXPECT_EQ(back->name, "round_trip");
    EXPECT_EQ(back->label, 0);
    ASSERT_EQ(back->triangles.rows(), mesh.triangles.rows()) << extension;
    EXPECT_EQ(back->vertices.rows(), mesh.vertices.rows()) << extension;
    double worst = 0.0;
    for (Eigen::Index f = 0; f < mesh.triangles.rows(); ++f) {
      for (int c = 0; c < 3; ++c) worst = std::max(worst, (corner(*back, f, c) - corner(mesh, f, c)).norm());
    }
    EXPECT_LT(worst, tol) << extension;
    EXPECT_TRUE(closed_and_consistent(*back)) << extension;
  }
}

TEST(MeshFiles, BadFilesAreClearErrorsNamingTheFileAndPrintNothing) {
  ScratchDir dir;
  std::mt19937 rng(9);
  std::string noise(4096, '\0');
  for (char& c : noise) c = static_cast<char>(rng() & 0xff);
  ASSERT_TRUE(write_surface(test_mesh(), dir.file("good.stl")).ok());
  ASSERT_TRUE(write_surface(test_mesh(), dir.file("good.ply")).ok());
  ASSERT_TRUE(write_surface(test_mesh(), dir.file("good.vtp")).ok());
  const std::string good_stl = posewarp::testing::read_bytes(dir.file("good.stl"));
  const std::string good_ply = posewarp::testing::read_bytes(dir.file("good.ply"));
  const std::string good_vtp = posewarp::testing::read_bytes(dir.file("good.vtp"));

  ::testing::internal::CaptureStderr();
  ::testing::internal::CaptureStdout();
  auto expect_error = [&](const std::string& name, StatusCode code) {
    const Status status = read_surface(dir.file(name)).status();
    EXPECT_EQ(status.code(), code) << name << ": " << status.to_string();
    EXPECT_NE(status.message().find(name), std::string::npos) << status.message();
  };
  expect_error("missing.stl", StatusCode::kNotFound);
  std::filesystem::create_directories(dir.file("folder.obj"));
  expect_error("folder.obj", StatusCode::kInvalidArgument);
  write_bytes(dir.file("mesh.off"), "OFF\n3 1 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n");
  expect_error("mesh.off", StatusCode::kInvalidArgument);
  for (const std::string extension : {".stl", ".obj", ".ply", ".vtp"}) {
    write_bytes(dir.file("empty" + extension), "");
    expect_error("empty" + extension, StatusCode::kInvalidArgument);
    write_bytes(dir.file("noise" + extension), noise);
    expect_error("noise" + extension, StatusCode::kInvalidArgument);
    write_bytes(dir.file("text" + extension), std::string(300, 'x') + "\nnot a mesh\n");
    expect_error("text" + extension, StatusCode::kInvalidArgument);
  }
  write_bytes(dir.file("truncated.stl"), good_stl.substr(0, 80));
  expect_error("truncated.stl", StatusCode::kInvalidArgument);
  write_bytes(dir.file("truncated.ply"), good_ply.substr(0, good_ply.size() / 2));
  expect_error("truncated.ply", StatusCode::kInvalidArgument);
  write_bytes(dir.file("truncated.vtp"), good_vtp.substr(0, good_vtp.size() / 2));
  expect_error("truncated.vtp", StatusCode::kInvalidArgument);
  write_bytes(dir.file("points.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\n");
  expect_error("points.obj", StatusCode::kInvalidArgument);
  // Faces that refer to vertices the file does not have.
  write_bytes(dir.file("bad_index.obj"), "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n");
  expect_error("bad_index.obj", StatusCode::kInvalidArgument);
  write_bytes(dir.file("bad_index.ply"),
              "ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
              "element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 7\n");
  expect_error("bad_index.ply", StatusCode::kInvalidArgument);
  write_bytes(dir.file("bad_index.vtp"),
              "<?xml version=\"1.0\"?>\n<VTKFile type=\"PolyData\" version=\"0.1\" byte_order=\"LittleEndian\">\n"
              "<PolyData><Piece NumberOfPoints=\"3\" NumberOfPolys=\"1\">\n"
              "<Points><DataArray type=\"Float64\" NumberOfComponents=\"3\" format=\"ascii\">0 0 0 1 0 0 0 1 0"
              "</DataArray></Points>\n<Polys><DataArray type=\"Int64\" Name=\"connectivity\" format=\"ascii\">0 1 "
              "70</DataArray>\n<DataArray type=\"Int64\" Name=\"offsets\" format=\"ascii\">3</DataArray></Polys>\n"
              "</Piece></PolyData></VTKFile>\n");
  expect_error("bad_index.vtp", StatusCode::kInvalidArgument);
  const std::string printed = ::testing::internal::GetCapturedStderr() + ::testing::internal::GetCapturedStdout();
  EXPECT_EQ(printed, "");
}

TEST(MeshFiles, CorruptedFilesGiveErrorsOrMeshesButNeverCrash) {
  ScratchDir dir;
  const SurfaceMesh mesh = test_mesh();
  std::mt19937 rng(21);
  const int rounds = std::getenv("POSEWARP_FUZZ_ROUNDS") ? std::atoi(std::getenv("POSEWARP_FUZZ_ROUNDS")) : 25;
  ::testing::internal::CaptureStderr();
  for (const std::string extension : {".stl", ".obj", ".ply", ".vtp", ".ply_ascii"}) {
    const bool ascii_ply = extension == ".ply_ascii";
    const std::string real_extension = ascii_ply ? ".ply" : extension;
    std::string good;
    if (ascii_ply) {
      std::ostringstream text;
      text << "ply\nformat ascii 1.0\nelement vertex " << mesh.vertices.rows()
           << "\nproperty float x\nproperty float y\nproperty float z\nelement face " << mesh.triangles.rows()
           << "\nproperty list uchar int vertex_indices\nend_header\n";
      for (Eigen::Index v = 0; v < mesh.vertices.rows(); ++v) text << mesh.vertices.row(v) << "\n";
      for (Eigen::Index f = 0; f < mesh.triangles.rows(); ++f) text << "3 " << mesh.triangles.row(f) << "\n";
      good = text.str();
    } else {
      ASSERT_TRUE(write_surface(mesh, dir.file("good" + extension)).ok());
      good = posewarp::testing::read_bytes(dir.file("good" + extension));
    }
    for (int round = 0; round < rounds; ++round) {
      std::string bad = good;
      const int kind = round % 3;
      if (kind == 0) {  // cut short
        bad.resize(std::uniform_int_distribution<size_t>(1, good.size() - 1)(rng));
      } else {  // bytes overwritten, in the header (kind 1) or anywhere (kind 2)
        const size_t span = kind == 1 ? std::min<size_t>(good.size(), 300) : good.size();
        for (int n = 0; n < 8; ++n)
          bad[std::uniform_int_distribution<size_t>(0, span - 1)(rng)] = static_cast<char>(rng());
      }
      const std::string path = dir.file("bad" + std::to_string(round) + real_extension);
      write_bytes(path, bad);
      const Result<SurfaceMesh> read = read_surface(path);  // must return, either way
      if (read.ok()) {
        EXPECT_TRUE(read->vertices.allFinite());
        EXPECT_GE(read->triangles.minCoeff(), 0);
        EXPECT_LT(read->triangles.maxCoeff(), read->vertices.rows());
      } else {
        EXPECT_NE(read.status().message().find(path), std::string::npos) << read.status().message();
      }
    }
  }
  EXPECT_EQ(::testing::internal::GetCapturedStderr(), "");
}

TEST(MeshFiles, WritesRefuseBadMeshesAndTargetsAndLeaveNoPartialFiles) {
  ScratchDir dir;
  const SurfaceMesh mesh = test_mesh();
  EXPECT_EQ(write_surface(mesh, dir.file("mesh.3ds")).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(write_surface(mesh, dir.file("no/such/dir/mesh.stl")).code(), StatusCode::kNotFound);
  SurfaceMesh bad = mesh;
  bad.triangles(0, 1) = static_cast<int>(mesh.vertices.rows());
  EXPECT_EQ(write_surface(bad, dir.file("bad.ply")).code(), StatusCode::kInvalidArgument);
  bad = mesh;
  bad.vertices(2, 2) = std::nan("");
  EXPECT_EQ(write_surface(bad, dir.file("bad.obj")).code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(write_surface(SurfaceMesh{}, dir.file("none.vtp")).code(), StatusCode::kInvalidArgument);

  // Overwriting replaces the file whole.
  ASSERT_TRUE(write_surface(mesh, dir.file("mesh.vtp")).ok());
  SurfaceMesh moved = mesh;
  moved.vertices.col(0).array() += 100.0;
  ASSERT_TRUE(write_surface(moved, dir.file("mesh.vtp")).ok());
  Result<SurfaceMesh> back = read_surface(dir.file("mesh.vtp"));
  ASSERT_TRUE(back.ok());
  EXPECT_LT((back->vertices - moved.vertices).cwiseAbs().maxCoeff(), 1e-12);
  int files = 0;
  for (const auto& entry : std::filesystem::directory_iterator(dir.path())) {
    ++files;
    EXPECT_EQ(entry.path().filename().string().find(".posewarp-partial"), std::string::npos) << entry.path();
  }
  EXPECT_EQ(files, 1);
}

}  // namespace
}  // namespace posewarp::surface

namespace posewarp::surface {
namespace {

// Every mesh the fuzzer found crashing or allocating without bound (tests/fuzz/corpus/surface/regression-*: a
// format byte, then the file) is refused in the ordinary build too; the seeds that are valid meshes still read.
TEST(SurfaceFiles, EveryMeshFuzzingFoundIsRefused) {
  posewarp::testing::ScratchDir dir;
  const char* const extensions[] = {".obj", ".ply", ".stl", ".vtp"};
  int seen = 0;
  for (const auto& entry :
       std::filesystem::directory_iterator(std::filesystem::path(POSEWARP_SOURCE_DIR) / "tests/fuzz/corpus/surface")) {
    const std::string name = entry.path().filename().string();
    const std::string bytes = posewarp::testing::read_bytes(entry.path().string());
    ASSERT_FALSE(bytes.empty());
    const std::string path = dir.file(name + extensions[static_cast<unsigned char>(bytes[0]) % 4]);
    posewarp::testing::write_bytes(path, bytes.substr(1));
    const Result<SurfaceMesh> mesh = read_surface(path);
    if (name.rfind("regression-", 0) == 0) {
      EXPECT_FALSE(mesh.ok()) << name;
      ++seen;
    } else {
      EXPECT_TRUE(mesh.ok()) << name << ": " << mesh.status().to_string();  // the seeds are valid tetrahedra
    }
  }
  EXPECT_GE(seen, 1);
}

}  // namespace
}  // namespace posewarp::surface
