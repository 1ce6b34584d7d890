#include "posewarp/resample/tet_warp.h"

#include <gtest/gtest.h>

#include <Eigen/Geometry>

#include <bit>
#include <cmath>
#include <iostream>
#include <limits>
#include <map>
#include <set>

#include "posewarp/common/compact_intensities.h"
#include "posewarp/common/parallel.h"
#include "posewarp/io/itk_reference.h"
#include "posewarp/labels/body.h"
#include "posewarp/mesh/mesher.h"
#include "posewarp/phantom/phantom.h"
#include "posewarp/resample/rigid_bones.h"

namespace posewarp::resample {
namespace {

struct Scene {
  phantom::Phantom phantom;
  TetMesh mesh;
  std::vector<int32_t> rest_owner;  // the identity warp's owner(), as a rig file holds it
  RowPacked<int32_t> packed_owner;  // as a rig's engine keeps it
};

// The bar phantom, meshed, with its rest ownership computed once (as a rig does).
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
    const ImageGeometry& g = s.phantom.labels.geometry();
    Result<TetWarp> identity = TetWarp::build({.rest = s.mesh, .posed = s.mesh.vertices, .source = g, .output = g});
    s.rest_owner = identity->owner();
    s.packed_owner = RowPacked<int32_t>::pack(s.rest_owner.data(), g.size, -1);
    return s;
  }();
  return scene;
}

TEST(TetWarp, IdentityPoseGivesBackTheInputVoxelForVoxel) {
  const Scene& s = bar_scene();
  const ImageGeometry& g = s.phantom.labels.geometry();
  // With the rest owner no tet moves and nothing is rasterized; without it every tet is.
  for (const RowPacked<int32_t>* rest_owner : {&s.packed_owner, static_cast<const RowPacked<int32_t>*>(nullptr)}) {
    SCOPED_TRACE(rest_owner ? "with rest owner" : "every tet rasterized");
    Result<TetWarp> warp =
        TetWarp::build({.rest = s.mesh, .posed = s.mesh.vertices, .source = g, .output = g, .rest_owner = rest_owner});
    ASSERT_TRUE(warp.ok()) << warp.status().to_string();
    EXPECT_EQ(warp->rasterized_tets(), rest_owner ? 0 : s.mesh.tet_count());
    Result<LabelVolume> labels = warp->warp_labels(s.phantom.labels);
    ASSERT_TRUE(labels.ok());
    EXPECT_EQ(labels->voxels(), s.phantom.labels.voxels());
    Result<IntensityVolume> ct = warp->warp_intensities(s.phantom.ct, Interpolation::kLinear);
    ASSERT_TRUE(ct.ok());
    for (int64_t v = 0; v < ct->voxel_count(); ++v) ASSERT_NEAR(ct->data()[v], s.phantom.ct.data()[v], 1e-3) << v;
    EXPECT_EQ(warp->stats().conflicted_voxels, 0);
    EXPECT_GT(warp->stats().covered_voxels, 0);
    EXPECT_EQ(warp->stats().background_voxels + warp->stats().covered_voxels + warp->stats().extrapolated_voxels,
              g.voxel_count());
    for (const float d : warp->inverse_displacement()) ASSERT_NEAR(d, 0.0f, 1e-6f);
  }
}

TEST(TetWarp, RigidRootMotionAgreesWithItksResampler) {
  const Scene& s = bar_scene();
  const ImageGeometry& g = s.phantom.labels.geometry();
  const Eigen::Matrix3d r =
      Eigen::AngleAxisd(25.0 * M_PI / 180.0, Eigen::Vector3d(1, 0.3, 0.2).normalized()).toRotationMatrix();
  const Eigen::Vector3d t(4.0, -3.0, 6.0);
  const Eigen::MatrixXd posed = (s.mesh.vertices * r.transpose()).rowwise() + t.transpose();
  Result<ImageGeometry> out = output_geometry(GridPolicy::kGrow, g, posed, nullptr, {});
  ASSERT_TRUE(out.ok());
  std::array<double, 9> rotation{};
  for (int i = 0; i < 9; ++i) rotation[static_cast<size_t>(i)] = r(i / 3, i % 3);
  Result<LabelVolume> itk = io::itk_resample_rigid_labels(s.phantom.labels, rotation, {t(0), t(1), t(2)}, *out);
  ASSERT_TRUE(itk.ok()) << itk.status().to_string();
  for (const RowPacked<int32_t>* rest_owner : {&s.packed_owner, static_cast<const RowPacked<int32_t>*>(nullptr)}) {
    SCOPED_TRACE(rest_owner ? "with rest owner" : "every tet rasterized");
    Result<TetWarp> warp = TetWarp::build({.rest = s.mesh,
                                           .posed = posed,
                                           .source = g,
                                           .output = *out,
                                           .background_rotation = r,
                                           .background_translation = t,
                                           .rest_owner = rest_owner});
    ASSERT_TRUE(warp.ok());
    Result<LabelVolume> ours = warp->warp_labels(s.phantom.labels);
    ASSERT_TRUE(ours.ok());
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
}

// A moved root on the study's own grid: every voxel samples through the root's map, runs of them across the source
// rows and off its edges (the unchecked span inside the grid, checked voxels at its ends). Each voxel is what the map
// says, worked out here voxel by voxel: the nearest label, the trilinear CT, the background outside the source, and
// the warp's counts from the rest owner of that nearest voxel (the classification's own walk across the rows).
TEST(TetWarp, AMovedRootSamplesEveryVoxelWhereItsMapTakesIt) {
  const Scene& s = bar_scene();
  const ImageGeometry& g = s.phantom.labels.geometry();
  const Eigen::Matrix3d r =
      Eigen::AngleAxisd(7.0 * M_PI / 180.0, Eigen::Vector3d(0.2, 0.3, 1).normalized()).toRotationMatrix();
  const Eigen::Vector3d t(6.3, -4.1, 2.7);
  const Eigen::MatrixXd posed = (s.mesh.vertices * r.transpose()).rowwise() + t.transpose();
  ResampleParams params;
  params.intensity_background = -1000.0f;
  Result<TetWarp> warp = TetWarp::build({.rest = s.mesh,
                                         .posed = posed,
                                         .source = g,
                                         .output = g,
                                         .background_rotation = r,
                                         .background_translation = t,
                                         .rest_owner = &s.packed_owner,
                                         .params = params});
  ASSERT_TRUE(warp.ok()) << warp.status().to_string();
  EXPECT_EQ(warp->rasterized_tets(), 0);
  Result<LabelVolume> labels = warp->warp_labels(s.phantom.labels);
  Result<IntensityVolume> ct = warp->warp_intensities(s.phantom.ct, Interpolation::kLinear);
  ASSERT_TRUE(labels.ok() && ct.ok());
  const Index3& m = g.size;
  int64_t inside = 0, outside = 0, covered = 0, extrapolated = 0;
  for (int64_t k = 0; k < m[2]; ++k) {
    for (int64_t j = 0; j < m[1]; ++j) {
      for (int64_t i = 0; i < m[0]; ++i) {
        const Vec3 x = g.index_to_physical({double(i), double(j), double(k)});
        const Eigen::Vector3d rest = r.transpose() * (Eigen::Vector3d(x[0], x[1], x[2]) - t);
        const Vec3 u = g.physical_to_index({rest.x(), rest.y(), rest.z()});
        const int64_t v = g.offset(i, j, k);
        const int64_t n[3] = {std::llround(u[0]), std::llround(u[1]), std::llround(u[2])};
        if (n[0] < 0 || n[1] < 0 || n[2] < 0 || n[0] >= m[0] || n[1] >= m[1] || n[2] >= m[2]) {
          ++outside;
          ASSERT_EQ(labels->data()[v], 0) << i << " " << j << " " << k;
          continue;
        }
        ++inside;
        ASSERT_EQ(labels->data()[v], s.phantom.labels.at(n[0], n[1], n[2])) << i << " " << j << " " << k;
        const int32_t rest_owner = s.rest_owner[static_cast<size_t>(g.offset(n[0], n[1], n[2]))];
        covered += rest_owner >= 0 ? 1 : 0;
        extrapolated += rest_owner <= -2 && rest_owner != TetWarp::kNoSample ? 1 : 0;
        if (u[0] < 0 || u[1] < 0 || u[2] < 0 || u[0] >= double(m[0] - 1) || u[1] >= double(m[1] - 1) ||
            u[2] >= double(m[2] - 1)) {
          continue;  // the CT's edge voxels clamp: checked by the ITK comparison above
        }
        const int64_t b[3] = {int64_t(u[0]), int64_t(u[1]), int64_t(u[2])};
        const double f[3] = {u[0] - double(b[0]), u[1] - double(b[1]), u[2] - double(b[2])};
        double value = 0.0;
        for (int corner = 0; corner < 8; ++corner) {
          const int c[3] = {corner & 1, (corner >> 1) & 1, (corner >> 2) & 1};
          double w = 1.0;
          for (int a = 0; a < 3; ++a) w *= c[a] ? f[a] : 1.0 - f[a];
          value += w * s.phantom.ct.at(b[0] + c[0], b[1] + c[1], b[2] + c[2]);
        }
        ASSERT_NEAR(ct->data()[v], value, 1e-2) << i << " " << j << " " << k;
      }
    }
  }
  EXPECT_GT(inside, g.voxel_count() / 2);
  EXPECT_GT(outside, 0);
  EXPECT_EQ(warp->stats().covered_voxels, covered);
  EXPECT_EQ(warp->stats().extrapolated_voxels, extrapolated);
  EXPECT_GT(extrapolated, 0);
  EXPECT_EQ(warp->stats().background_voxels, g.voxel_count() - covered - extrapolated);
}

// Row spans (row_spans): outside each row's span every voxel holds the fill, the span's ends do not; a box is only
// fill where none of its rows' spans meets it.
TEST(RowSpans, BoundEachRowsOtherValuesAndAnswerForBoxes) {
  const Scene& s = bar_scene();
  const LabelVolume& labels = s.phantom.labels;
  const Index3& m = labels.size();
  const RowSpans spans = row_spans(labels.data(), m, 0);
  ASSERT_EQ(spans.span.size(), static_cast<size_t>(m[1] * m[2]));
  int64_t on = 0, empty_rows = 0;
  for (int64_t z = 0; z < m[2]; ++z) {
    for (int64_t y = 0; y < m[1]; ++y) {
      const uint32_t span = spans.span[static_cast<size_t>(y + m[1] * z)];
      const int64_t lo = span & 0xffff, hi = span >> 16;
      ASSERT_LE(lo, hi);
      ASSERT_LE(hi, m[0]);
      empty_rows += lo == hi ? 1 : 0;
      on += hi - lo;
      if (lo < hi) {
        EXPECT_NE(labels.at(lo, y, z), 0);
        EXPECT_NE(labels.at(hi - 1, y, z), 0);
      }
      for (int64_t x = 0; x < m[0]; ++x) {
        if (x < lo || x >= hi) {
          ASSERT_EQ(labels.at(x, y, z), 0) << x << " " << y << " " << z;
        }
      }
      const int64_t row_lo[3] = {0, y, z}, row_hi[3] = {m[0] - 1, y, z};
      EXPECT_EQ(spans.only_fill(row_lo, row_hi), lo == hi);
      if (lo > 0) {
        const int64_t before_hi[3] = {lo - 1, y, z};
        EXPECT_TRUE(spans.only_fill(row_lo, before_hi));
      }
    }
  }
  // The bar lies in air: the spans leave most of the grid out, so the warp's skipping is exercised below.
  EXPECT_GT(empty_rows, 0);
  EXPECT_LT(on, labels.voxel_count() / 2);
  const int64_t off_lo[3] = {-5, -5, -5}, off_hi[3] = {-1, -1, -1};
  EXPECT_TRUE(spans.only_fill(off_lo, off_hi));  // off the grid
  const int64_t all_lo[3] = {0, 0, 0}, all_hi[3] = {m[0] - 1, m[1] - 1, m[2] - 1};
  EXPECT_FALSE(spans.only_fill(all_lo, all_hi));
  EXPECT_FALSE(RowSpans{}.only_fill(all_lo, all_hi));  // no spans: nothing is known
}

// A table packed on its rows' spans answers for every voxel as the grid it packs, in a fraction of its bytes (the bar
// lies in air), and so does one kept in whole rows; each row's span is the stretch between its first and last value
// other than the fill.
TEST(RowPacked, AnswersForEveryVoxelAsTheGridItPacks) {
  const Scene& s = bar_scene();
  const Index3& m = s.phantom.labels.size();
  const RowPacked<int32_t> packed = RowPacked<int32_t>::pack(s.rest_owner.data(), m, -1);
  const RowPacked<int32_t> whole = RowPacked<int32_t>::pack(s.rest_owner.data(), m, -1, true);
  EXPECT_EQ(packed.unpacked(), s.rest_owner);
  EXPECT_EQ(whole.unpacked(), s.rest_owner);
  EXPECT_LT(packed.bytes(), s.rest_owner.size() * sizeof(int32_t) / 2);
  EXPECT_FALSE(packed == whole);
  const RowSpans spans = row_spans(s.rest_owner.data(), m, -1);
  // The spans found before (as the warp's classification finds them) and the runs of a rig file give the same table.
  EXPECT_EQ(RowPacked<int32_t>::pack(s.rest_owner.data(), m, -1, false, spans.span.data()), packed);
  std::vector<int32_t> run_values;
  std::vector<uint32_t> run_lengths;
  for (const int32_t v : s.rest_owner) {
    if (!run_values.empty() && run_values.back() == v) {
      ++run_lengths.back();
    } else {
      run_values.push_back(v);
      run_lengths.push_back(1);
    }
  }
  EXPECT_EQ(RowPacked<int32_t>::from_runs(run_values.data(), run_lengths.data(), run_values.size(), m, -1), packed);
  for (int64_t z = 0; z < m[2]; ++z) {
    for (int64_t y = 0; y < m[1]; ++y) {
      int64_t lo = 0, hi = 0, whole_lo = 0, whole_hi = 0;
      const int32_t* span = packed.row(y, z, lo, hi);
      (void)whole.row(y, z, whole_lo, whole_hi);
      EXPECT_EQ(whole_lo, 0);
      EXPECT_EQ(whole_hi, m[0]);
      const uint32_t expected = spans.span[static_cast<size_t>(y + m[1] * z)];
      if (expected == 0) {
        EXPECT_EQ(lo, hi);
      } else {
        EXPECT_EQ(lo, expected & 0xffff);
        EXPECT_EQ(hi, expected >> 16);
      }
      for (int64_t x = 0; x < m[0]; ++x) {
        const int32_t value = s.rest_owner[static_cast<size_t>(x + m[0] * (y + m[1] * z))];
        ASSERT_EQ(packed.at(x, y, z), value) << x << " " << y << " " << z;
        ASSERT_EQ(whole.at(x, y, z), value);
        if (x >= lo && x < hi) {
          ASSERT_EQ(span[x - lo], value);
        }
      }
      const int64_t row_lo[3] = {0, y, z}, row_hi[3] = {m[0] - 1, y, z};
      EXPECT_EQ(packed.only_fill(row_lo, row_hi), lo == hi);
    }
  }
  const std::vector<int16_t> regions(static_cast<size_t>(m[0] * m[1] * m[2]), int16_t{-1});
  const RowPacked<int16_t> nothing = RowPacked<int16_t>::pack(regions.data(), m, int16_t{-1});
  EXPECT_EQ(nothing.bytes(), static_cast<size_t>(m[1] * m[2]) * sizeof(uint64_t));  // the rows' entries alone
  EXPECT_EQ(nothing.at(m[0] / 2, m[1] / 2, m[2] / 2), -1);
}

// Where the root moved, the warp with the rest owners packed on their rows' spans, and the labels' row spans, is the
// warp with every row kept whole and no spans, owner for owner and label for label; label spans that lie (every row
// empty) are followed, so they are used; tables of another grid or fill are refused.
TEST(TetWarp, RowSpansChangeNothingButTheLoadsWhereTheRootMoved) {
  const Scene& s = bar_scene();
  const ImageGeometry& g = s.phantom.labels.geometry();
  const Eigen::Matrix3d r =
      Eigen::AngleAxisd(7.0 * M_PI / 180.0, Eigen::Vector3d(0.2, 0.3, 1).normalized()).toRotationMatrix();
  const Eigen::Vector3d t(6.3, -4.1, 2.7);
  const Eigen::MatrixXd posed = (s.mesh.vertices * r.transpose()).rowwise() + t.transpose();
  const RowPacked<int32_t> whole_rows = RowPacked<int32_t>::pack(s.rest_owner.data(), g.size, -1, true);
  const RowSpans label_spans = row_spans(s.phantom.labels.data(), g.size, 0);
  auto warp_with = [&](const RowPacked<int32_t>* owners) {
    return TetWarp::build({.rest = s.mesh,
                           .posed = posed,
                           .source = g,
                           .output = g,
                           .background_rotation = r,
                           .background_translation = t,
                           .rest_owner = owners});
  };
  Result<TetWarp> plain = warp_with(&whole_rows), spanned = warp_with(&s.packed_owner);
  ASSERT_TRUE(plain.ok() && spanned.ok());
  EXPECT_EQ(plain->owner(), spanned->owner());
  EXPECT_EQ(plain->stats().background_voxels, spanned->stats().background_voxels);
  EXPECT_EQ(plain->stats().covered_voxels, spanned->stats().covered_voxels);
  EXPECT_EQ(plain->stats().extrapolated_voxels, spanned->stats().extrapolated_voxels);
  Result<LabelVolume> labels = plain->warp_labels(s.phantom.labels);
  Result<LabelVolume> labels_spanned = spanned->warp_labels(s.phantom.labels, nullptr, &label_spans);
  ASSERT_TRUE(labels.ok() && labels_spanned.ok());
  EXPECT_EQ(labels->voxels(), labels_spanned->voxels());

  RowSpans lying = label_spans;  // every row said to be all background
  std::fill(lying.span.begin(), lying.span.end(), 0u);
  Result<LabelVolume> lied = plain->warp_labels(s.phantom.labels, nullptr, &lying);
  ASSERT_TRUE(lied.ok());
  EXPECT_NE(labels->voxels(), lied->voxels());

  RowSpans other = label_spans;
  other.size = {g.size[0], g.size[1], g.size[2] + 1};
  EXPECT_EQ(plain->warp_labels(s.phantom.labels, nullptr, &other).status().code(), StatusCode::kInvalidArgument);
  const std::vector<int32_t> longer(s.rest_owner.size() + static_cast<size_t>(g.size[0] * g.size[1]), -1);
  const RowPacked<int32_t> another_grid =
      RowPacked<int32_t>::pack(longer.data(), {g.size[0], g.size[1], g.size[2] + 1}, -1);
  EXPECT_EQ(warp_with(&another_grid).status().code(), StatusCode::kInvalidArgument);
  const RowPacked<int32_t> another_fill = RowPacked<int32_t>::pack(s.rest_owner.data(), g.size, 0);
  EXPECT_EQ(warp_with(&another_fill).status().code(), StatusCode::kInvalidArgument);
}

TEST(TetWarp, WarpedLabelsAreAlwaysInputLabels) {
  const Scene& s = bar_scene();
  const ImageGeometry& g = s.phantom.labels.geometry();
  // A non-rigid deformation: shear the upper half.
  Eigen::MatrixXd posed = s.mesh.vertices;
  for (int64_t v = 0; v < posed.rows(); ++v) posed(v, 0) += 0.2 * std::max(0.0, posed(v, 2) - 60.0);
  Result<TetWarp> warp =
      TetWarp::build({.rest = s.mesh, .posed = posed, .source = g, .output = g, .rest_owner = &s.packed_owner});
  ASSERT_TRUE(warp.ok());
  Result<LabelVolume> labels = warp->warp_labels(s.phantom.labels);
  const std::set<Label> before(s.phantom.labels.voxels().begin(), s.phantom.labels.voxels().end());
  const std::set<Label> after(labels->voxels().begin(), labels->voxels().end());
  for (const Label l : after) EXPECT_TRUE(before.count(l)) << "new label " << l;
  // Where the body moved away, no ghost is left behind: far from the sheared top, the rest position is empty.
  EXPECT_GT(warp->stats().background_voxels, 0);
}

// Two disjoint tets: soft tissue (index 0) at the origin and bone (index 1) at (10, 10, 10), and a 20^3 label
// volume marking one voxel of each.
TetMesh soft_and_bone_tets() {
  TetMesh mesh;
  mesh.vertices.resize(8, 3);
  mesh.vertices << 0, 0, 0, 6, 0, 0, 0, 6, 0, 0, 0, 6,  //
      10, 10, 10, 16, 10, 10, 10, 16, 10, 10, 10, 16;
  mesh.tets.resize(2, 4);
  mesh.tets << 0, 1, 2, 3, 4, 5, 6, 7;
  mesh.tet_class.resize(2);
  mesh.tet_class << 1, 2;
  mesh.segment_count = 1;
  return mesh;
}

LabelVolume soft_and_bone_labels(const ImageGeometry& g) {
  LabelVolume labels(g, 0);
  labels.at(1, 1, 1) = 5;     // soft tissue
  labels.at(11, 11, 11) = 7;  // bone
  return labels;
}

TEST(TetWarp, FoldsLetBonesWinAndAreCounted) {
  // Two tets that cover the same region after posing: soft tissue (index 0) and bone (index 1).
  const TetMesh mesh = soft_and_bone_tets();
  Eigen::MatrixXd posed = mesh.vertices;
  posed.bottomRows(4).rowwise() -= Eigen::RowVector3d(10, 10, 10);  // the bone tet folds onto the soft one
  ImageGeometry g;
  g.size = {20, 20, 20};
  const LabelVolume labels = soft_and_bone_labels(g);
  Result<TetWarp> warp = TetWarp::build({.rest = mesh, .posed = posed, .source = g, .output = g});
  ASSERT_TRUE(warp.ok());
  EXPECT_GT(warp->stats().conflicted_voxels, 0);
  Result<LabelVolume> out = warp->warp_labels(labels);
  EXPECT_EQ(out->at(1, 1, 1), 7);
}

TEST(TetWarp, AMovingSoftTetFoldedOntoAStillBoneLosesAndLeavesNoGhost) {
  // The soft tet (index 0) moves onto the bone tet (index 1), which follows the background and is not rasterized.
  const TetMesh mesh = soft_and_bone_tets();
  ImageGeometry g;
  g.size = {20, 20, 20};
  const LabelVolume labels = soft_and_bone_labels(g);
  Result<TetWarp> identity = TetWarp::build({.rest = mesh, .posed = mesh.vertices, .source = g, .output = g});
  ASSERT_TRUE(identity.ok());
  const RowPacked<int32_t> rest_owner = RowPacked<int32_t>::pack(identity->owner().data(), g.size, -1);
  Eigen::MatrixXd posed = mesh.vertices;
  posed.topRows(4).rowwise() += Eigen::RowVector3d(10, 10, 10);
  Result<TetWarp> warp =
      TetWarp::build({.rest = mesh, .posed = posed, .source = g, .output = g, .rest_owner = &rest_owner});
  ASSERT_TRUE(warp.ok());
  EXPECT_EQ(warp->rasterized_tets(), 1);
  EXPECT_GT(warp->stats().conflicted_voxels, 0);
  Result<LabelVolume> out = warp->warp_labels(labels);
  EXPECT_EQ(out->at(11, 11, 11), 7);  // the bone wins its own place
  EXPECT_EQ(out->at(1, 1, 1), 0);     // where the soft tet was, nothing is copied
}

TEST(TetWarp, SkippingStillTetsChangesNothingButTheWork) {
  const Scene& s = bar_scene();
  const ImageGeometry& g = s.phantom.labels.geometry();
  // Shear the upper half only: the lower half follows the (identity) background.
  Eigen::MatrixXd posed = s.mesh.vertices;
  for (int64_t v = 0; v < posed.rows(); ++v) posed(v, 0) += 0.2 * std::max(0.0, posed(v, 2) - 60.0);
  Result<TetWarp> full = TetWarp::build({.rest = s.mesh, .posed = posed, .source = g, .output = g});
  Result<TetWarp> lean =
      TetWarp::build({.rest = s.mesh, .posed = posed, .source = g, .output = g, .rest_owner = &s.packed_owner});
  ASSERT_TRUE(full.ok() && lean.ok());
  EXPECT_GT(lean->rasterized_tets(), 0);
  EXPECT_LT(lean->rasterized_tets(), s.mesh.tet_count());
  Result<LabelVolume> a = full->warp_labels(s.phantom.labels);
  Result<LabelVolume> b = lean->warp_labels(s.phantom.labels);
  ASSERT_TRUE(a.ok() && b.ok());
  // Without a rest owner, a voxel outside every posed tet is copied through the background (identity) map even
  // where the body moved away; the rest owner is what removes that ghost.
  const std::vector<int32_t> full_owner = full->owner();
  int64_t body = 0, differ = 0;
  for (int64_t v = 0; v < g.voxel_count(); ++v) {
    const Label expected =
        full_owner[static_cast<size_t>(v)] == -1 && s.rest_owner[static_cast<size_t>(v)] != -1 ? 0 : a->data()[v];
    body += expected != 0;
    differ += expected != b->data()[v];
  }
  std::cout << "labels differ in " << differ << " of " << body << " body voxels\n";
  EXPECT_LE(differ, body / 1000);
  // The body's extent agrees to a few shell voxels (a still tet's rest shell now wins over a moving tet's shell).
  EXPECT_NEAR(static_cast<double>(full->stats().covered_voxels + full->stats().extrapolated_voxels),
              static_cast<double>(lean->stats().covered_voxels + lean->stats().extrapolated_voxels), 1e-3 * body);
}

// The bar's last bone turned 4 degrees about its centre on top of a background (root) motion, `background_turn`
// degrees about the body's centre, that the mesh and every other bone follow: the background shows that bone's rest
// voxels the turned bone left (each off by its own distance), the bone's own map claims the rest exactly (deviation 0).
// Checks warp_labels' deviation against a per-voxel reference.
struct Deviations {
  std::vector<std::vector<float>> all;              // per segment, the reference's deviations (mm)
  std::vector<std::pair<double, double>> reported;  // per segment, warp_labels' {max, 99th percentile}
};
Deviations expect_bone_deviation_as_reference(double background_turn) {
  const Scene& s = bar_scene();
  const ImageGeometry& g = s.phantom.labels.geometry();
  std::vector<std::vector<Label>> segment_labels;
  for (const labels::LabelEntry& e : s.phantom.label_map.entries()) {
    if (e.role == labels::LabelRole::kBone) segment_labels.push_back({e.value});
  }
  EXPECT_GE(segment_labels.size(), 2u);
  Result<BoneVoxels> voxels = bone_voxels(s.phantom.labels, segment_labels);
  EXPECT_TRUE(voxels.ok());
  if (segment_labels.size() < 2 || !voxels.ok()) return {};
  const size_t moved = segment_labels.size() - 1;
  auto centre_of = [&](const std::array<int64_t, 6>& box) {
    const Vec3 c = g.index_to_physical(
        {0.5 * double(box[0] + box[3]), 0.5 * double(box[1] + box[4]), 0.5 * double(box[2] + box[5])});
    return Eigen::Vector3d(c[0], c[1], c[2]);
  };
  const Eigen::Vector3d middle = centre_of({0, 0, 0, g.size[0] - 1, g.size[1] - 1, g.size[2] - 1});
  const Eigen::Matrix3d root =
      Eigen::AngleAxisd(background_turn * M_PI / 180.0, Eigen::Vector3d(0.3, 0.2, 1.0).normalized()).toRotationMatrix();
  const Eigen::Vector3d root_shift = middle - root * middle + Eigen::Vector3d(1.3, -0.7, 0.4);
  const Eigen::Vector3d centre = centre_of(voxels->box[moved]);
  RigidBones bones;
  bones.voxels = &*voxels;
  bones.rotation.assign(segment_labels.size(), root);
  bones.translation.assign(segment_labels.size(), root_shift);
  const Eigen::Matrix3d turn = Eigen::AngleAxisd(4.0 * M_PI / 180.0, Eigen::Vector3d::UnitX()).toRotationMatrix();
  bones.rotation[moved] = root * turn;
  bones.translation[moved] = root * (centre - turn * centre) + root_shift;
  const Eigen::MatrixXd posed = (s.mesh.vertices * root.transpose()).rowwise() + root_shift.transpose();
  Result<TetWarp> warp = TetWarp::build({.rest = s.mesh,
                                         .posed = posed,
                                         .source = g,
                                         .output = g,
                                         .background_rotation = root,
                                         .background_translation = root_shift,
                                         .rest_owner = &s.packed_owner,
                                         .bones = &bones});
  EXPECT_TRUE(warp.ok());
  if (!warp.ok()) return {};
  // The reference: every output voxel a bone or the background maps onto a bone's source voxel, the distance (mm)
  // between that source point and where the bone's own inverse takes the voxel; max and 99th percentile over all of
  // them, zeros included.
  auto inverse = [&](size_t segment, const Eigen::Vector3d& x) -> Eigen::Vector3d {
    return bones.rotation[segment].transpose() * (x - bones.translation[segment]);
  };
  const std::vector<int32_t> owner = warp->owner();
  std::vector<std::vector<float>> all(segment_labels.size());
  for (int64_t k = 0; k < g.size[2]; ++k) {
    for (int64_t j = 0; j < g.size[1]; ++j) {
      for (int64_t i = 0; i < g.size[0]; ++i) {
        const int32_t o = owner[static_cast<size_t>(g.offset(i, j, k))];
        if (o != -1 && !TetWarp::is_bone_owner(o)) continue;
        const Vec3 p = g.index_to_physical({double(i), double(j), double(k)});
        const Eigen::Vector3d x(p[0], p[1], p[2]);
        const Eigen::Vector3d from =
            o == -1 ? root.transpose() * (x - root_shift) : inverse(static_cast<size_t>(o - TetWarp::kBoneOwner), x);
        const Vec3 u = g.physical_to_index({from.x(), from.y(), from.z()});
        const int64_t si = std::llround(u[0]), sj = std::llround(u[1]), sk = std::llround(u[2]);
        if (!s.phantom.labels.contains(si, sj, sk)) continue;
        const int segment = voxels->segment_of(g.offset(si, sj, sk));
        if (segment < 0) continue;
        all[static_cast<size_t>(segment)].push_back(
            static_cast<float>((from - inverse(static_cast<size_t>(segment), x)).norm()));
      }
    }
  }
  std::vector<std::pair<double, double>> deviation;
  EXPECT_TRUE(warp->warp_labels(s.phantom.labels, &deviation).ok());
  EXPECT_EQ(deviation.size(), segment_labels.size());
  if (deviation.size() != segment_labels.size()) return {};
  for (size_t segment = 0; segment < all.size(); ++segment) {
    std::vector<float>& d = all[segment];
    if (d.empty()) continue;
    const size_t p99 = std::min(d.size() - 1, static_cast<size_t>(0.99 * static_cast<double>(d.size())));
    std::nth_element(d.begin(), d.begin() + static_cast<std::ptrdiff_t>(p99), d.end());
    EXPECT_NEAR(deviation[segment].second, d[p99], 1e-4) << "segment " << segment;
    EXPECT_NEAR(deviation[segment].first, *std::max_element(d.begin(), d.end()), 1e-4) << "segment " << segment;
  }
  return {all, deviation};
}

TEST(TetWarp, BoneDeviationCountsExactVoxelsAndFindsThePercentileOverAll) {
  const Deviations found = expect_bone_deviation_as_reference(0.0);
  ASSERT_FALSE(found.all.empty());
  const size_t moved = found.all.size() - 1;
  const std::vector<float>& turned = found.all[moved];
  const auto zeros = std::count(turned.begin(), turned.end(), 0.0f);
  EXPECT_GT(zeros, 0);  // the turned bone has exact voxels and deviations both
  EXPECT_LT(zeros, static_cast<std::ptrdiff_t>(turned.size()));
  EXPECT_GT(found.reported[moved].second, 0.0);
}

// The same where the root moved: the background's runs cross the source rows, the other bones follow it.
TEST(TetWarp, BoneDeviationFollowsTheLabelsWhereTheRootMoved) {
  const Deviations found = expect_bone_deviation_as_reference(3.0);
  ASSERT_FALSE(found.all.empty());
  const std::vector<std::vector<float>>& all = found.all;
  const std::vector<float>& turned = all.back();
  const auto zeros = std::count(turned.begin(), turned.end(), 0.0f);
  EXPECT_GT(zeros, 0);
  EXPECT_LT(zeros, static_cast<std::ptrdiff_t>(turned.size()));
  EXPECT_GT(found.reported.back().second, 0.0);
  for (size_t segment = 0; segment + 1 < all.size(); ++segment) {  // the bones that follow the root: exact
    EXPECT_FALSE(all[segment].empty()) << "segment " << segment;
    for (float d : all[segment]) EXPECT_LT(d, 1e-3f) << "segment " << segment;
  }
}

// Each bone voxel's segment is its label's, kept per bone voxel behind the rank index; each bone voxel's substitute
// is a voxel outside the bones; kept sparse (as a rig file keeps them) they give back the same table, and a sparse
// table naming a voxel that is no bone is refused as damage.
TEST(BoneVoxels, SubstitutesAreSoftVoxelsAndSurviveTheSparseFormTheRigKeeps) {
  const Scene& s = bar_scene();
  std::vector<std::vector<Label>> segment_labels;
  for (const labels::LabelEntry& e : s.phantom.label_map.entries()) {
    if (e.role == labels::LabelRole::kBone) segment_labels.push_back({e.value});
  }
  Result<BoneVoxels> bones = bone_voxels(s.phantom.labels, segment_labels);
  ASSERT_TRUE(bones.ok()) << bones.status().to_string();
  ASSERT_GT(bones->bone_voxels, 1000);
  ASSERT_EQ(bones->substitute.size(), static_cast<size_t>(bones->bone_voxels));
  ASSERT_EQ(bones->voxel_count, s.phantom.labels.voxel_count());
  ASSERT_EQ(bones->bone_segment.size(), static_cast<size_t>(bones->bone_voxels));
  int64_t seen = 0, first_soft = -1;
  std::set<int> segments_seen;
  for (int64_t v = 0; v < bones->voxel_count; ++v) {
    int expected = BoneVoxels::kNone;
    for (size_t k = 0; k < segment_labels.size(); ++k) {
      if (segment_labels[k].front() == s.phantom.labels.data()[v]) expected = static_cast<int>(k);
    }
    ASSERT_EQ(bones->segment_of(v), expected) << "voxel " << v;
    ASSERT_EQ(bones->is_bone(v), expected != BoneVoxels::kNone) << "voxel " << v;
    if (expected == BoneVoxels::kNone) {
      if (first_soft < 0) first_soft = v;
      continue;
    }
    segments_seen.insert(expected);
    const int32_t substitute = bones->substitute_of(v);
    ASSERT_EQ(bones->rank_of(v), static_cast<size_t>(seen++));
    ASSERT_FALSE(bones->is_bone(substitute)) << "bone voxel " << v;
  }
  EXPECT_EQ(seen, bones->bone_voxels);
  EXPECT_EQ(segments_seen.size(), segment_labels.size());  // every bone's voxels, not one bone's for all
  for (const uint64_t word : {uint64_t{0}, ~uint64_t{0}, uint64_t{0x8000000000000001}, uint64_t{0x0123456789abcdef}}) {
    EXPECT_EQ(count_bits(word), std::popcount(word)) << word;
  }
  const BoneSubstitutes sparse = bones->sparse();
  EXPECT_EQ(sparse.voxel.size(), static_cast<size_t>(bones->bone_voxels));  // no bone voxel is its own here
  Result<BoneVoxels> again = bone_voxels(s.phantom.labels, segment_labels, &sparse);
  ASSERT_TRUE(again.ok()) << again.status().to_string();
  EXPECT_EQ(again->substitute, bones->substitute);
  ASSERT_GE(first_soft, 0);
  ASSERT_LT(first_soft, sparse.voxel.front());
  BoneSubstitutes damaged = sparse;
  damaged.voxel.insert(damaged.voxel.begin(), static_cast<int32_t>(first_soft));
  damaged.substitute.insert(damaged.substitute.begin(), 0);
  const Status refused = bone_voxels(s.phantom.labels, segment_labels, &damaged).status();
  EXPECT_EQ(refused.code(), StatusCode::kDataLoss) << refused.to_string();
  EXPECT_NE(refused.message().find("no bone voxel"), std::string::npos) << refused.to_string();
}

TEST(TetWarp, TheSkinShellKeepsBodyVoxelsOutsideTheMeshAndRefusesAnAbsurdWidth) {
  const Scene& s = bar_scene();
  const ImageGeometry& g = s.phantom.labels.geometry();
  // Every tet rasterized: body voxels the mesh surface leaves out must come back through the shell, as labels.
  Result<TetWarp> warp = TetWarp::build({.rest = s.mesh, .posed = s.mesh.vertices, .source = g, .output = g});
  ASSERT_TRUE(warp.ok());
  EXPECT_GT(warp->stats().extrapolated_voxels, 0);
  const std::vector<int32_t> owner = warp->owner();
  int64_t body = 0, outside_mesh = 0;
  for (int64_t v = 0; v < g.voxel_count(); ++v) {
    if (s.phantom.labels.data()[v] == 0) continue;
    ++body;
    if (owner[static_cast<size_t>(v)] < 0) ++outside_mesh;
    EXPECT_NE(owner[static_cast<size_t>(v)], -1) << "body voxel " << v << " is neither in the mesh nor in its shell";
  }
  EXPECT_LT(outside_mesh, body / 10);
  ResampleParams wide;
  wide.shell_mm = 100.0;
  EXPECT_EQ(TetWarp::build({.rest = s.mesh, .posed = s.mesh.vertices, .source = g, .output = g, .params = wide})
                .status()
                .code(),
            StatusCode::kInvalidArgument);
  // The default shell follows each axis's spacing: thick slices (0.8 x 0.8 x 5 mm) and a much finer output grid
  // are not refused, and a far-away root moves the body off the grid without harm.
  ImageGeometry thick = g;
  thick.spacing = {0.8, 0.8, 5.0};
  ImageGeometry fine = g;
  fine.spacing = {g.spacing[0] / 6.0, g.spacing[1] / 6.0, g.spacing[2] / 6.0};
  fine.size = {8, 8, 8};
  for (const ImageGeometry* out : {&thick, &fine}) {
    EXPECT_TRUE(
        TetWarp::build({.rest = s.mesh, .posed = s.mesh.vertices, .source = out == &thick ? thick : g, .output = *out})
            .ok());
  }
  const Eigen::Vector3d far(0.0, 0.0, 3e9);
  const Eigen::MatrixXd moved = s.mesh.vertices.rowwise() + far.transpose();
  for (const Eigen::Vector3d& root : {far, Eigen::Vector3d(Eigen::Vector3d::Zero())}) {  // tets still, or all moving
    Result<TetWarp> away = TetWarp::build({.rest = s.mesh,
                                           .posed = moved,
                                           .source = g,
                                           .output = g,
                                           .background_translation = root,
                                           .rest_owner = &s.packed_owner});
    ASSERT_TRUE(away.ok());
    EXPECT_EQ(away->rasterized_tets(), root.isZero() ? s.mesh.tet_count() : 0);
    EXPECT_EQ(away->stats().covered_voxels, 0);
  }
}

// The skin shell voxel by voxel: an uncovered voxel takes a tet exactly when a covered voxel lies within its ellipsoid
// (two source voxels along each axis by default, so on the source's own grid every offset with di^2 + dj^2 + dk^2 <=
// 4), and the tet is one covering a nearest such voxel. The warp looks only near the covered voxels of the neighbour
// rows; this is the whole search it must agree with.
TEST(TetWarp, TheSkinShellTakesTheTetOfTheNearestCoveredVoxelWithinReach) {
  const Scene& s = bar_scene();
  const ImageGeometry& g = s.phantom.labels.geometry();
  Eigen::MatrixXd posed = s.mesh.vertices;  // the upper half sheared
  for (int64_t v = 0; v < posed.rows(); ++v) posed(v, 0) += 0.2 * std::max(0.0, posed(v, 2) - 60.0);
  Result<TetWarp> warp = TetWarp::build({.rest = s.mesh, .posed = posed, .source = g, .output = g});
  ASSERT_TRUE(warp.ok()) << warp.status().to_string();
  const std::vector<int32_t> owner = warp->owner();
  const Index3& n = g.size;
  int64_t shell = 0;
  for (int64_t k = 0; k < n[2]; ++k) {
    for (int64_t j = 0; j < n[1]; ++j) {
      for (int64_t i = 0; i < n[0]; ++i) {
        const int32_t o = owner[static_cast<size_t>(g.offset(i, j, k))];
        if (o >= 0) continue;
        double nearest = std::numeric_limits<double>::infinity();
        std::set<int32_t> nearest_tets;
        for (int64_t dk = -2; dk <= 2; ++dk) {
          for (int64_t dj = -2; dj <= 2; ++dj) {
            for (int64_t di = -2; di <= 2; ++di) {
              const int64_t x = i + di, y = j + dj, z = k + dk;
              if (di * di + dj * dj + dk * dk > 4 || x < 0 || y < 0 || z < 0 || x >= n[0] || y >= n[1] || z >= n[2])
                continue;
              const int32_t covering = owner[static_cast<size_t>(g.offset(x, y, z))];
              if (covering < 0) continue;
              const double d =
                  std::hypot(double(di) * g.spacing[0], double(dj) * g.spacing[1], double(dk) * g.spacing[2]);
              if (d < nearest - 1e-9) nearest = d, nearest_tets.clear();
              if (d <= nearest + 1e-9) nearest_tets.insert(covering);
            }
          }
        }
        if (nearest_tets.empty()) {
          ASSERT_EQ(o, -1) << i << " " << j << " " << k << ": in the shell with no covered voxel within reach";
          continue;
        }
        ++shell;
        ASSERT_LE(o, -2) << i << " " << j << " " << k << ": a covered voxel within reach, yet not in the shell";
        ASSERT_TRUE(nearest_tets.count(-2 - o)) << i << " " << j << " " << k << ": not a nearest covered voxel's tet";
      }
    }
  }
  EXPECT_GT(shell, 0);
  EXPECT_EQ(shell, warp->stats().extrapolated_voxels);
}

TEST(TetWarp, WarpsInsideAParallelLoopGiveWhatOneWarpGives) {
  // Warps keep raster buffers per thread; warps run from the tasks of a parallel loop, on several threads at once
  // (and, when the scheduler lets a waiting thread pick up another task, nested on one), must not share them.
  const Scene& s = bar_scene();
  const ImageGeometry& g = s.phantom.labels.geometry();
  auto posed_by = [&](double shear) {
    Eigen::MatrixXd posed = s.mesh.vertices;
    for (int64_t v = 0; v < posed.rows(); ++v) posed(v, 0) += shear * std::max(0.0, posed(v, 2) - 60.0);
    return posed;
  };
  auto warp_labels = [&](double shear) {
    Result<TetWarp> warp = TetWarp::build(
        {.rest = s.mesh, .posed = posed_by(shear), .source = g, .output = g, .rest_owner = &s.packed_owner});
    return std::move(warp->warp_labels(s.phantom.labels)).value().voxels();
  };
  constexpr int kWarps = 8;
  std::vector<VoxelVector<Label>> expected(kWarps), got(kWarps);
  for (int w = 0; w < kWarps; ++w) expected[static_cast<size_t>(w)] = warp_labels(0.05 * w);
  parallel_for(0, kWarps, 1, [&](int64_t begin, int64_t end) {
    for (int64_t w = begin; w < end; ++w) got[static_cast<size_t>(w)] = warp_labels(0.05 * static_cast<double>(w));
  });
  for (int w = 0; w < kWarps; ++w)
    EXPECT_EQ(got[static_cast<size_t>(w)], expected[static_cast<size_t>(w)]) << "warp " << w;
}

TEST(TetWarp, Int16IntensitiesWarpToTheBitsOfTheirFloats) {
  // The CT as a rig holds it (CompactIntensities: int16 where it fits) against the same values in floats, through a
  // turned and shifted root (runs across the source rows: the SSE2 and AVX2 loops, and the checked one at the
  // edges) with the upper half sheared on top (tet maps), trilinear and nearest.
  const Scene& s = bar_scene();
  const ImageGeometry& g = s.phantom.labels.geometry();
  IntensityVolume floats = s.phantom.ct;
  for (int64_t v = 0; v < floats.voxel_count(); ++v) floats.data()[v] = std::round(floats.data()[v]) + 0.0f;
  const CompactIntensities held(floats);
  ASSERT_NE(held.as_int16(), nullptr);
  const Eigen::Matrix3d r =
      Eigen::AngleAxisd(9.0 * M_PI / 180.0, Eigen::Vector3d(0.3, -0.2, 1).normalized()).toRotationMatrix();
  const Eigen::Vector3d t(3.7, -2.2, 4.1);
  Eigen::MatrixXd posed = (s.mesh.vertices * r.transpose()).rowwise() + t.transpose();
  for (int64_t v = 0; v < posed.rows(); ++v) posed(v, 0) += 0.15 * std::max(0.0, s.mesh.vertices(v, 2) - 60.0);
  Result<TetWarp> warp = TetWarp::build({.rest = s.mesh,
                                         .posed = posed,
                                         .source = g,
                                         .output = g,
                                         .background_rotation = r,
                                         .background_translation = t,
                                         .rest_owner = &s.packed_owner});
  ASSERT_TRUE(warp.ok()) << warp.status().to_string();
  EXPECT_GT(warp->rasterized_tets(), 0);
  for (const Interpolation interpolation : {Interpolation::kLinear, Interpolation::kNearest}) {
    Result<IntensityVolume> a = warp->warp_intensities(floats, interpolation);
    Result<IntensityVolume> b = warp->warp_intensities(*held.as_int16(), interpolation);
    ASSERT_TRUE(a.ok() && b.ok());
    ASSERT_EQ(a->voxel_count(), b->voxel_count());
    int64_t differ = 0, fractional = 0;
    for (int64_t v = 0; v < a->voxel_count(); ++v) {
      differ += std::bit_cast<uint32_t>(a->data()[v]) != std::bit_cast<uint32_t>(b->data()[v]);
      fractional += a->data()[v] != std::round(a->data()[v]);
    }
    EXPECT_EQ(differ, 0) << (interpolation == Interpolation::kLinear ? "trilinear" : "nearest");
    if (interpolation == Interpolation::kLinear) {
      EXPECT_GT(fractional, 1000);  // interpolated, not copied
    }
    EXPECT_EQ(b->source_type(), floats.source_type());
  }
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
