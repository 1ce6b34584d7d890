#include "posewarp/resample/tet_warp.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <map>
#include <set>

#include "posewarp/io/itk_reference.h"
#include "posewarp/labels/body.h"
#include "posewarp/mesh/mesher.h"
#include "posewarp/phantom/phantom.h"

namespace posewarp::resample {
namespace {

struct Scene {
  phantom::Phantom phantom;
  TetMesh mesh;
  RestTopology topology;
  std::vector<uint8_t> rest_coverage;
};

// The bar phantom, meshed, with its rest coverage computed once (as a rig does).
const Scene& bar_scene() {
  static const Scene scene = [] {
    Scene s;
    phantom::BarParams params;
    params.length_mm = 120.0;
    params.bone_count = 3;
    s.phantom = *phantom::make_bar(params);
    Result<LabelVolume> body = labels::body_mask(s.phantom.label_map, s.phantom.labels, nullptr);
    const LabelVolume classes = labels::segment_classes(s.phantom.label_map, s.phantom.labels, *body);
    mesh::MeshParams mp;
    mp.facet_size_mm = 4.0;
    mp.facet_distance_mm = 1.0;
    mp.bone_cell_size_mm = 4.0;
    mp.soft_cell_size_mm = 8.0;
    mp.parallel = false;
    s.mesh = *mesh::make_cgal_mesher()->mesh(classes, 3, mp, {}, nullptr);
    s.topology = rest_topology(s.mesh);
    const ImageGeometry& g = s.phantom.labels.geometry();
    Result<TetWarp> identity = TetWarp::build(s.mesh, s.topology, s.mesh.vertices, g, g, Eigen::Matrix3d::Identity(),
                                              Eigen::Vector3d::Zero(), nullptr, {}, {});
    s.rest_coverage = identity->coverage();
    return s;
  }();
  return scene;
}

TEST(TetWarp, IdentityPoseGivesBackTheInputVoxelForVoxel) {
  const Scene& s = bar_scene();
  const ImageGeometry& g = s.phantom.labels.geometry();
  Result<TetWarp> warp = TetWarp::build(s.mesh, s.topology, s.mesh.vertices, g, g, Eigen::Matrix3d::Identity(),
                                        Eigen::Vector3d::Zero(), &s.rest_coverage, {}, {});
  ASSERT_TRUE(warp.ok()) << warp.status().to_string();
  Result<LabelVolume> labels = warp->warp_labels(s.phantom.labels);
  ASSERT_TRUE(labels.ok());
  EXPECT_EQ(labels->voxels(), s.phantom.labels.voxels());
  Result<IntensityVolume> ct = warp->warp_intensities(s.phantom.ct, Interpolation::kLinear);
  ASSERT_TRUE(ct.ok());
  for (int64_t v = 0; v < ct->voxel_count(); ++v) ASSERT_NEAR(ct->data()[v], s.phantom.ct.data()[v], 1e-3) << v;
  EXPECT_EQ(warp->stats().conflicted_voxels, 0);
  EXPECT_GT(warp->stats().covered_voxels, 0);
  for (const float d : warp->inverse_displacement()) ASSERT_NEAR(d, 0.0f, 1e-6f);
}

TEST(TetWarp, RigidRootMotionAgreesWithItksResampler) {
  const Scene& s = bar_scene();
  const ImageGeometry& g = s.phantom.labels.geometry();
  const Eigen::Matrix3d r = Eigen::AngleAxisd(25.0 * M_PI / 180.0, Eigen::Vector3d(1, 0.3, 0.2).normalized()).toRotationMatrix();
  const Eigen::Vector3d t(4.0, -3.0, 6.0);
  const Eigen::MatrixXd posed = (s.mesh.vertices * r.transpose()).rowwise() + t.transpose();
  Result<ImageGeometry> out = output_geometry(GridPolicy::kGrow, g, posed, nullptr, {});
  ASSERT_TRUE(out.ok());
  Result<TetWarp> warp = TetWarp::build(s.mesh, s.topology, posed, g, *out, r, t, &s.rest_coverage, {}, {});
  ASSERT_TRUE(warp.ok());
  Result<LabelVolume> ours = warp->warp_labels(s.phantom.labels);
  std::array<double, 9> rotation{};
  for (int i = 0; i < 9; ++i) rotation[static_cast<size_t>(i)] = r(i / 3, i % 3);
  Result<LabelVolume> itk = io::itk_resample_rigid_labels(s.phantom.labels, rotation, {t(0), t(1), t(2)}, *out);
  ASSERT_TRUE(ours.ok() && itk.ok()) << itk.status().to_string();
  std::map<Label, int64_t> a, b, both;
  for (int64_t v = 0; v < ours->voxel_count(); ++v) {
    ++a[ours->data()[v]];
    ++b[itk->data()[v]];
    if (ours->data()[v] == itk->data()[v]) ++both[ours->data()[v]];
  }
  for (const auto& [label, count] : b) {
    if (label == 0 || count < 100) continue;
    const double dice = 2.0 * static_cast<double>(both[label]) / static_cast<double>(a[label] + count);
    EXPECT_GE(dice, 0.99) << "label " << label;
  }
}

TEST(TetWarp, WarpedLabelsAreAlwaysInputLabels) {
  const Scene& s = bar_scene();
  const ImageGeometry& g = s.phantom.labels.geometry();
  // A non-rigid deformation: shear the upper half.
  Eigen::MatrixXd posed = s.mesh.vertices;
  for (int64_t v = 0; v < posed.rows(); ++v) posed(v, 0) += 0.2 * std::max(0.0, posed(v, 2) - 60.0);
  Result<TetWarp> warp = TetWarp::build(s.mesh, s.topology, posed, g, g, Eigen::Matrix3d::Identity(),
                                        Eigen::Vector3d::Zero(), &s.rest_coverage, {}, {});
  ASSERT_TRUE(warp.ok());
  Result<LabelVolume> labels = warp->warp_labels(s.phantom.labels);
  const std::set<Label> before(s.phantom.labels.voxels().begin(), s.phantom.labels.voxels().end());
  const std::set<Label> after(labels->voxels().begin(), labels->voxels().end());
  for (const Label l : after) EXPECT_TRUE(before.count(l)) << "new label " << l;
  // Where the body moved away, no ghost is left behind: far from the sheared top, the rest position is empty.
  EXPECT_GT(warp->stats().background_voxels, 0);
}

TEST(TetWarp, FoldsLetBonesWinAndAreCounted) {
  // Two tets that cover the same region after posing: soft tissue (index 0) and bone (index 1).
  TetMesh mesh;
  mesh.vertices.resize(8, 3);
  mesh.vertices << 0, 0, 0, 6, 0, 0, 0, 6, 0, 0, 0, 6,  //
      10, 10, 10, 16, 10, 10, 10, 16, 10, 10, 10, 16;
  mesh.tets.resize(2, 4);
  mesh.tets << 0, 1, 2, 3, 4, 5, 6, 7;
  mesh.tet_class.resize(2);
  mesh.tet_class << 1, 2;
  mesh.segment_count = 1;
  Eigen::MatrixXd posed = mesh.vertices;
  posed.bottomRows(4).rowwise() -= Eigen::RowVector3d(10, 10, 10);  // the bone tet folds onto the soft one
  ImageGeometry g;
  g.size = {20, 20, 20};
  LabelVolume labels(g, 0);
  labels.at(1, 1, 1) = 5;    // soft tissue
  labels.at(11, 11, 11) = 7; // bone
  Result<TetWarp> warp = TetWarp::build(mesh, rest_topology(mesh), posed, g, g, Eigen::Matrix3d::Identity(),
                                        Eigen::Vector3d::Zero(), nullptr, {}, {});
  ASSERT_TRUE(warp.ok());
  EXPECT_GT(warp->stats().conflicted_voxels, 0);
  Result<LabelVolume> out = warp->warp_labels(labels);
  EXPECT_EQ(out->at(1, 1, 1), 7);
}

TEST(OutputGrid, GrowsToHoldTheBodyAndRefusesAbsurdGrids) {
  const Scene& s = bar_scene();
  const ImageGeometry& g = s.phantom.labels.geometry();
  Eigen::MatrixXd posed = s.mesh.vertices;
  posed.col(0).array() += 100.0;
  Result<ImageGeometry> grown = output_geometry(GridPolicy::kGrow, g, posed, nullptr, {});
  ASSERT_TRUE(grown.ok());
  EXPECT_GT(grown->size[0], g.size[0]);
  for (int64_t v = 0; v < posed.rows(); ++v) {
    const Vec3 u = grown->physical_to_index({posed(v, 0), posed(v, 1), posed(v, 2)});
    for (int a = 0; a < 3; ++a) {
      ASSERT_GE(u[a], -0.5);
      ASSERT_LE(u[a], grown->size[a] - 0.5);
    }
  }
  ImageGeometry huge = g;
  huge.size = {60000, 60000, 60000};
  EXPECT_EQ(output_geometry(GridPolicy::kGiven, g, posed, &huge, {}).status().code(), StatusCode::kResourceExhausted);
  Eigen::MatrixXd far = s.mesh.vertices;
  far.col(2).array() += 1e7;
  EXPECT_EQ(output_geometry(GridPolicy::kGrow, g, far, nullptr, {}).status().code(), StatusCode::kInvalidArgument);
}

}  // namespace
}  // namespace posewarp::resample
