// posewarp-view: previews poses of a rig held by posewarp-server, live (sliders) or as offscreen snapshots, and
// shows the posed volume as slices with its quality report.
#include <vtkCallbackCommand.h>
#include <vtkCommand.h>
#include <vtkInteractorStyleTrackballCamera.h>
#include <vtkObjectFactory.h>
#include <vtkRenderWindow.h>
#include <vtkRenderWindowInteractor.h>
#include <vtkRenderer.h>
#include <vtkSliderRepresentation2D.h>
#include <vtkSliderWidget.h>
#include <vtkTextProperty.h>
#include <CLI/CLI.hpp>

#include <unistd.h>
#include <cmath>

#include <array>
#include <cstdio>
#include <filesystem>
#include <memory>
#include <optional>

#include "app.h"
#include "files.h"

namespace {

using namespace posewarp::view;
namespace v1 = posewarp::v1;
namespace fs = std::filesystem;

int fail(const std::string& message, int code = 1) {
  std::fprintf(stderr, "error: %s\n", message.c_str());
  return code;
}

// gRPC's code -> the CLI's exit codes: 2 for what the user can fix (bad input, unknown rig), 3 over a limit, 1
// otherwise.
int exit_code(const CallError& e) {
  switch (e.code) {
    case grpc::StatusCode::INVALID_ARGUMENT:
    case grpc::StatusCode::NOT_FOUND:
    case grpc::StatusCode::UNAUTHENTICATED:
    case grpc::StatusCode::PERMISSION_DENIED:
    case grpc::StatusCode::FAILED_PRECONDITION: return 2;
    case grpc::StatusCode::RESOURCE_EXHAUSTED: return 3;
    default: return 1;
  }
}

// Waits for a request from the command line, saying how far it got about once a second.
CallError finish(VolumeRequest& request, const std::string& what, PosedVolumes* result) {
  std::string last;
  while (!request.wait(1000)) {
    const std::string now = progress_text(what, request);
    if (now != last) std::fprintf(stderr, "%s\n", now.c_str());
    last = now;
  }
  return request.take(result);
}

// The trackball camera without its own keys (posewarp-view's keys are its own), with clicks on slices and
// joint spheres taken by the app, and the wheel stepping slices over a slice view.
class ViewerStyle : public vtkInteractorStyleTrackballCamera {
 public:
  static ViewerStyle* New();
  vtkTypeMacro(ViewerStyle, vtkInteractorStyleTrackballCamera) App* app = nullptr;
  void OnChar() override {}
  void OnLeftButtonDown() override {
    const int* at = GetInteractor()->GetEventPosition();
    if (app != nullptr && app->click(at[0], at[1])) {
      GetInteractor()->Render();
    } else {
      vtkInteractorStyleTrackballCamera::OnLeftButtonDown();
    }
  }
  void OnMouseWheelForward() override { wheel(1); }
  void OnMouseWheelBackward() override { wheel(-1); }

 private:
  void wheel(int steps) {
    const int* at = GetInteractor()->GetEventPosition();
    for (int v = 0; app != nullptr && v < 3; ++v) {
      vtkRenderer* r = app->scene->slices().renderer(v);
      if (r->GetDraw() && r->IsInViewport(at[0], at[1])) {
        app->scene->slices().step(r, steps);
        GetInteractor()->Render();
        return;
      }
    }
    if (steps > 0) {
      vtkInteractorStyleTrackballCamera::OnMouseWheelForward();
    } else {
      vtkInteractorStyleTrackballCamera::OnMouseWheelBackward();
    }
  }
};
vtkStandardNewMacro(ViewerStyle);

void on_slider(vtkObject* caller, unsigned long, void* client, void*) {
  auto* app = static_cast<App*>(client);
  for (int i = 0; i < 3; ++i) {
    if (caller == app->sliders[i]) {
      const double value = static_cast<vtkSliderRepresentation2D*>(app->sliders[i]->GetRepresentation())->GetValue();
      app->controller->set_angle(i, std::round(value));
    }
  }
}

void on_timer(vtkObject* caller, unsigned long, void* client, void*) {
  if (static_cast<App*>(client)->tick()) static_cast<vtkRenderWindowInteractor*>(caller)->Render();
}

void on_key(vtkObject* caller, unsigned long, void* client, void*) {
  auto* interactor = static_cast<vtkRenderWindowInteractor*>(caller);
  static_cast<App*>(client)->key(interactor->GetKeySym() ? interactor->GetKeySym() : "");
  interactor->Render();
}

vtkSmartPointer<vtkSliderWidget> make_slider(vtkRenderWindowInteractor* interactor, vtkRenderer* renderer,
                                             const char* title, double y) {
  auto rep = vtkSmartPointer<vtkSliderRepresentation2D>::New();
  rep->SetMinimumValue(-120.0);
  rep->SetMaximumValue(120.0);
  rep->SetValue(0.0);
  rep->SetTitleText(title);
  rep->GetPoint1Coordinate()->SetCoordinateSystemToNormalizedDisplay();
  rep->GetPoint1Coordinate()->SetValue(0.72, y);
  rep->GetPoint2Coordinate()->SetCoordinateSystemToNormalizedDisplay();
  rep->GetPoint2Coordinate()->SetValue(0.97, y);
  rep->SetSliderLength(0.02);
  rep->SetTubeWidth(0.006);
  rep->SetLabelFormat("%.0f");
  rep->SetTitleHeight(0.018);
  rep->SetLabelHeight(0.018);
  rep->SetEndCapLength(0.006);
  rep->SetEndCapWidth(0.02);
  rep->SetSliderWidth(0.015);
  auto widget = vtkSmartPointer<vtkSliderWidget>::New();
  widget->SetInteractor(interactor);
  widget->SetDefaultRenderer(renderer);  // the 3D view's, not whichever renderer lies under (0, 0)
  widget->SetRepresentation(rep);
  widget->SetAnimationModeToJump();
  widget->EnabledOn();
  return widget;
}

constexpr const char* kHelp =
    "posewarp-view: preview poses of a rig held by posewarp-server.\n\n"
    "In the window: n/p (or a click on a joint's sphere) choose the joint, the first entry being the root; the three "
    "sliders set its flexion, abduction and axial rotation (degrees, the joint's own frame; the root's turn about "
    "L-R, A-P and S-I). 1/2/3/4 CoR/DQS/LBS/FEM, c two methods side by side, r/R reset the joint/all, u undo, "
    "a/l/s anterior/lateral/superior view, t tissue surfaces, T one tissue surface at a time, w save the pose JSON, o "
    "load the next pose of --poses, "
    "f full volume (posed CT and labels as three slices with the quality report; a click moves the cursor, arrows or "
    "the wheel step a slice, b bone/soft-tissue window, +/- label opacity, v back to 3D), d save the posed volumes, "
    "surfaces and report, k save a picture of the window, Esc cancel a running request, x reconnect the preview, "
    "q quit.\n\n"
    "With --snapshot it renders once offscreen and exits (use xvfb-run without a display); with --save it writes "
    "the posed files and exits.";

// The command line, every option with its help: nullopt to go on, else the exit code (--help, a bad option).
std::optional<int> parse_options(int argc, char** argv, Options& o) {
  CLI::App app{kHelp};
  app.add_option("--server", o.address.server, "posewarp-server at HOST:PORT")->required();
  app.add_option("--token-file", o.address.token_file, "File holding the server's bearer token");
  app.add_option("--tls-ca", o.address.tls_ca, "CA certificate (PEM) of a TLS server");
  app.add_flag("--list", o.list, "List the server's rigs (id, name, size, created) and exit");
  app.add_option("--rig", o.rig_id, "Rig id to open (default: the only rig, or one chosen from a list at a terminal)");
  app.add_option("--pose", o.pose_path, "Pose JSON to start from (the CLI's; joints in angles_deg)");
  app.add_option("--poses", o.poses_dir, "Directory of pose JSONs that o steps through (default: --pose's directory)");
  app.add_option("--method", o.method, "How the tissue moves: cor, dqs, lbs or fem (volume-preserving, slower)")
      ->check(CLI::IsMember({"cor", "dqs", "lbs", "fem"}))
      ->capture_default_str();
  app.add_option("--compare", o.compare,
                 "Show this method side by side with --method; with --slices (or f), the two methods' report figures side by side")
      ->check(CLI::IsMember({"cor", "dqs", "lbs", "fem"}));
  app.add_option("--view", o.view, "Camera: anterior, lateral or superior")
      ->check(CLI::IsMember({"anterior", "lateral", "superior"}))
      ->capture_default_str();
  app.add_flag("--tissue", o.tissue, "Show the tissue surfaces too");
  app.add_flag("--slices", o.slices, "Ask for the full posed volume and show its slices with the quality report");
  app.add_option("--cursor", o.cursor, "Where the slices cross: X,Y,Z in LPS mm (default: the volume's centre)");
  app.add_option("--window", o.window, "CT window of the slices: soft (tissue) or bone")
      ->check(CLI::IsMember({"soft", "bone"}))
      ->capture_default_str();
  app.add_option("--label-opacity", o.label_opacity, "Opacity of the labels over the CT, 0 to 1")
      ->check(CLI::Range(0.0, 1.0))
      ->capture_default_str();
  app.add_option("--grid", o.grid,
                 "Grid of the full volume and saved files: input (the study's, as the CLI) or grow "
                 "(grown to hold the posed body)")
      ->check(CLI::IsMember({"input", "grow"}))
      ->capture_default_str();
  app.add_option("--snapshot", o.snapshot, "Render offscreen to this PNG and exit");
  app.add_option("--save", o.save, "Write the posed volumes, surfaces, report and pose into this directory and exit");
  app.add_option("--out-dir", o.out_dir, "Where w and d write in the window")->capture_default_str();
  app.add_option("--size", o.size, "Window or snapshot size WxH")->capture_default_str();
  app.add_option("--triangles", o.triangles, "Draw a rig with more triangles than this with fewer (0: every one)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  CLI11_PARSE(app, argc, argv);
  return std::nullopt;
}

// What the options say beyond CLI11's checks: the window's size and the slices' cursor.
struct Checked {
  int width = 0, height = 0;
  std::array<double, 3> cursor{};
};

std::optional<int> check_options(const Options& o, Checked* checked) {
  int& width = checked->width;
  int& height = checked->height;
  if (std::sscanf(o.size.c_str(), "%dx%d", &width, &height) != 2 || width < 64 || height < 64 || width > 8192 ||
      height > 8192) {
    return fail("--size takes WxH between 64x64 and 8192x8192, not '" + o.size + "'", 2);
  }
  std::array<double, 3>& cursor = checked->cursor;
  if (!o.cursor.empty() && (std::sscanf(o.cursor.c_str(), "%lf,%lf,%lf", &cursor[0], &cursor[1], &cursor[2]) != 3 ||
                            !std::isfinite(cursor[0] + cursor[1] + cursor[2]))) {
    return fail("--cursor takes X,Y,Z in millimetres, not '" + o.cursor + "'", 2);
  }
  if (o.compare == o.method) return fail("--compare names the method --method shows already; choose another", 2);
  return std::nullopt;
}

// --list: the server's rigs, one a line.
int print_rigs(const std::vector<v1::Rig>& rigs) {
  for (const v1::Rig& rig : rigs) {
    std::printf("%s  %-24s %10.1f MB  %s\n", rig.id().c_str(), rig.name().c_str(),
                static_cast<double>(rig.size_bytes()) / 1e6, rig.created().c_str());
  }
  return 0;
}

// The rig to open: --rig, else the only one, else one the user chooses from a numbered list at a terminal.
std::optional<int> choose_rig(const std::vector<v1::Rig>& rigs, Options& o) {
  if (!o.rig_id.empty()) return std::nullopt;
  const bool ask = rigs.size() > 1 && o.snapshot.empty() && o.save.empty() && ::isatty(0) && ::isatty(1);
  if (ask) {
    for (size_t i = 0; i < rigs.size(); ++i) {
      std::printf("%3zu  %-24s %10.1f MB  %s  %s\n", i + 1, rigs[i].name().c_str(),
                  static_cast<double>(rigs[i].size_bytes()) / 1e6, rigs[i].created().c_str(), rigs[i].id().c_str());
    }
    std::printf("open which rig (1-%zu)? ", rigs.size());
    std::fflush(stdout);
    size_t chosen = 0;
    if (std::scanf("%zu", &chosen) != 1 || chosen < 1 || chosen > rigs.size()) return fail("no rig chosen", 2);
    o.rig_id = rigs[chosen - 1].id();
  } else if (rigs.size() != 1) {
    return fail(
        "the server holds " + std::to_string(rigs.size()) + " rigs; choose one with --rig ID (--list lists them)", 2);
  } else {
    o.rig_id = rigs.front().id();
  }
  return std::nullopt;
}

// --save: the posed volumes, surfaces, report and pose written into a directory, without a window.
std::optional<int> save_without_window(ViewerClient& client, const Options& o, const Pose& start, v1::Method method) {
  VolumeRequest request(client, o.rig_id, start, method, false, grid_named(o.grid));
  PosedVolumes posed;
  if (CallError e = finish(request, "saving", &posed); e.failed()) return fail(e.message, exit_code(e));
  std::string why;
  if (!save_posed(posed, o.save, &why)) return fail(why);
  std::fprintf(stderr, "wrote the posed volumes, surfaces, report and pose to %s\n", o.save.c_str());
  return std::nullopt;
}

// The first preview (and the compared method's), waited for: the server's refusal of the start pose ends here.
std::optional<int> first_preview(PreviewSession& session, PreviewSession* compare, Controller& controller) {
  const auto answered = [&](PreviewSession& s, uint64_t sequence) -> std::optional<int> {
    if (s.wait_for(sequence, 30000)) return std::nullopt;
    const CallError e = s.ended();
    return fail(e.failed() ? e.message : "the server did not answer the preview within 30 s",
                e.failed() ? exit_code(e) : 1);
  };
  if (std::optional<int> failed = answered(session, controller.last_sent())) return failed;
  if (compare != nullptr) {
    if (std::optional<int> failed = answered(*compare, 1)) return failed;
  }
  controller.poll();
  if (const CallError& e = controller.last_error(); e.failed()) {
    return fail("the server refused the pose: " + e.message, exit_code(e));
  }
  return std::nullopt;
}

// The reports shown beside the slices: this method's, and with --compare the other method's.
struct ShownReports {
  v1::QualityReport report;
  std::optional<v1::QualityReport> compare;
};

// --slices: the full posed volume as three slices with its quality report.
std::optional<int> show_slices(ViewerClient& client, const Options& o, const Checked& checked, const Pose& start,
                               v1::Method method, Scene& scene, ShownReports* shown) {
  VolumeRequest request(client, o.rig_id, start, method, true, grid_named(o.grid));
  std::unique_ptr<VolumeRequest> other =
      o.compare.empty() ? nullptr : VolumeRequest::report_only(client, o.rig_id, start, method_named(o.compare));
  PosedVolumes posed;
  if (CallError e = finish(request, "full volume", &posed); e.failed()) return fail(e.message, exit_code(e));
  if (other) {
    PosedVolumes report;
    if (CallError e = finish(*other, "the " + o.compare + " report", &report); e.failed()) {
      return fail(e.message, exit_code(e));
    }
    shown->compare = report.report;
  }
  SliceVolume volume;
  std::string why;
  if (!slice_volume(posed, &volume, &why)) return fail(why);
  scene.slices().set_volume(std::move(volume));
  if (!o.cursor.empty()) scene.slices().set_cursor_mm(checked.cursor);
  scene.set_report(std::string("quality report (") + method_name(method) + ")", posed.report,
                   shown->compare ? &*shown->compare : nullptr, method_name(method),
                   o.compare.empty() ? "" : method_name(method_named(o.compare)));
  scene.set_layout(Scene::Layout::kSlices);
  shown->report = posed.report;
  return std::nullopt;
}

// The window: sliders, keys and a timer that polls the preview, until the user quits.
int run_window(App& ui, Scene& scene, Controller& controller) {
  auto interactor = vtkSmartPointer<vtkRenderWindowInteractor>::New();
  interactor->SetRenderWindow(scene.window());
  auto style = vtkSmartPointer<ViewerStyle>::New();
  style->app = &ui;
  interactor->SetInteractorStyle(style);
  interactor->Initialize();
  ui.interactor = interactor;
  vtkSmartPointer<vtkSliderWidget> sliders[3] = {make_slider(interactor, scene.renderer(), "flexion", 0.20),
                                                 make_slider(interactor, scene.renderer(), "abduction", 0.13),
                                                 make_slider(interactor, scene.renderer(), "rotation", 0.06)};
  for (int i = 0; i < 3; ++i) ui.sliders[i] = sliders[i];
  ui.layout(scene.layout());
  ui.controller = &controller;
  using Callback = void (*)(vtkObject*, unsigned long, void*, void*);
  const auto observe = [&](vtkObject* subject, unsigned long event, Callback callback) {
    auto command = vtkSmartPointer<vtkCallbackCommand>::New();
    command->SetCallback(callback);
    command->SetClientData(&ui);
    subject->AddObserver(event, command);
  };
  for (auto& s : sliders) observe(s, vtkCommand::InteractionEvent, on_slider);
  observe(interactor, vtkCommand::TimerEvent, on_timer);
  interactor->CreateRepeatingTimer(15);
  observe(interactor, vtkCommand::KeyPressEvent, on_key);
  ui.show_joint();
  scene.set_status("joint " + controller.joint() + " (n/p or a click on a sphere to change; --help lists the keys)");
  scene.render();
  interactor->Start();
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  if (std::optional<int> exit = parse_options(argc, argv, o)) return *exit;
  Checked checked;
  if (std::optional<int> failed = check_options(o, &checked)) return *failed;
  CallError error;
  std::unique_ptr<ViewerClient> client = ViewerClient::connect(o.address, &error);
  if (!client) return fail(error.message, 2);
  std::vector<v1::Rig> rigs;
  if (CallError e = client->list_rigs(&rigs); e.failed()) return fail(e.message, exit_code(e));
  if (o.list) return print_rigs(rigs);
  if (std::optional<int> failed = choose_rig(rigs, o)) return *failed;
  RigAssets assets;
  if (CallError e = client->assets(o.rig_id, &assets); e.failed()) return fail(e.message, exit_code(e));
  Pose start;
  std::string why;
  if (std::optional<Pose> pose = o.pose_path.empty() ? Pose{} : read_pose(o.pose_path, &why)) {
    start = *pose;
  } else {
    return fail(why, 2);
  }
  const v1::Method method = method_named(o.method);
  if (!o.save.empty()) {
    if (std::optional<int> failed = save_without_window(*client, o, start, method)) return *failed;
    if (o.snapshot.empty()) return 0;
  }

  const bool offscreen = !o.snapshot.empty();
  Scene scene(checked.width, checked.height, offscreen);
  scene.set_rig(assets, o.triangles);
  scene.show_tissue(o.tissue);
  scene.slices().set_window(o.window == "bone" ? kBone : kSoftTissue);
  scene.slices().set_label_opacity(o.label_opacity);
  auto session = std::make_unique<PreviewSession>(*client, o.rig_id);
  Controller controller(scene, *session);
  std::unique_ptr<PreviewSession> compare;
  controller.set_method(method);
  controller.set_pose(start);
  if (!o.compare.empty()) {
    compare = std::make_unique<PreviewSession>(*client, o.rig_id);
    controller.set_compare(compare.get(), method_named(o.compare));
    scene.set_layout(Scene::Layout::kCompare);
  }
  if (std::optional<int> failed = first_preview(*session, compare.get(), controller)) return *failed;
  ShownReports shown;
  if (o.slices) {
    if (std::optional<int> failed = show_slices(*client, o, checked, start, method, scene, &shown)) return *failed;
  }
  scene.set_view(o.view);
  if (offscreen) {
    scene.set_status("");
    scene.slices().update();
    if (!scene.snapshot(o.snapshot, &why)) return fail(why);
    std::fprintf(stderr, "wrote %s\n", o.snapshot.c_str());
    return 0;
  }

  App ui;
  if (scene.slices().has_volume()) {  // --slices: the window knows which pose its slices show
    ui.shown_pose = pose_json(start) + method_name(method);
    ui.shown_title = std::string("quality report (") + method_name(method) + ")";
    ui.shown_report = shown.report;
    ui.shown_method = method;
    ui.compare_report = shown.compare;
    ui.compare_report_method = o.compare.empty() ? "" : method_name(method_named(o.compare));
  }
  ui.options = o;
  ui.client = client.get();
  ui.scene = &scene;
  ui.session = std::move(session);
  ui.compare = std::move(compare);
  const std::string poses_dir = !o.poses_dir.empty()   ? o.poses_dir
                                : !o.pose_path.empty() ? fs::path(o.pose_path).parent_path().string()
                                                       : std::string(".");
  ui.options.poses_dir = poses_dir.empty() ? "." : poses_dir;
  ui.pose_files = pose_files_in(ui.options.poses_dir);
  return run_window(ui, scene, controller);
}
