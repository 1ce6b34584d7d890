// posewarp-view's window state and what its keys, clicks and timer do: the joint chosen, the streams, the full
// volume and the saves running off the render thread. The interactor and sliders are optional, so tests drive the
// same code the controls call.
#pragma once

#include <chrono>
#include <future>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "scene.h"

class vtkRenderWindowInteractor;
class vtkSliderWidget;

namespace posewarp::view {

struct Options {
  ServerAddress address;
  std::string rig_id, pose_path, poses_dir, method = "cor", compare, view = "anterior", snapshot, save, out_dir = ".",
                                            size = "1024x768", window = "soft", cursor, grid = "input";
  bool list = false, tissue = false, slices = false;
  double label_opacity = 0.4;
  int64_t triangles = Scene::kTriangleBudget;
};

v1::Method method_named(const std::string& name);    // "cor", "dqs" or "lbs"
v1::GridPolicy grid_named(const std::string& name);  // "input" or "grow"
// A pose file; an error naming it when it cannot be read or is not a pose the viewer reads.
std::optional<Pose> read_pose(const std::string& path, std::string* error);
// "full volume: received 12.3 MB of 60.9 MB (Esc cancels)".
std::string progress_text(const std::string& what, const VolumeRequest& request);
// The pose files (*.json that read as poses) of a directory, sorted.
std::vector<std::string> pose_files_in(const std::string& dir);

struct App {
  Options options;
  ViewerClient* client = nullptr;
  Scene* scene = nullptr;
  std::unique_ptr<PreviewSession> session, compare;
  Controller* controller = nullptr;
  vtkRenderWindowInteractor* interactor = nullptr;            // optional
  vtkSliderWidget* sliders[3] = {nullptr, nullptr, nullptr};  // optional
  bool tissue = false, stream_lost = false;
  // The full volume (for the slices) and a save, each a Pose call on its own thread; the conversion of a finished
  // volume runs off the render thread too.
  std::unique_ptr<VolumeRequest> volume_request, save_request;
  // While two methods are compared, the full volume's pose is also asked of the other method for its report only,
  // and the slices' report shows both side by side.
  std::unique_ptr<VolumeRequest> compare_request;
  v1::Method compare_request_method = v1::METHOD_DQS;
  std::optional<v1::QualityReport> compare_report;  // of the compare method, for requested_pose's pose
  std::string compare_report_method;
  SliceVolume converted;
  PosedVolumes arrived;
  // Declared after what it reads and writes, so it is waited for (destroyed) first.
  std::future<std::pair<bool, std::string>> converting;
  std::string requested_pose, shown_pose;  // the pose JSON and method of the volume asked for and of the one shown
  std::string shown_title;
  v1::QualityReport shown_report;
  v1::Method shown_method = v1::METHOD_COR;  // of the volume shown
  bool stale = false;    // the pose changed since the volume shown
  std::string save_dir;  // of the save running or last done
  std::vector<std::string> pose_files;
  size_t next_pose_file = 0;
  std::chrono::steady_clock::time_point last_progress;

  void status(const std::string& text);
  // "root", then the skeleton's joints.
  std::vector<std::string> joint_list() const;
  // The sliders and the joint list show the chosen joint.
  void show_joint();
  void choose(int index);
  // Changes the window's layout and moves the sliders into the 3D view.
  void layout(Scene::Layout layout);
  void full_volume();
  // The slices' report: the shown pose's, beside the compare method's when it has arrived for that pose.
  void show_report();
  void save_volumes();
  void toggle_compare();
  void reconnect();
  void load_next_pose();
  void save_pose();
  // Called every 15 ms on the render thread: draws new answers and finishes requests; true when it drew.
  bool tick();
  // tick's parts, each true when it changed what the window shows: the preview stream lost, the full volume's
  // progress and arrival, its slices ready, the compare method's report, the slices outdated by a newer pose, a
  // save's progress and end.
  bool poll_stream();
  bool poll_volume(std::chrono::steady_clock::time_point now, bool progress_due);
  bool poll_slices();
  bool poll_compare_report();
  bool mark_stale();
  bool poll_save(std::chrono::steady_clock::time_point now, bool progress_due);
  // A key by its X keysym ("n", "Up", "Escape", ...).
  void key(const std::string& k);
  // A left click: a slice moves the cursor, a joint sphere chooses the joint; false lets the camera turn.
  bool click(int x, int y);
  // Waits (pumping tick) until no request runs, at most timeout_ms; for scripts and tests.
  bool settle(int timeout_ms);
};

}  // namespace posewarp::view
