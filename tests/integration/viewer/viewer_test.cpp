// posewarp-view against the real server on loopback, rendered under Xvfb (ctest runs this binary through
// xvfb-run): snapshots at rest and posed, the rest one against a stored reference, and the controller that the
// sliders call driving the preview stream and the scene.
#include <gtest/gtest.h>
#include <vtkImageData.h>
#include <vtkPNGReader.h>
#include <vtkRenderer.h>
#include <vtkSmartPointer.h>

#include <nlohmann/json.hpp>

#include <fcntl.h>
#include <signal.h>
#include <sys/wait.h>

#include <cmath>
#include <sstream>
#include <functional>
#include <thread>

#include "app.h"
#include "posewarp/api/files.h"
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
  // Pictures of different sizes (or none, when a snapshot failed) differ everywhere; the callers' sizes checks say
  // which.
  if (a.width != b.width || a.height != b.height || a.rgb.empty()) return -1.0;
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

// Pixels of the rectangle [x0, x1) x [y0, y1) (rows from the bottom) that are coloured (channels apart by more than
// 60) in `labelled` and grey but not black in `plain`: labels drawn over CT.
int64_t labels_over_ct(const Image& labelled, const Image& plain, int x0, int x1, int y0, int y1) {
  int64_t count = 0;
  for (int y = y0; y < y1; ++y) {
    for (int x = x0; x < x1; ++x) {
      const unsigned char *a = labelled.at(x, y), *b = plain.at(x, y);
      const int spread_a = std::max({a[0], a[1], a[2]}) - std::min({a[0], a[1], a[2]});
      const int spread_b = std::max({b[0], b[1], b[2]}) - std::min({b[0], b[1], b[2]});
      count += spread_a > 60 && spread_b < 8 && b[0] > 40;
    }
  }
  return count;
}

// Grey, not black pixels of a rectangle: CT drawn.
int64_t grey_pixels(const Image& image, int x0, int x1, int y0, int y1) {
  int64_t count = 0;
  for (int y = y0; y < y1; ++y) {
    for (int x = x0; x < x1; ++x) {
      const unsigned char* a = image.at(x, y);
      count += std::max({a[0], a[1], a[2]}) - std::min({a[0], a[1], a[2]}) < 8 && a[0] > 40;
    }
  }
  return count;
}

// What a command prints on stderr.
std::string stderr_of(const std::vector<std::string>& args) {
  std::string command;
  for (const std::string& a : args) command += "'" + a + "' ";
  std::string out;
  if (FILE* pipe = ::popen((command + "2>&1 >/dev/null").c_str(), "r")) {
    char buffer[4096];
    for (size_t n; (n = std::fread(buffer, 1, sizeof buffer, pipe)) > 0;) out.append(buffer, n);
    ::pclose(pipe);
  }
  return out;
}

// Where a world point (LPS mm) lands in the window, after a render.
std::array<int, 2> on_screen(vtkRenderer* renderer, const std::array<double, 3>& point) {
  renderer->SetWorldPoint(point[0], point[1], point[2], 1.0);
  renderer->WorldToDisplay();
  double display[3];
  renderer->GetDisplayPoint(display);
  return {static_cast<int>(std::lround(display[0])), static_cast<int>(std::lround(display[1]))};
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
    std::vector<std::string> args{POSEWARP_VIEW, "--server",   server_->address(), "--rig",
                                  rig_id_,       "--snapshot", png.string()};
    if (std::find(more.begin(), more.end(), "--size") == more.end()) args.insert(args.end(), {"--size", "480x360"});
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
                 (dir_ / "none.png").string()}) >>
                8,
            2);
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
  // Drawn with a quarter of the triangles (a rig over the triangle budget), the same pose looks the same.
  int64_t sent = 0;
  for (const auto& surface : assets.surfaces) sent += surface.triangles_size() / 3;
  view::Scene fewer(480, 360, true);
  fewer.set_rig(assets, sent / 4);
  EXPECT_LT(fewer.drawn_triangles(), sent / 2);
  EXPECT_EQ(scene.drawn_triangles(), sent);
  view::PreviewSession again(*client, rig_id_);
  view::Controller bent(fewer, again);
  bent.select_joint(static_cast<size_t>(joint - joints.begin()));
  bent.set_angle(0, 90.0);
  ASSERT_TRUE(again.wait_for(bent.last_sent(), 30000));
  ASSERT_TRUE(bent.poll());
  fewer.set_status("");
  ASSERT_TRUE(fewer.snapshot((dir_ / "fewer.png").string(), &why)) << why;
  EXPECT_LT(differing(read_png(dir_ / "fewer.png"), read_png(dir_ / "posed.png"), 0, 360), 0.03);
  // Undo takes back the whole drag (moves of one control less than a second apart); reset all goes back to rest.
  controller.undo();
  EXPECT_FALSE(controller.pose().joints.count("joint_2_3") && controller.pose().joints.at("joint_2_3").flexion != 0.0);
  controller.set_angle(0, 30.0);
  controller.set_angle(1, 10.0);
  controller.undo();
  EXPECT_EQ(controller.pose().joints.at("joint_2_3").flexion, 30.0);
  EXPECT_EQ(controller.pose().joints.at("joint_2_3").abduction, 0.0);
  controller.reset_all();
  ASSERT_TRUE(session.wait_for(controller.last_sent(), 30000));
  EXPECT_TRUE(controller.pose().is_rest());
  EXPECT_GE(session.answers(), 2u);
}

TEST_F(Viewer, TheSlicesSnapshotShowsLabelsOverTheCtWithTheReport) {
  const std::string bend = (fs::path(POSEWARP_SOURCE_DIR) / "data/poses/bar_bend_90.json").string();
  ASSERT_EQ(snapshot(dir_ / "slices.png", {"--pose", bend, "--slices", "--size", "960x720", "--label-opacity", "0.5"}),
            0);
  ASSERT_EQ(snapshot(dir_ / "plain.png", {"--pose", bend, "--slices", "--size", "960x720", "--label-opacity", "0"}), 0);
  const Image labelled = read_png(dir_ / "slices.png"), plain = read_png(dir_ / "plain.png");
  ASSERT_EQ(labelled.width, 960);
  ASSERT_EQ(labelled.height, 720);
  // The layout: the 3D view top left, axial top right, coronal bottom left, sagittal bottom right (rows from the
  // bottom). Each slice shows CT without labels, and coloured labels over that CT with them.
  const int quadrants[3][4] = {{480, 960, 360, 720}, {0, 480, 0, 360}, {480, 960, 0, 360}};
  for (const auto& q : quadrants) {
    const int64_t area = static_cast<int64_t>(q[1] - q[0]) * (q[3] - q[2]);
    EXPECT_GT(grey_pixels(plain, q[0], q[1], q[2], q[3]), area / 50)
        << "no CT in the view at x " << q[0] << ", y " << q[2];
    EXPECT_GT(labels_over_ct(labelled, plain, q[0], q[1], q[2], q[3]), area / 50)
        << "no labels over the CT in the view at x " << q[0] << ", y " << q[2];
  }
  // The 3D view above them still shows the posed bar, and the same in both.
  EXPECT_LT(differing(labelled, plain, 360, 720), 0.5);
  // A grid grown to hold the bent bar: the bar is no longer cut where it leaves the study's grid.
  ASSERT_EQ(snapshot(dir_ / "grown.png", {"--pose", bend, "--slices", "--size", "960x720", "--grid", "grow"}), 0);
  EXPECT_GT(differing(read_png(dir_ / "grown.png"), labelled, 0, 360), 0.01);
}

TEST_F(Viewer, SavesThePosedFilesAsTheCliWritesThem) {
  const std::string bend = (fs::path(POSEWARP_SOURCE_DIR) / "data/poses/bar_bend_90.json").string();
  const fs::path saved = dir_ / "saved", cli = dir_ / "cli";
  ASSERT_EQ(run({POSEWARP_VIEW, "--server", server_->address(), "--rig", rig_id_, "--pose", bend, "--method", "dqs",
                 "--save", saved.string()}),
            0);
  fs::create_directories(cli);
  ASSERT_EQ(run({POSEWARP_CLI, "-q", "pose", rig_id_, "--server", server_->address(), "--pose", bend, "--method", "dqs",
                 "--labels-out", (cli / "labels.nii.gz").string(), "--ct-out", (cli / "ct.nii.gz").string(),
                 "--surfaces-out", (cli / "surfaces").string(), "--report", (cli / "report.json").string()}),
            0);
  auto ours = api::read_label_volume((saved / "labels.nii.gz").string());
  auto theirs = api::read_label_volume((cli / "labels.nii.gz").string());
  ASSERT_TRUE(ours.ok() && theirs.ok());
  EXPECT_TRUE(ours->geometry().same_grid(theirs->geometry()));
  EXPECT_EQ(ours->voxels(), theirs->voxels());
  auto ct = api::read_intensity_volume((saved / "ct.nii.gz").string());
  auto cli_ct = api::read_intensity_volume((cli / "ct.nii.gz").string());
  ASSERT_TRUE(ct.ok() && cli_ct.ok());
  EXPECT_EQ(ct->voxels(), cli_ct->voxels());
  size_t surfaces = 0;
  for (const auto& entry : fs::directory_iterator(cli / "surfaces")) {
    ++surfaces;
    auto a = api::read_surface((saved / "surfaces" / entry.path().filename()).string());
    auto b = api::read_surface(entry.path().string());
    ASSERT_TRUE(a.ok()) << entry.path().filename();
    ASSERT_TRUE(b.ok());
    EXPECT_EQ(a->vertices.rows(), b->vertices.rows());
    EXPECT_LT((a->vertices - b->vertices).cwiseAbs().maxCoeff(), 1e-4);
  }
  EXPECT_GT(surfaces, 0u);
  EXPECT_EQ(nlohmann::json::parse(file_text(saved / "report.json"))["inverted_tets"],
            nlohmann::json::parse(file_text(cli / "report.json"))["inverted_tets"]);
  std::string why;
  const std::optional<view::Pose> pose = view::pose_from_json(file_text(saved / "pose.json"), &why);
  ASSERT_TRUE(pose) << why;
  EXPECT_EQ(pose->joints.at("joint_2_3").flexion, 90.0);
  for (const auto& entry : fs::recursive_directory_iterator(saved)) EXPECT_NE(entry.path().extension(), ".partial");
}

TEST_F(Viewer, BadAddressesPosesAndRigsGetClearErrorsAndNoSnapshot) {
  // Nothing listens on the port of a server that was stopped.
  const int port = [] {
    ServerProcess gone(dir_ / "gone-store");
    return gone.port();
  }();
  const std::string message = stderr_of(
      {POSEWARP_VIEW, "--server", "127.0.0.1:" + std::to_string(port), "--snapshot", (dir_ / "x.png").string()});
  EXPECT_NE(message.find("cannot reach posewarp-server"), std::string::npos) << message;
  // A server that needs a token: without one, or with a wrong one, exit 2 and a message that says so.
  {
    std::ofstream(dir_ / "tokens") << "right-token\n";
    std::ofstream(dir_ / "wrong") << "wrong-token\n";
    ServerProcess guarded(dir_ / "guarded-store", {"--token-file", (dir_ / "tokens").string()});
    const std::vector<std::string> base{POSEWARP_VIEW, "--server", guarded.address(), "--list"};
    EXPECT_NE(stderr_of(base).find("needs a bearer token"), std::string::npos);
    std::vector<std::string> wrong = base;
    wrong.insert(wrong.end(), {"--token-file", (dir_ / "wrong").string()});
    EXPECT_NE(stderr_of(wrong).find("not one this server accepts"), std::string::npos);
    EXPECT_EQ(run(wrong) >> 8, 2);
    std::vector<std::string> right = base;
    right.insert(right.end(), {"--token-file", (dir_ / "tokens").string()});
    EXPECT_EQ(run(right), 0);
  }
  // A joint the rig does not have: the server refuses the pose, the viewer says so and writes nothing.
  const fs::path wrong = dir_ / "wrong_joint.json";
  std::ofstream(wrong)
      << R"({"format": "posewarp.pose", "version": 1, "joints": {"knee_left": {"angles_deg": {"flexion": 30}}}})";
  EXPECT_EQ(snapshot(dir_ / "refused.png", {"--pose", wrong.string()}) >> 8, 2);
  EXPECT_FALSE(fs::exists(dir_ / "refused.png"));
  // A pose file the viewer cannot read: exit 2 before any call.
  std::ofstream(dir_ / "broken.json") << "{\"joints\": [1, 2]}";
  EXPECT_EQ(snapshot(dir_ / "broken.png", {"--pose", (dir_ / "broken.json").string()}) >> 8, 2);
  EXPECT_EQ(snapshot(dir_ / "bad.png", {"--cursor", "1,2"}) >> 8, 2);
}

TEST(ViewerPose, RootAnglesAndJointsSurviveTheJsonTheServerReads) {
  view::Pose pose;
  pose.joints["knee_left"].flexion = 45;
  pose.root_deg = {10.0, -20.0, 30.0};
  pose.root_mm = {1.0, 2.0, 3.0};
  std::string why;
  const std::optional<view::Pose> back = view::pose_from_json(view::pose_json(pose), &why);
  ASSERT_TRUE(back) << why;
  EXPECT_EQ(back->joints.at("knee_left").flexion, 45.0);
  for (size_t a = 0; a < 3; ++a) {
    EXPECT_NEAR(back->root_deg[a], pose.root_deg[a], 1e-9);
    EXPECT_EQ(back->root_mm[a], pose.root_mm[a]);
  }
  // A root turn as an axis-angle about S-I is the third angle.
  const auto turned = view::pose_from_json(
      R"({"joints": {}, "root": {"rotation": {"axis_angle": {"axis": [0, 0, 2], "degrees": 25}}}})", &why);
  ASSERT_TRUE(turned) << why;
  EXPECT_NEAR(turned->root_deg[2], 25.0, 1e-9);
  EXPECT_NEAR(turned->root_deg[0], 0.0, 1e-9);
  EXPECT_FALSE(view::pose_from_json(R"({"joints": {}, "root": {"rotation": {"quaternion": [2, 0, 0, 0]}}})", &why));
  EXPECT_FALSE(view::pose_from_json(R"({"joints": {"a": {"quaternion": [1, 0, 0, 0]}}})", &why));
  EXPECT_NE(why.find("angles_deg"), std::string::npos);
}

TEST(ViewerReport, KeyFiguresReadAsTheyShould) {
  v1::QualityReport report;
  report.set_inverted_tets(3);
  report.set_bone_rigidity_error_mm(0.126);
  report.set_volume_change(-0.0123);
  report.add_lost_labels(13);
  const std::vector<std::string> lines = view::report_lines(report);
  ASSERT_EQ(lines.size(), 5u);
  EXPECT_EQ(lines[0], "inverted tets: 3");
  EXPECT_EQ(lines[1], "bone rigidity error: 0.13 mm");
  EXPECT_EQ(lines[2], "volume change: -1.23 %");
  EXPECT_EQ(lines[3], "new labels: none");
  EXPECT_EQ(lines[4], "lost labels: 13");
  // The local figures of each moved joint follow, from the report's JSON; two methods side by side in rows.
  report.set_json(R"({"moved_joints": [{"joint": "knee_left", "radius_mm": 50, "volume_change": -0.148,
      "folded_fraction": 0.095, "skin_vertices": 300, "skin_inside_tissue": 70, "skin_inside_bone": 4}]})");
  const std::vector<std::string> local = view::report_lines(report);
  ASSERT_EQ(local.size(), 6u);
  EXPECT_EQ(local[5], "knee_left 50 mm: -14.8 % tissue, 9.5 % folded");
  v1::QualityReport other = report;
  other.set_inverted_tets(0);
  other.set_json(R"({"moved_joints": [{"joint": "knee_left", "radius_mm": 50, "volume_change": -0.178,
      "folded_fraction": 0.181, "skin_vertices": 300, "skin_inside_tissue": 90, "skin_inside_bone": 0}]})");
  const std::vector<std::string> table = view::compare_report_lines(report, "fem", other, "cor");
  ASSERT_EQ(table.size(), 5u);
  auto cells = [](const std::string& line) {
    std::istringstream in(line.substr(22));
    std::string a, b, unit;
    in >> a;
    if (line.find('%', 22) != std::string::npos) in >> unit;
    in >> b;
    return std::make_pair(a, b);
  };
  EXPECT_EQ(cells(table[0]), std::make_pair(std::string("fem"), std::string("cor")));
  EXPECT_EQ(cells(table[1]), std::make_pair(std::string("3"), std::string("0")));
  EXPECT_EQ(table[3].substr(0, 16), "knee_left 50 mm ");
  EXPECT_EQ(cells(table[3]), std::make_pair(std::string("-14.8"), std::string("-17.8")));
  EXPECT_EQ(table[4].substr(0, 8), "  folded");
  EXPECT_EQ(cells(table[4]), std::make_pair(std::string("9.5"), std::string("18.1")));
  EXPECT_EQ(view::compare_report_lines(report, "fem", other, "cor", 0).back(), "and 1 more joints (d saves report.json)");
  // A report without the joint leaves its rows out; a report that is not JSON has no local figures.
  other.set_json("not json");
  EXPECT_EQ(view::compare_report_lines(report, "fem", other, "cor").size(), 3u);
  EXPECT_EQ(view::report_lines(other).size(), 5u);
}

// The window's keys and clicks, driven as the interactor calls them (without one): choose a joint by clicking its
// sphere, bend it, compare two methods, ask for the full volume, move the cursor, change the window and opacity,
// save, load a pose file, turn the root, reconnect.
TEST_F(Viewer, TheWindowsKeysAndClicksWorkWithoutFreezing) {
  view::CallError error;
  auto client = view::ViewerClient::connect({server_->address(), "", ""}, &error);
  ASSERT_TRUE(client) << error.message;
  view::RigAssets assets;
  ASSERT_FALSE(client->assets(rig_id_, &assets).failed());
  view::Scene scene(960, 720, true);
  scene.set_rig(assets);
  view::App app;
  app.options.rig_id = rig_id_;
  app.options.out_dir = (dir_ / "window").string();
  fs::create_directories(app.options.out_dir);
  app.client = client.get();
  app.scene = &scene;
  app.session = std::make_unique<view::PreviewSession>(*client, rig_id_);
  view::Controller controller(scene, *app.session);
  app.controller = &controller;
  const auto answered = [&] {
    const uint64_t before = static_cast<uint64_t>(scene.updates());
    for (int i = 0; i < 3000 && static_cast<uint64_t>(scene.updates()) == before; ++i) {
      app.tick();
      std::this_thread::sleep_for(std::chrono::milliseconds(5));
    }
    return static_cast<uint64_t>(scene.updates()) > before;
  };
  scene.render();
  // A click on joint_2_3's sphere chooses it.
  const auto& joints = scene.joint_names();
  const size_t knee = static_cast<size_t>(std::find(joints.begin(), joints.end(), "joint_2_3") - joints.begin());
  ASSERT_LT(knee, joints.size());
  const std::array<double, 3> centre{assets.skeleton.joints(static_cast<int>(knee)).centre_mm(0),
                                     assets.skeleton.joints(static_cast<int>(knee)).centre_mm(1),
                                     assets.skeleton.joints(static_cast<int>(knee)).centre_mm(2)};
  const std::array<int, 2> at = on_screen(scene.renderer(), centre);
  ASSERT_TRUE(app.click(at[0], at[1]));
  EXPECT_EQ(controller.joint(), "joint_2_3");
  // A click on empty background leaves the camera to the trackball.
  EXPECT_FALSE(app.click(5, 5));
  controller.set_angle(0, 90);
  ASSERT_TRUE(answered());
  // Side by side: the second stream answers too, with the other method.
  app.key("c");
  EXPECT_EQ(scene.layout(), view::Scene::Layout::kCompare);
  EXPECT_EQ(controller.compare_method(), v1::METHOD_DQS);
  ASSERT_TRUE(app.compare->wait_for(1, 30000));
  app.key("c");
  EXPECT_EQ(scene.layout(), view::Scene::Layout::kSingle);
  // The full volume arrives off this thread (tick keeps returning while it runs) and shows as slices.
  // The request runs on its own thread: neither the key nor the timer's ticks wait for it.
  const auto milliseconds = [](auto start) {
    return std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - start).count();
  };
  // Asked while two methods are compared, the full volume comes with the other method's report, and the slices'
  // report shows the two methods' figures side by side.
  app.key("c");
  ASSERT_TRUE(app.compare != nullptr);
  auto pressed = std::chrono::steady_clock::now();
  app.key("f");
  EXPECT_LT(milliseconds(pressed), 200.0);
  EXPECT_TRUE(app.volume_request != nullptr);
  EXPECT_TRUE(app.compare_request != nullptr);
  pressed = std::chrono::steady_clock::now();
  app.tick();
  EXPECT_LT(milliseconds(pressed), 200.0);
  ASSERT_TRUE(app.settle(120000));
  ASSERT_TRUE(scene.slices().has_volume());
  EXPECT_EQ(scene.layout(), view::Scene::Layout::kSlices);
  ASSERT_TRUE(app.compare_report.has_value());
  const std::string& text = scene.report_text();
  EXPECT_NE(text.find("CoR"), std::string::npos) << text;
  EXPECT_NE(text.find("DQS"), std::string::npos) << text;
  EXPECT_NE(text.find("joint_2_3 50 mm"), std::string::npos) << text;
  EXPECT_NE(text.find("joint_2_3 100 mm"), std::string::npos) << text;
  EXPECT_NE(text.find("  folded"), std::string::npos) << text;
  // A click in the coronal view (bottom left) moves the cursor's L-R and S-I, not its A-P.
  scene.render();
  const std::array<double, 3> before = scene.slices().cursor_mm();
  vtkRenderer* coronal = scene.slices().renderer(1);
  std::array<double, 3> target = before;
  target[0] += 10.0, target[2] -= 20.0;
  const std::array<int, 2> there = on_screen(coronal, target);
  ASSERT_TRUE(app.click(there[0], there[1]));
  const std::array<double, 3> after = scene.slices().cursor_mm();
  const view::SliceVolume& volume = scene.slices().volume();
  EXPECT_NEAR(after[0], target[0], volume.spacing[0]);
  EXPECT_NEAR(after[2], target[2], volume.spacing[2]);
  EXPECT_EQ(after[1], before[1]);
  app.key("T");
  app.key("T");
  app.key("b");
  EXPECT_STREQ(scene.slices().window().name, view::kBone.name);
  app.key("plus");
  EXPECT_NEAR(scene.slices().label_opacity(), 0.5, 1e-9);
  // A changed pose marks the slices as an earlier pose's.
  controller.set_angle(0, 60);
  app.tick();
  EXPECT_TRUE(app.stale);
  // d saves the posed files into --out-dir.
  app.key("d");
  ASSERT_TRUE(app.settle(120000));
  ASSERT_FALSE(app.save_dir.empty());
  EXPECT_TRUE(fs::exists(fs::path(app.save_dir) / "labels.nii.gz"));
  EXPECT_TRUE(fs::exists(fs::path(app.save_dir) / "report.json"));
  // w writes the pose JSON; o loads the pose files of --poses.
  app.key("w");
  bool wrote_pose = false;
  for (const auto& entry : fs::directory_iterator(app.options.out_dir))
    wrote_pose |= entry.path().extension() == ".json";
  EXPECT_TRUE(wrote_pose);
  app.pose_files = {(fs::path(POSEWARP_SOURCE_DIR) / "data/poses/bar_twist_90.json").string()};
  app.key("o");
  EXPECT_EQ(controller.pose().joints.at("joint_2_3").rotation, 90.0);
  // The root: first in the joint list; its third control turns the body about S-I.
  app.choose(0);
  EXPECT_TRUE(controller.at_root());
  controller.set_angle(2, 30);
  ASSERT_TRUE(answered());
  EXPECT_FALSE(controller.last_error().failed()) << controller.last_error().message;
  EXPECT_EQ(controller.pose().root_deg[2], 30.0);
  // Undo, reset all; then a fresh stream (x) answers as the old one did.
  app.key("u");
  EXPECT_EQ(controller.pose().root_deg[2], 0.0);
  app.key("R");
  EXPECT_TRUE(controller.pose().is_rest());
  app.key("x");
  ASSERT_TRUE(answered());
  EXPECT_FALSE(app.stream_lost);
}

// The real sample (data/totalsegmentator_example) through the viewer: at rest, bent (the lumbar spine bent to the
// left and the left hip flexed), CoR beside LBS, and the slices of the posed CT with its labels and report. These are
// the README's pictures: scripts/docs-snapshots runs this test with POSEWARP_DOCS_OUT=docs to keep them.
TEST_F(Viewer, TheSampleAtRestBentSideBySideAndInSlices) {
  const std::string sample = (fs::path(POSEWARP_SOURCE_DIR) / "data/totalsegmentator_example").string();
  std::string rig = output_of({POSEWARP_CLI, "-q", "rig", "build", "--server", server_->address(), "--labels",
                               sample + "/seg_total.nii.gz", "--ct", sample + "/ct.nii.gz", "--name", "sample"});
  if (!rig.empty() && rig.back() == '\n') rig.pop_back();
  ASSERT_EQ(rig.size(), 64u) << rig;
  const fs::path pose = dir_ / "sample_bent.json";
  std::ofstream(pose) << R"({"format": "posewarp.pose", "version": 1, "name": "spine bent left, left hip flexed",
    "joints": {"L2_L3": {"angles_deg": {"abduction": 12}}, "L1_L2": {"angles_deg": {"abduction": 12}},
               "thoracolumbar": {"angles_deg": {"abduction": 10}}, "hip_left": {"angles_deg": {"flexion": 40}}}})";
  const auto shot = [&](const std::string& name, std::vector<std::string> more) {
    std::vector<std::string> args{POSEWARP_VIEW, "--server",   server_->address(),    "--rig", rig, "--size",
                                  "800x600",     "--snapshot", (dir_ / name).string()};
    args.insert(args.end(), more.begin(), more.end());
    EXPECT_EQ(run(args), 0) << name;
    return read_png(dir_ / name);
  };
  const Image rest = shot("sample_rest.png", {});
  const Image bent = shot("sample_bent.png", {"--pose", pose.string()});
  const Image compare = shot("sample_cor_lbs.png", {"--pose", pose.string(), "--compare", "lbs", "--view", "lateral"});
  const Image slices = shot("sample_slices.png", {"--pose", pose.string(), "--slices", "--window", "bone"});
  // The slices with CoR's and fem's report figures side by side: the same picture as the slices but for the report
  // panel in the upper half (rows 300-600: the picture's rows count from its bottom).
  const Image figures = shot("sample_slices_cor_fem.png",
                             {"--pose", pose.string(), "--slices", "--window", "bone", "--compare", "fem"});
  EXPECT_GT(differing(slices, figures, 300, 600), 0.01);
  EXPECT_EQ(differing(slices, figures, 0, 300), 0.0);
  for (const Image* image : {&rest, &bent, &compare, &slices, &figures}) {
    ASSERT_EQ(image->width, 800);
    EXPECT_GT(drawn(*image), 0.10);
  }
  // The spine bends above the pelvis (the upper part of the picture); the pelvis below stays.
  EXPECT_GT(differing(rest, bent, 300, 600), 0.02);
  EXPECT_LT(differing(rest, bent, 0, 150), differing(rest, bent, 300, 600));
  if (const char* out = std::getenv("POSEWARP_DOCS_OUT")) {
    for (const char* name :
         {"sample_rest.png", "sample_bent.png", "sample_cor_lbs.png", "sample_slices.png", "sample_slices_cor_fem.png"}) {
      fs::copy_file(dir_ / name, fs::path(out) / name, fs::copy_options::overwrite_existing);
    }
  }
}

// The real window under Xvfb, driven with X events (xdotool, from scripts/setup): a joint chosen with a key, its
// flexion slider dragged with the mouse, the pose saved, side by side on and off, the full volume shown and pictured,
// the posed files saved, and q quits cleanly.
TEST_F(Viewer, TheRealWindowAnswersKeysAndTheMouse) {
  if (std::system("command -v xdotool >/dev/null 2>&1") != 0)
    GTEST_SKIP() << "xdotool is not installed (scripts/setup installs it)";
  const fs::path out = dir_ / "window-out";
  fs::create_directories(out);
  const pid_t viewer = ::fork();
  if (viewer == 0) {
    const int null = ::open("/dev/null", O_WRONLY);
    ::dup2(null, 1);
    ::dup2(null, 2);
    ::execl(POSEWARP_VIEW, POSEWARP_VIEW, "--server", server_->address().c_str(), "--rig", rig_id_.c_str(), "--size",
            "900x700", "--out-dir", out.c_str(), static_cast<char*>(nullptr));
    ::_exit(127);
  }
  ASSERT_GT(viewer, 0);
  const auto xdotool = [](const std::string& arguments) {
    return std::system(("xdotool " + arguments + " >/dev/null 2>&1").c_str());
  };
  std::string window;
  for (int i = 0; i < 100 && window.empty(); ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
    window = output_of({"xdotool", "search", "--name", "^posewarp-view$"});
    if (const size_t end = window.find('\n'); end != std::string::npos) window.resize(end);
  }
  if (window.empty()) {
    ::kill(viewer, SIGKILL);
    ::waitpid(viewer, nullptr, 0);
    FAIL() << "the window did not open";
  }
  const auto key = [&](const std::string& k, int wait_ms = 400) {
    EXPECT_EQ(xdotool("key --window " + window + " " + k), 0) << k;
    std::this_thread::sleep_for(std::chrono::milliseconds(wait_ms));
  };
  key("n");
  // The flexion slider: the top one in the bottom right corner (y = 0.20 of the height from the bottom).
  EXPECT_EQ(xdotool("mousemove --window " + window + " 760 560 mousedown 1 sleep 0.2 mousemove --window " + window +
                    " 800 560 sleep 0.2 mousemove --window " + window + " 840 560 mouseup 1"),
            0);
  // What the window writes tells how far it got; each step waits for it (up to 60 s) instead of guessing a time.
  const auto written = [&](const std::function<bool(const fs::path&)>& test) {
    for (int i = 0; i < 300; ++i) {
      for (const auto& entry : fs::directory_iterator(out)) {
        if (entry.path().extension() != ".partial" && test(entry.path())) return true;
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(200));
    }
    return false;
  };
  // The dragged pose: w until the saved pose has the flexion.
  bool flexed = false;
  for (int attempt = 0; attempt < 20 && !flexed; ++attempt) {
    key("w", 300);
    flexed = written([](const fs::path& p) {
      std::string why;
      const auto pose = p.extension() == ".json" ? view::pose_from_json(file_text(p), &why) : std::nullopt;
      return pose && std::any_of(pose->joints.begin(), pose->joints.end(),
                                 [](const auto& j) { return j.second.flexion > 10.0; });
    });
  }
  EXPECT_TRUE(flexed) << "the slider drag did not reach the saved pose";
  key("c", 500);
  key("c", 500);
  // The full volume: pictures (k) until one shows the slices layout, where the coronal view fills the bottom left.
  key("f", 500);
  const auto shows_slices = [](const fs::path& p) {
    if (p.extension() != ".png") return false;
    const Image picture = read_png(p);
    int64_t lit = 0;
    for (int y = 100; y < 330 && picture.width == 900; ++y) {
      for (int x = 160; x < 400; ++x)
        lit += std::max({picture.at(x, y)[0], picture.at(x, y)[1], picture.at(x, y)[2]}) > 60;
    }
    return lit > 2000;
  };
  bool pictured = false;
  for (int attempt = 0; attempt < 60 && !pictured; ++attempt) {
    key("k", 500);
    for (const auto& entry : fs::directory_iterator(out)) pictured |= shows_slices(entry.path());
  }
  EXPECT_TRUE(pictured) << "no picture of the slices";
  key("v", 300);
  key("d", 300);
  const bool saved = written([](const fs::path& p) {
    return fs::is_directory(p) && fs::exists(p / "labels.nii.gz") && fs::exists(p / "ct.nii.gz") &&
           fs::exists(p / "report.json");
  });
  EXPECT_TRUE(saved) << "the posed files were not saved";
  xdotool("key --window " + window + " q");  // may fail on the key's release: the window is gone by then
  int status = -1;
  for (int i = 0; i < 100 && ::waitpid(viewer, &status, WNOHANG) == 0; ++i)
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
  if (::waitpid(viewer, &status, WNOHANG) == 0) {
    ::kill(viewer, SIGKILL);
    ::waitpid(viewer, &status, 0);
    FAIL() << "q did not close the window";
  }
  EXPECT_TRUE(WIFEXITED(status) && WEXITSTATUS(status) == 0);
}

// A posed volume as the Pose call sends it: raw uint8 labels and int16 CT on `grid`, the voxel at index (i, j, k)
// holding label value(i, j, k) and CT 10 * value(i, j, k).
view::PosedVolumes synthetic(const std::array<int, 3>& n, const std::array<double, 9>& direction,
                             const std::array<double, 3>& spacing, const std::array<double, 3>& origin,
                             const std::function<int(int, int, int)>& value) {
  view::PosedVolumes posed;
  v1::Grid& grid = *posed.header.mutable_grid();
  for (int a = 0; a < 3; ++a) {
    grid.add_size(n[static_cast<size_t>(a)]);
    grid.add_spacing(spacing[static_cast<size_t>(a)]);
    grid.add_origin(origin[static_cast<size_t>(a)]);
  }
  for (double d : direction) grid.add_direction(d);
  posed.header.set_label_sample_type(v1::PIXEL_TYPE_UINT8);
  posed.header.set_ct_sample_type(v1::PIXEL_TYPE_INT16);
  for (int k = 0; k < n[2]; ++k) {
    for (int j = 0; j < n[1]; ++j) {
      for (int i = 0; i < n[0]; ++i) {
        const int v = value(i, j, k);
        posed.labels.push_back(static_cast<char>(v));
        const int16_t ct = static_cast<int16_t>(10 * v);
        posed.ct.append(reinterpret_cast<const char*>(&ct), 2);
      }
    }
  }
  return posed;
}

// The world position (LPS mm) of index (i, j, k) on a grid, as ITK defines it.
std::array<double, 3> world(const std::array<double, 9>& d, const std::array<double, 3>& spacing,
                            const std::array<double, 3>& origin, int i, int j, int k) {
  const double index[3] = {i * spacing[0], j * spacing[1], k * spacing[2]};
  std::array<double, 3> p = origin;
  for (int r = 0; r < 3; ++r) {
    for (int c = 0; c < 3; ++c) p[static_cast<size_t>(r)] += d[static_cast<size_t>(3 * r + c)] * index[c];
  }
  return p;
}

TEST(ViewerSlices, AGridOnPermutedAndFlippedAxesIsTurnedOntoLps) {
  // Index axis 0 runs toward anterior (-y), axis 1 toward superior (+z), axis 2 toward the patient's right (-x).
  const std::array<double, 9> direction{0, 0, -1, -1, 0, 0, 0, 1, 0};
  const std::array<int, 3> n{4, 5, 6};
  const std::array<double, 3> spacing{1.5, 2.0, 0.5}, origin{10.0, -20.0, 30.0};
  const auto value = [](int i, int j, int k) { return 1 + i + 4 * j + 20 * k; };
  view::SliceVolume volume;
  std::string why;
  ASSERT_TRUE(view::slice_volume(synthetic(n, direction, spacing, origin, value), &volume, &why)) << why;
  EXPECT_FALSE(volume.oblique);
  EXPECT_EQ(volume.size, (std::array<int, 3>{6, 4, 5}));
  EXPECT_EQ(volume.spacing, (std::array<double, 3>{0.5, 1.5, 2.0}));
  // Every source voxel lands where its world position says, with its values.
  for (int k = 0; k < n[2]; ++k) {
    for (int j = 0; j < n[1]; ++j) {
      for (int i = 0; i < n[0]; ++i) {
        const std::array<double, 3> p = world(direction, spacing, origin, i, j, k);
        int at[3];
        for (size_t a = 0; a < 3; ++a) {
          const double index = (p[a] - volume.origin[a]) / volume.spacing[a];
          ASSERT_NEAR(index, std::round(index), 1e-9);
          at[a] = static_cast<int>(std::lround(index));
          ASSERT_GE(at[a], 0);
          ASSERT_LT(at[a], volume.size[a]);
        }
        const size_t linear = static_cast<size_t>(at[0] + volume.size[0] * (at[1] + volume.size[1] * at[2]));
        EXPECT_EQ(volume.labels[linear], value(i, j, k));
        EXPECT_EQ(volume.ct[linear], 10.0f * static_cast<float>(value(i, j, k)));
      }
    }
  }
  // A header that promises more voxels than came: an error, not a read past the end.
  view::PosedVolumes short_one = synthetic(n, direction, spacing, origin, value);
  short_one.ct.resize(short_one.ct.size() - 2);
  EXPECT_FALSE(view::slice_volume(short_one, &volume, &why));
}

// Where the patient's left, anterior and superior parts show in each view: axial with the left on the right and
// anterior up, coronal with the left on the right and superior up, sagittal with anterior on the left and superior
// up (the radiological convention).
TEST(ViewerSlices, TheViewsFollowTheRadiologicalConvention) {
  const std::array<double, 9> identity{1, 0, 0, 0, 1, 0, 0, 0, 1};
  const std::array<int, 3> n{30, 30, 30};
  const auto render = [&](const std::function<int(int, int, int)>& value) {
    view::SliceVolume volume;
    std::string why;
    EXPECT_TRUE(view::slice_volume(synthetic(n, identity, {2, 2, 2}, {0, 0, 0}, value), &volume, &why)) << why;
    view::Scene scene(600, 600, true);
    scene.slices().set_volume(std::move(volume));
    scene.slices().set_label_opacity(1.0);
    scene.set_layout(view::Scene::Layout::kSlices);
    scene.set_status("");
    std::string why_not;
    const fs::path png = fs::temp_directory_path() / ("posewarp-viewer-slices-" + std::to_string(::getpid()) + ".png");
    EXPECT_TRUE(scene.snapshot(png.string(), &why_not)) << why_not;
    Image image = read_png(png);
    fs::remove(png);
    return image;
  };
  // Coloured (labelled) pixels in a window rectangle [x0, x1) x [y0, y1), rows from the bottom.
  const auto coloured = [](const Image& image, int x0, int x1, int y0, int y1) {
    int64_t count = 0;
    for (int y = y0; y < y1; ++y) {
      for (int x = x0; x < x1; ++x) {
        const unsigned char* p = image.at(x, y);
        count += std::max({p[0], p[1], p[2]}) - std::min({p[0], p[1], p[2]}) > 80;
      }
    }
    return count;
  };
  // Quadrants (600x600, rows from the bottom): axial top right, coronal bottom left, sagittal bottom right. Each
  // half is split away from its centre line (the cursor lines) by 20 pixels.
  struct Half {
    int x0, x1, y0, y1;
  };
  const auto left_right = [](int qx, int qy) {
    return std::pair{Half{qx + 20, qx + 130, qy + 40, qy + 260}, Half{qx + 170, qx + 280, qy + 40, qy + 260}};
  };
  const auto bottom_top = [](int qx, int qy) {
    return std::pair{Half{qx + 40, qx + 260, qy + 20, qy + 130}, Half{qx + 40, qx + 260, qy + 170, qy + 280}};
  };
  const auto more_in_second = [&](const Image& image, const std::pair<Half, Half>& halves) {
    const auto& [a, b] = halves;
    return coloured(image, b.x0, b.x1, b.y0, b.y1) > 10 * (1 + coloured(image, a.x0, a.x1, a.y0, a.y1));
  };
  const auto more_in_first = [&](const Image& image, const std::pair<Half, Half>& halves) {
    return more_in_second(image, {halves.second, halves.first});
  };
  // The patient's left (x > centre): on the right in axial and coronal.
  const Image left = render([](int i, int, int) { return i >= 18 ? 1 : 0; });
  EXPECT_TRUE(more_in_second(left, left_right(300, 300))) << "axial: left not on the right";
  EXPECT_TRUE(more_in_second(left, left_right(0, 0))) << "coronal: left not on the right";
  // Anterior (y < centre): up in axial, on the left in sagittal.
  const Image anterior = render([](int, int j, int) { return j < 12 ? 2 : 0; });
  EXPECT_TRUE(more_in_second(anterior, bottom_top(300, 300))) << "axial: anterior not up";
  EXPECT_TRUE(more_in_first(anterior, left_right(300, 0))) << "sagittal: anterior not on the left";
  // Superior (z > centre): up in coronal and sagittal.
  const Image superior = render([](int, int, int k) { return k >= 18 ? 3 : 0; });
  EXPECT_TRUE(more_in_second(superior, bottom_top(0, 0))) << "coronal: superior not up";
  EXPECT_TRUE(more_in_second(superior, bottom_top(300, 0))) << "sagittal: superior not up";
}
}  // namespace
}  // namespace posewarp
