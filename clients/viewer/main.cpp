// posewarp-view: previews poses of a rig held by posewarp-server, live (sliders) or as offscreen snapshots.
#include <CLI/CLI.hpp>
#include <vtkCallbackCommand.h>
#include <vtkCommand.h>
#include <vtkInteractorStyleTrackballCamera.h>
#include <vtkRenderWindow.h>
#include <vtkRenderWindowInteractor.h>
#include <vtkSliderRepresentation2D.h>
#include <vtkSliderWidget.h>
#include <vtkTextProperty.h>

#include <cstdio>
#include <fstream>
#include <sstream>

#include "scene.h"

namespace {

using namespace posewarp::view;
namespace v1 = posewarp::v1;

int fail(const std::string& message, int code = 1) {
  std::fprintf(stderr, "error: %s\n", message.c_str());
  return code;
}

// gRPC's code -> the CLI's exit codes: 2 for what the user can fix (bad input, unknown rig), 1 otherwise.
int exit_code(const CallError& e) {
  switch (e.code) {
    case grpc::StatusCode::INVALID_ARGUMENT:
    case grpc::StatusCode::NOT_FOUND:
    case grpc::StatusCode::UNAUTHENTICATED:
    case grpc::StatusCode::PERMISSION_DENIED: return 2;
    default: return 1;
  }
}

v1::Method method_named(const std::string& name) {
  return name == "dqs" ? v1::METHOD_DQS : name == "lbs" ? v1::METHOD_LBS : v1::METHOD_COR;
}

struct Options {
  ServerAddress address;
  std::string rig_id, pose_path, method = "cor", view = "anterior", snapshot, size = "1024x768";
  bool list = false, tissue = false;
};

// The interactive window: three sliders for the chosen joint, keys for the rest, answers drawn on a timer.
struct Interactive {
  Scene* scene;
  Controller* controller;
  vtkSliderWidget* sliders[3];
  bool tissue = false;
  void show_joint() {
    const JointAngles a = controller->angles().count(controller->joint()) ? controller->angles().at(controller->joint())
                                                                          : JointAngles{};
    const double values[3] = {a.flexion, a.abduction, a.rotation};
    for (int i = 0; i < 3; ++i) static_cast<vtkSliderRepresentation2D*>(sliders[i]->GetRepresentation())->SetValue(values[i]);
  }
};

void on_slider(vtkObject* caller, unsigned long, void* client, void*) {
  auto* ui = static_cast<Interactive*>(client);
  for (int i = 0; i < 3; ++i) {
    if (caller == ui->sliders[i]) {
      const double value = static_cast<vtkSliderRepresentation2D*>(ui->sliders[i]->GetRepresentation())->GetValue();
      ui->controller->set_angle(i, std::round(value));
    }
  }
}

void on_timer(vtkObject* caller, unsigned long, void* client, void*) {
  auto* ui = static_cast<Interactive*>(client);
  if (ui->controller->poll()) static_cast<vtkRenderWindowInteractor*>(caller)->Render();
}

void on_key(vtkObject* caller, unsigned long, void* client, void*) {
  auto* ui = static_cast<Interactive*>(client);
  auto* interactor = static_cast<vtkRenderWindowInteractor*>(caller);
  const std::string key = interactor->GetKeySym() ? interactor->GetKeySym() : "";
  const std::vector<std::string>& joints = ui->scene->joint_names();
  size_t at = std::find(joints.begin(), joints.end(), ui->controller->joint()) - joints.begin();
  if (key == "n" || key == "p") {
    if (!joints.empty()) ui->controller->select_joint(key == "n" ? (at + 1) % joints.size() : (at + joints.size() - 1) % joints.size());
    ui->show_joint();
  } else if (key == "1") {
    ui->controller->set_method(v1::METHOD_COR);
  } else if (key == "2") {
    ui->controller->set_method(v1::METHOD_DQS);
  } else if (key == "3") {
    ui->controller->set_method(v1::METHOD_LBS);
  } else if (key == "r") {
    ui->controller->reset_joint();
    ui->show_joint();
  } else if (key == "R") {
    ui->controller->reset_all();
    ui->show_joint();
  } else if (key == "u") {
    ui->controller->undo();
    ui->show_joint();
  } else if (key == "a" || key == "l" || key == "s") {
    ui->scene->set_view(key == "a" ? "anterior" : key == "l" ? "lateral" : "superior");
  } else if (key == "t") {
    ui->tissue = !ui->tissue;
    ui->scene->show_tissue(ui->tissue);
  } else if (key == "w") {
    const std::string path = "pose_" + std::to_string(std::time(nullptr)) + ".json";
    std::ofstream(path) << pose_json(ui->controller->angles()) << "\n";
    ui->scene->set_status("saved the pose to " + path);
  }
  interactor->Render();
}

vtkSmartPointer<vtkSliderWidget> make_slider(vtkRenderWindowInteractor* interactor, const char* title, double y) {
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
  rep->GetTitleProperty()->SetFontSize(12);
  auto widget = vtkSmartPointer<vtkSliderWidget>::New();
  widget->SetInteractor(interactor);
  widget->SetRepresentation(rep);
  widget->SetAnimationModeToJump();
  widget->EnabledOn();
  return widget;
}

}  // namespace

int main(int argc, char** argv) {
  Options o;
  CLI::App app{"posewarp-view: preview poses of a rig held by posewarp-server. Interactive: n/p choose the joint, the "
               "sliders set its flexion, abduction and axial rotation (degrees, the joint's own frame), 1/2/3 CoR/DQS/"
               "LBS, r/R reset the joint/all, u undo, a/l/s anterior/lateral/superior view, t tissue surfaces, w save "
               "the pose JSON. With --snapshot it renders once offscreen and exits (use xvfb-run without a display)."};
  app.add_option("--server", o.address.server, "posewarp-server at HOST:PORT")->required();
  app.add_option("--token-file", o.address.token_file, "File holding the server's bearer token");
  app.add_option("--tls-ca", o.address.tls_ca, "CA certificate (PEM) of a TLS server");
  app.add_flag("--list", o.list, "List the server's rigs (id, name, size, created) and exit");
  app.add_option("--rig", o.rig_id, "Rig id to open (default: the only rig, if the server holds one)");
  app.add_option("--pose", o.pose_path, "Pose JSON to start from (the CLI's angles_deg form)");
  app.add_option("--method", o.method, "Skinning: cor, dqs or lbs")->check(CLI::IsMember({"cor", "dqs", "lbs"}))->capture_default_str();
  app.add_option("--view", o.view, "Camera: anterior, lateral or superior")
      ->check(CLI::IsMember({"anterior", "lateral", "superior"}))
      ->capture_default_str();
  app.add_flag("--tissue", o.tissue, "Show the tissue surfaces too");
  app.add_option("--snapshot", o.snapshot, "Render offscreen to this PNG and exit");
  app.add_option("--size", o.size, "Window or snapshot size WxH")->capture_default_str();
  CLI11_PARSE(app, argc, argv);

  int width = 0, height = 0;
  if (std::sscanf(o.size.c_str(), "%dx%d", &width, &height) != 2 || width < 64 || height < 64 || width > 8192 ||
      height > 8192) {
    return fail("--size takes WxH between 64x64 and 8192x8192, not '" + o.size + "'", 2);
  }
  CallError error;
  std::unique_ptr<ViewerClient> client = ViewerClient::connect(o.address, &error);
  if (!client) return fail(error.message, 2);
  std::vector<v1::Rig> rigs;
  if (CallError e = client->list_rigs(&rigs); e.failed()) return fail(e.message, exit_code(e));
  if (o.list) {
    for (const v1::Rig& rig : rigs) {
      std::printf("%s  %-24s %10.1f MB  %s\n", rig.id().c_str(), rig.name().c_str(), static_cast<double>(rig.size_bytes()) / 1e6,
                  rig.created().c_str());
    }
    return 0;
  }
  if (o.rig_id.empty()) {
    if (rigs.size() != 1) {
      return fail("the server holds " + std::to_string(rigs.size()) + " rigs; choose one with --rig ID (--list lists them)", 2);
    }
    o.rig_id = rigs.front().id();
  }
  RigAssets assets;
  if (CallError e = client->assets(o.rig_id, &assets); e.failed()) return fail(e.message, exit_code(e));
  PoseAngles start;
  if (!o.pose_path.empty()) {
    std::ifstream in(o.pose_path);
    std::ostringstream text;
    text << in.rdbuf();
    std::string why;
    std::optional<PoseAngles> angles = in ? angles_from_json(text.str(), &why) : std::nullopt;
    if (!angles) return fail("pose file '" + o.pose_path + "': " + (in ? why : "cannot be read"), 2);
    start = *angles;
  }

  const bool offscreen = !o.snapshot.empty();
  Scene scene(width, height, offscreen);
  scene.set_rig(assets);
  scene.show_tissue(o.tissue);
  scene.set_view(o.view);
  PreviewSession session(*client, o.rig_id);
  Controller controller(scene, session);
  if (!start.empty() || o.method != "cor") {
    controller.set_method(method_named(o.method));
    controller.set_pose(start);
    if (!session.wait_for(controller.last_sent(), 30000)) {
      const CallError e = session.ended();
      return fail(e.failed() ? e.message : "the server did not answer the preview within 30 s", e.failed() ? exit_code(e) : 1);
    }
    controller.poll();
  }
  if (offscreen) {
    scene.set_status("");
    std::string why;
    if (!scene.snapshot(o.snapshot, &why)) return fail(why);
    std::fprintf(stderr, "wrote %s\n", o.snapshot.c_str());
    return 0;
  }

  auto interactor = vtkSmartPointer<vtkRenderWindowInteractor>::New();
  interactor->SetRenderWindow(scene.window());
  interactor->SetInteractorStyle(vtkSmartPointer<vtkInteractorStyleTrackballCamera>::New());
  interactor->Initialize();
  vtkSmartPointer<vtkSliderWidget> sliders[3] = {make_slider(interactor, "flexion", 0.20),
                                                 make_slider(interactor, "abduction", 0.13),
                                                 make_slider(interactor, "rotation", 0.06)};
  Interactive ui{&scene, &controller, {sliders[0], sliders[1], sliders[2]}, o.tissue};
  auto slid = vtkSmartPointer<vtkCallbackCommand>::New();
  slid->SetCallback(on_slider);
  slid->SetClientData(&ui);
  for (auto& s : sliders) s->AddObserver(vtkCommand::InteractionEvent, slid);
  auto timer = vtkSmartPointer<vtkCallbackCommand>::New();
  timer->SetCallback(on_timer);
  timer->SetClientData(&ui);
  interactor->AddObserver(vtkCommand::TimerEvent, timer);
  interactor->CreateRepeatingTimer(15);
  auto keys = vtkSmartPointer<vtkCallbackCommand>::New();
  keys->SetCallback(on_key);
  keys->SetClientData(&ui);
  interactor->AddObserver(vtkCommand::KeyPressEvent, keys);
  ui.show_joint();
  scene.set_status("joint " + controller.joint() + " (n/p to change)");
  scene.render();
  interactor->Start();
  return 0;
}
