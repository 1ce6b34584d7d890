// What posewarp-view's keys, clicks and timer do.
#include "app.h"

#include <vtkRenderWindowInteractor.h>
#include <vtkRenderer.h>
#include <vtkSliderRepresentation2D.h>
#include <vtkSliderWidget.h>

#include <algorithm>
#include <cmath>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <thread>

#include "files.h"

namespace posewarp::view {
namespace fs = std::filesystem;

v1::Method method_named(const std::string& name) {
  return name == "dqs"   ? v1::METHOD_DQS
         : name == "lbs" ? v1::METHOD_LBS
         : name == "fem" ? v1::METHOD_FEM
                         : v1::METHOD_COR;
}

v1::GridPolicy grid_named(const std::string& name) {
  return name == "grow" ? v1::GRID_POLICY_GROW : v1::GRID_POLICY_INPUT;
}

std::optional<Pose> read_pose(const std::string& path, std::string* error) {
  std::ifstream in(path);
  std::ostringstream text;
  text << in.rdbuf();
  if (!in) {
    *error = "pose file '" + path + "' cannot be read";
    return std::nullopt;
  }
  std::string why;
  std::optional<Pose> pose = pose_from_json(text.str(), &why);
  if (!pose) *error = "pose file '" + path + "': " + why;
  return pose;
}

namespace {

std::string megabytes(uint64_t bytes) {
  char text[32];
  std::snprintf(text, sizeof text, "%.1f MB", static_cast<double>(bytes) / 1e6);
  return text;
}

}  // namespace

std::string progress_text(const std::string& what, const VolumeRequest& request) {
  const auto [received, expected] = request.progress();
  if (received == 0) return what + ": posing on the server...";
  return what + ": received " + megabytes(received) + (expected > 0 ? " of " + megabytes(expected) : "") +
         " (Esc cancels)";
}

namespace {

std::string clock_time() {
  const std::time_t now = std::time(nullptr);
  char text[32];
  std::strftime(text, sizeof text, "%H:%M:%S", std::localtime(&now));
  return text;
}

std::string stamp() {
  const std::time_t now = std::time(nullptr);
  char text[32];
  std::strftime(text, sizeof text, "%Y%m%d-%H%M%S", std::localtime(&now));
  return text;
}

}  // namespace

std::vector<std::string> pose_files_in(const std::string& dir) {
  std::vector<std::string> files;
  std::error_code ec;
  for (const auto& entry : fs::directory_iterator(dir, ec)) {
    std::string ignored;
    if (entry.path().extension() == ".json" && read_pose(entry.path().string(), &ignored))
      files.push_back(entry.path().string());
  }
  std::sort(files.begin(), files.end());
  return files;
}

void App::status(const std::string& text) {
  scene->set_status(text);
}

std::vector<std::string> App::joint_list() const {
  std::vector<std::string> names{"root"};
  names.insert(names.end(), scene->joint_names().begin(), scene->joint_names().end());
  return names;
}

void App::show_joint() {
  const std::array<double, 3> a = controller->chosen_angles();
  const char* titles[2][3] = {{"flexion", "abduction", "rotation"}, {"turn about L-R", "about A-P", "about S-I"}};
  for (int i = 0; i < 3 && sliders[i] != nullptr; ++i) {
    auto* rep = static_cast<vtkSliderRepresentation2D*>(sliders[i]->GetRepresentation());
    rep->SetMinimumValue(controller->at_root() ? -180.0 : -120.0);
    rep->SetMaximumValue(controller->at_root() ? 180.0 : 120.0);
    rep->SetTitleText(titles[controller->at_root() ? 1 : 0][i]);
    rep->SetValue(a[static_cast<size_t>(i)]);
  }
  scene->set_joint_list(joint_list(), controller->joint());
}

void App::layout(Scene::Layout layout) {
  scene->set_layout(layout);
  // The sliders sit in the bottom right corner of the 3D view; the slices leave it too small for them (v returns).
  const double right = layout == Scene::Layout::kSingle ? 0.97 : 0.48,
               width = layout == Scene::Layout::kSingle ? 0.25 : 0.2;
  for (int i = 0; i < 3 && sliders[i] != nullptr; ++i) {
    auto* rep = static_cast<vtkSliderRepresentation2D*>(sliders[i]->GetRepresentation());
    rep->GetPoint1Coordinate()->SetValue(right - width, 0.06 + 0.07 * (2 - i));
    rep->GetPoint2Coordinate()->SetValue(right, 0.06 + 0.07 * (2 - i));
    rep->Modified();  // its coordinates changing does not tell it
    sliders[i]->SetEnabled(layout == Scene::Layout::kSlices ? 0 : 1);
  }
}

// index in joint_list()'s order.
void App::choose(int index) {
  if (index <= 0) {
    controller->select_root();
  } else {
    controller->select_joint(static_cast<size_t>(index - 1));
  }
  show_joint();
}

void App::full_volume() {
  if (volume_request || converting.valid()) return status("a full volume is on its way already (Esc cancels)");
  volume_request = std::make_unique<VolumeRequest>(*client, options.rig_id, controller->pose(), controller->method(),
                                                   true, grid_named(options.grid));
  requested_pose = pose_json(controller->pose()) + method_name(controller->method());
  compare_report.reset();
  compare_request.reset();
  if (compare) {  // the other method's figures for the same pose, beside the slices' report
    compare_request_method = controller->compare_method();
    compare_request = VolumeRequest::report_only(*client, options.rig_id, controller->pose(), compare_request_method);
  }
  status(progress_text("full volume", *volume_request));
}

void App::show_report() {
  if (compare_report) {
    scene->set_report(shown_title, shown_report, &*compare_report, method_name(shown_method), compare_report_method);
  } else {
    scene->set_report(shown_title, shown_report);
  }
}

void App::save_volumes() {
  if (save_request) return status("a save is running already (Esc cancels)");
  save_dir = (fs::path(options.out_dir) / ("posewarp-view-" + stamp())).string();
  save_request = std::make_unique<VolumeRequest>(*client, options.rig_id, controller->pose(), controller->method(),
                                                 false, grid_named(options.grid));
  status(progress_text("saving", *save_request));
}

void App::toggle_compare() {
  if (compare) {
    controller->set_compare(nullptr, v1::METHOD_DQS);
    compare.reset();
    layout(Scene::Layout::kSingle);
    return;
  }
  // The other method: the next one after the current (CoR -> DQS -> LBS -> FEM -> CoR).
  const v1::Method other = controller->method() == v1::METHOD_COR   ? v1::METHOD_DQS
                           : controller->method() == v1::METHOD_DQS ? v1::METHOD_LBS
                           : controller->method() == v1::METHOD_LBS ? v1::METHOD_FEM
                                                                    : v1::METHOD_COR;
  compare = std::make_unique<PreviewSession>(*client, options.rig_id);
  controller->set_compare(compare.get(), other);
  layout(Scene::Layout::kCompare);
}

void App::reconnect() {
  // The old streams go first (a server limits the streams of one client).
  const bool comparing = compare != nullptr;
  const v1::Method other = controller->compare_method();
  if (comparing) {
    controller->set_compare(nullptr, other);
    compare.reset();
  }
  auto fresh = std::make_unique<PreviewSession>(*client, options.rig_id);
  controller->set_session(*fresh);
  session = std::move(fresh);
  if (comparing) {
    compare = std::make_unique<PreviewSession>(*client, options.rig_id);
    controller->set_compare(compare.get(), other);
  }
  stream_lost = false;
  status("reconnecting to " + client->server() + "...");
}

void App::load_next_pose() {
  if (pose_files.empty()) return status("no pose files in '" + options.poses_dir + "' (--poses DIR)");
  const std::string path = pose_files[next_pose_file++ % pose_files.size()];
  std::string why;
  std::optional<Pose> pose = read_pose(path, &why);
  if (!pose) return status(why);
  controller->set_pose(*pose);
  show_joint();
  status("loaded " + fs::path(path).filename().string());
}

void App::save_pose() {
  const std::string path = (fs::path(options.out_dir) / ("pose-" + stamp() + ".json")).string();
  std::string why;
  status(write_file(path, pose_json(controller->pose()) + "\n", &why) ? "saved the pose to " + path : why);
}

// Called every 15 ms on the render thread: draws new answers and finishes requests.
bool App::poll_stream() {
  const CallError ended = session->ended().failed() ? session->ended() : compare ? compare->ended() : CallError{};
  if (stream_lost || !ended.failed()) return false;
  stream_lost = true;
  status((ended.code == grpc::StatusCode::UNAVAILABLE ? "lost the server: " : "the preview stopped: ") + ended.message +
         "  (x reconnects)");
  return true;
}

bool App::poll_volume(std::chrono::steady_clock::time_point now, bool progress_due) {
  if (volume_request && !volume_request->done() && progress_due) {
    status(progress_text("full volume", *volume_request));
    last_progress = now;
    return true;
  }
  if (!volume_request || !volume_request->done() || converting.valid()) return false;
  PosedVolumes result;
  const CallError e = volume_request->take(&result);
  volume_request.reset();
  if (e.failed()) {
    status("full volume: " + e.message);
    return true;
  }
  status("full volume: arrived, preparing the slices...");
  arrived = std::move(result);
  converting = std::async(std::launch::async, [this]() -> std::pair<bool, std::string> {
    try {
      std::string why;
      const bool ok = slice_volume(arrived, &converted, &why);
      return {ok, why};
    } catch (const std::bad_alloc&) {
      return {false, "not enough memory for the slices of this volume"};
    }
  });
  return true;
}

bool App::poll_slices() {
  if (!converting.valid() || converting.wait_for(std::chrono::seconds(0)) != std::future_status::ready) return false;
  const auto [ok, why] = converting.get();
  if (!ok) {
    status("full volume: " + why);
  } else {
    scene->slices().set_volume(std::move(converted));
    shown_pose = requested_pose, shown_report = arrived.report, stale = false;
    shown_method = controller->method();
    shown_title = "quality report (" + clock_time() + ", " + requested_pose.substr(requested_pose.rfind('}') + 1) + ")";
    show_report();
    if (compare) toggle_compare();
    layout(Scene::Layout::kSlices);
    status("full volume shown: click a slice to move the cursor, arrows step, b window, +/- label opacity");
  }
  arrived = PosedVolumes{};
  return true;
}

bool App::poll_compare_report() {
  if (!compare_request || !compare_request->done()) return false;
  PosedVolumes result;
  const CallError e = compare_request->take(&result);
  compare_request.reset();
  if (e.failed()) {
    status(std::string("the ") + method_name(compare_request_method) + " report: " + e.message);
  } else {
    compare_report = result.report;
    compare_report_method = method_name(compare_request_method);
    if (scene->slices().has_volume() && !stale) show_report();
  }
  return true;
}

bool App::mark_stale() {
  if (!scene->slices().has_volume() || stale ||
      pose_json(controller->pose()) + method_name(controller->method()) == shown_pose) {
    return false;
  }
  stale = true;
  shown_title += "\nof an earlier pose: f refreshes";
  show_report();
  return true;
}

bool App::poll_save(std::chrono::steady_clock::time_point now, bool progress_due) {
  if (save_request && !save_request->done() && progress_due) {
    status(progress_text("saving", *save_request));
    last_progress = now;
    return true;
  }
  if (!save_request || !save_request->done()) return false;
  PosedVolumes result;
  const CallError e = save_request->take(&result);
  save_request.reset();
  std::string why;
  if (e.failed()) {
    status("saving: " + e.message);
  } else {
    status(save_posed(result, save_dir, &why) ? "saved the posed volumes, surfaces and report to " + save_dir : why);
  }
  return true;
}

bool App::tick() {
  bool redraw = controller->poll();
  redraw |= poll_stream();
  const auto now = std::chrono::steady_clock::now();
  const bool progress_due = now - last_progress > std::chrono::milliseconds(250);
  redraw |= poll_volume(now, progress_due);
  redraw |= poll_slices();
  redraw |= poll_compare_report();
  redraw |= mark_stale();
  redraw |= poll_save(now, progress_due);
  return redraw;
}

void App::key(const std::string& k) {
  const std::vector<std::string> names = joint_list();
  const auto at = std::find(names.begin(), names.end(), controller->joint());
  const int index = at == names.end() ? 0 : static_cast<int>(at - names.begin());
  const int count = static_cast<int>(names.size());
  if (k == "n" || k == "p") {
    choose(k == "n" ? (index + 1) % count : (index + count - 1) % count);
  } else if (k == "1" || k == "2" || k == "3" || k == "4") {
    controller->set_method(k == "1"   ? v1::METHOD_COR
                           : k == "2" ? v1::METHOD_DQS
                           : k == "3" ? v1::METHOD_LBS
                                      : v1::METHOD_FEM);
  } else if (k == "c") {
    toggle_compare();
  } else if (k == "r") {
    controller->reset_joint();
    show_joint();
  } else if (k == "R") {
    controller->reset_all();
    show_joint();
  } else if (k == "u") {
    controller->undo();
    show_joint();
  } else if (k == "a" || k == "l" || k == "s") {
    scene->set_view(k == "a" ? "anterior" : k == "l" ? "lateral" : "superior");
  } else if (k == "t") {
    tissue = !tissue;
    scene->show_tissue(tissue);
  } else if (k == "T") {
    const std::string shown = scene->next_tissue();
    status(shown.empty() ? "no tissue surface shown (T steps through them)" : "tissue surface: " + shown);
  } else if (k == "w") {
    save_pose();
  } else if (k == "o") {
    load_next_pose();
  } else if (k == "f") {
    full_volume();
  } else if (k == "v") {
    if (!scene->slices().has_volume()) return status("no full volume yet (f asks for one)");
    if (compare) toggle_compare();
    layout(scene->layout() == Scene::Layout::kSlices ? Scene::Layout::kSingle : Scene::Layout::kSlices);
  } else if (k == "b") {
    const bool bone = scene->slices().window().name == std::string(kBone.name);
    scene->slices().set_window(bone ? kSoftTissue : kBone);
    status(std::string("window: ") + scene->slices().window().name);
  } else if (k == "plus" || k == "equal" || k == "KP_Add" || k == "minus" || k == "KP_Subtract") {
    const bool up = k == "plus" || k == "equal" || k == "KP_Add";
    scene->slices().set_label_opacity(scene->slices().label_opacity() + (up ? 0.1 : -0.1));
    status("label opacity " + std::to_string(static_cast<int>(std::lround(100 * scene->slices().label_opacity()))) +
           "%");
  } else if ((k == "Up" || k == "Down") && interactor != nullptr) {
    int* at_mouse = interactor->GetEventPosition();
    for (int v = 0; v < 3; ++v) {
      vtkRenderer* r = scene->slices().renderer(v);
      if (r->GetDraw() && r->IsInViewport(at_mouse[0], at_mouse[1])) scene->slices().step(r, k == "Up" ? 1 : -1);
    }
  } else if (k == "d") {
    save_volumes();
  } else if (k == "k") {
    const std::string path = (fs::path(options.out_dir) / ("posewarp-view-" + stamp() + ".png")).string();
    std::string why;
    status(scene->snapshot(path, &why) ? "saved the picture to " + path : why);
  } else if (k == "x") {
    reconnect();
  } else if (k == "Escape") {
    if (volume_request) volume_request->cancel();
    if (compare_request) compare_request->cancel();
    if (save_request) save_request->cancel();
  } else if (k == "q" && interactor != nullptr) {
    interactor->TerminateApp();
  }
}

// A left click: a slice moves the cursor, a joint sphere chooses the joint; false lets the camera turn.
bool App::click(int x, int y) {
  for (int v = 0; v < 3; ++v) {
    vtkRenderer* r = scene->slices().renderer(v);
    if (r->GetDraw() && r->IsInViewport(x, y)) {
      scene->slices().click(r, x, y);
      return true;
    }
  }
  const int joint = scene->renderer()->IsInViewport(x, y) ? scene->joint_at(x, y) : -1;
  if (joint < 0) return false;
  choose(joint + 1);
  status("joint " + controller->joint());
  return true;
}

bool App::settle(int timeout_ms) {
  const auto until = std::chrono::steady_clock::now() + std::chrono::milliseconds(timeout_ms);
  for (;;) {
    tick();
    if (!volume_request && !save_request && !compare_request && !converting.valid()) return true;
    if (std::chrono::steady_clock::now() > until) return false;
    std::this_thread::sleep_for(std::chrono::milliseconds(5));
  }
}

}  // namespace posewarp::view
