// posewarp-view against the real server on loopback, rendered under Xvfb (ctest runs this binary through
// xvfb-run): snapshots at rest and posed, the rest one against a stored reference, and the controller that the
// sliders call driving the preview stream and the scene.
#include <gtest/gtest.h>
#include <vtkImageData.h>
#include <vtkPNGReader.h>
#include <vtkSmartPointer.h>

#include "scene.h"
#include "server_process.h"

namespace posewarp {
namespace {

using namespace testing_server;

struct Image {
  int width = 0, height = 0;
  std::vector<unsigned char> rgb;  // rows from the bottom, as VTK reads them
  const unsigned char* at(int x, int y) const { return &rgb[static_cast<size_t>(3 * (y * width + x))]; }
};

Image read_png(const fs::path& path) {
  auto reader = vtkSmartPointer<vtkPNGReader>::New();
  reader->SetFileName(path.c_str());
  reader->Update();
  Image image;
  vtkImageData* data = reader->GetOutput();
  int dims[3];
  data->GetDimensions(dims);
  image.width = dims[0], image.height = dims[1];
  const int components = data->GetNumberOfScalarComponents();
  const auto* pixels = static_cast<const unsigned char*>(data->GetScalarPointer());
  if (pixels == nullptr || components < 3) return {};
  for (int i = 0; i < image.width * image.height; ++i) {
    for (int c = 0; c < 3; ++c) image.rgb.push_back(pixels[i * components + c]);
  }
  return image;
}

// Fraction of the pixels in rows [y0, y1) whose largest channel difference exceeds `tolerance`.
double differing(const Image& a, const Image& b, int y0, int y1, int tolerance = 24) {
  int64_t count = 0, total = 0;
  for (int y = y0; y < y1; ++y) {
    for (int x = 0; x < a.width; ++x, ++total) {
      int d = 0;
      for (int c = 0; c < 3; ++c) d = std::max(d, std::abs(a.at(x, y)[c] - b.at(x, y)[c]));
      count += d > tolerance;
    }
  }
  return total == 0 ? 1.0 : static_cast<double>(count) / static_cast<double>(total);
}

// Fraction of pixels that are not the background.
double drawn(const Image& a) {
  int64_t count = 0;
  for (int y = 0; y < a.height; ++y) {
    for (int x = 0; x < a.width; ++x) count += std::abs(a.at(x, y)[0] - 26) + std::abs(a.at(x, y)[2] - 33) > 30;
  }
  return static_cast<double>(count) / (a.width * a.height);
}

class Viewer : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = fs::temp_directory_path() / ("posewarp-viewer-test-" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    ASSERT_EQ(run({POSEWARP_CLI, "--quiet", "phantom", "bar", "-o", (dir_ / "bar").string()}), 0);
    server_ = new ServerProcess(dir_ / "store");
    ASSERT_GT(server_->port(), 0);
    rig_id_ = output_of({POSEWARP_CLI, "-q", "rig", "build", "--server", server_->address(), "--labels",
                         (dir_ / "bar" / "labels.nii.gz").string(), "--ct", (dir_ / "bar" / "ct.nii.gz").string(),
                         "--label-map", (dir_ / "bar" / "label_map.json").string()});
    if (!rig_id_.empty() && rig_id_.back() == '\n') rig_id_.pop_back();
  }
  static void TearDownTestSuite() {
    delete server_;
    fs::remove_all(dir_);
  }
  static int snapshot(const fs::path& png, const std::vector<std::string>& more = {}) {
    std::vector<std::string> args{POSEWARP_VIEW, "--server", server_->address(), "--rig", rig_id_, "--size", "480x360",
                                  "--snapshot", png.string()};
    args.insert(args.end(), more.begin(), more.end());
    return run(args);
  }
  static inline fs::path dir_;
  static inline ServerProcess* server_ = nullptr;
  static inline std::string rig_id_;
};

TEST_F(Viewer, SnapshotsAtRestAndPosedDifferWhereTheBarBentAndTheRestOneMatchesItsReference) {
  ASSERT_EQ(snapshot(dir_ / "rest.png"), 0);
  const std::string bend = (fs::path(POSEWARP_SOURCE_DIR) / "data/poses/bar_bend_90.json").string();
  ASSERT_EQ(snapshot(dir_ / "bent.png", {"--pose", bend}), 0);
  const Image rest = read_png(dir_ / "rest.png"), bent = read_png(dir_ / "bent.png");
  ASSERT_EQ(rest.width, 480);
  ASSERT_EQ(rest.height, 360);
  EXPECT_GT(drawn(rest), 0.05);
  EXPECT_GT(drawn(bent), 0.05);
  // The bar bends at its middle joint: its upper half moves (rows from the bottom), its lowest quarter stays.
  EXPECT_GT(differing(rest, bent, rest.height * 6 / 10, rest.height * 9 / 10), 0.05);
  EXPECT_LT(differing(rest, bent, rest.height / 20, rest.height / 5), 0.01);
  // The rest snapshot against the reference made by the same command (tests/data/viewer/README.md): at most 1% of
  // the pixels differ by more than 24 of 255 in a channel.
  const Image reference = read_png(fs::path(POSEWARP_SOURCE_DIR) / "tests/data/viewer/bar_rest_anterior.png");
  ASSERT_EQ(reference.width, rest.width);
  EXPECT_LT(differing(rest, reference, 0, rest.height), 0.01);
  // A wrong rig id: a clear error, exit code 2.
  EXPECT_EQ(run({POSEWARP_VIEW, "--server", server_->address(), "--rig", std::string(64, '0'), "--snapshot",
                 (dir_ / "none.png").string()}) >> 8, 2);
  EXPECT_FALSE(fs::exists(dir_ / "none.png"));
}

TEST_F(Viewer, TheControlsDriveThePreviewStreamAndTheSceneFollows) {
  view::CallError error;
  auto client = view::ViewerClient::connect({server_->address(), "", ""}, &error);
  ASSERT_TRUE(client) << error.message;
  view::RigAssets assets;
  ASSERT_FALSE(client->assets(rig_id_, &assets).failed());
  view::Scene scene(480, 360, true);
  scene.set_rig(assets);
  view::PreviewSession session(*client, rig_id_);
  view::Controller controller(scene, session);
  const auto& joints = scene.joint_names();
  const auto joint = std::find(joints.begin(), joints.end(), "joint_2_3");
  ASSERT_NE(joint, joints.end());
  controller.select_joint(static_cast<size_t>(joint - joints.begin()));
  // A slider dragged from 0 to 90 degrees of flexion, as its callback calls the controller.
  for (const double degrees : {10.0, 30.0, 50.0, 70.0, 90.0}) controller.set_angle(0, degrees);
  ASSERT_TRUE(session.wait_for(controller.last_sent(), 30000)) << session.ended().message;
  ASSERT_TRUE(controller.poll());
  EXPECT_GE(scene.updates(), 1);
  EXPECT_GT(controller.last_round_trip_ms(), 0.0);
  EXPECT_EQ(controller.pose().joints.at("joint_2_3").flexion, 90.0);
  // The scene now shows what the snapshot of the same pose shows.
  scene.set_status("");
  std::string why;
  ASSERT_TRUE(scene.snapshot((dir_ / "driven.png").string(), &why)) << why;
  const std::string bend = (fs::path(POSEWARP_SOURCE_DIR) / "data/poses/bar_bend_90.json").string();
  ASSERT_EQ(snapshot(dir_ / "posed.png", {"--pose", bend}), 0);
  EXPECT_LT(differing(read_png(dir_ / "driven.png"), read_png(dir_ / "posed.png"), 0, 360), 0.01);
  // Undo returns to 70 degrees; reset all goes back to rest.
  controller.undo();
  EXPECT_EQ(controller.pose().joints.at("joint_2_3").flexion, 70.0);
  controller.reset_all();
  ASSERT_TRUE(session.wait_for(controller.last_sent(), 30000));
  EXPECT_TRUE(controller.pose().is_rest());
  EXPECT_GE(session.answers(), 2u);
}

}  // namespace
}  // namespace posewarp
