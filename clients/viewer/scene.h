// posewarp-view's scene (the rest surfaces, bones opaque and the skin translucent, the skeleton as joint spheres and
// bone sticks, an L/P/S orientation marker, a scale bar, camera presets) and the controller the sliders drive.
#pragma once

#include <vtkSmartPointer.h>

#include <chrono>
#include <string>
#include <vector>

#include "viewer_client.h"

class vtkActor;
class vtkPolyData;
class vtkRenderer;
class vtkRenderWindow;
class vtkTextActor;

namespace posewarp::view {

class Scene {
 public:
  // offscreen: render without showing a window (snapshots; under Xvfb on a machine without a display).
  Scene(int width, int height, bool offscreen);
  ~Scene();

  void set_rig(const RigAssets& assets);
  // Posed surfaces and joints from a preview answer (vertices in the rest surfaces' order).
  void apply(const PreviewSession::Answer& answer);
  // "anterior", "lateral" (from the patient's left) or "superior"; false for another name.
  bool set_view(const std::string& preset);
  void set_status(const std::string& text);
  void show_tissue(bool shown);
  void render();
  // Renders and writes a PNG; false with a message when it cannot.
  bool snapshot(const std::string& png_path, std::string* error);

  vtkRenderWindow* window() const;
  vtkRenderer* renderer() const;
  int updates() const { return updates_; }
  const std::vector<std::string>& joint_names() const { return joint_names_; }

 private:
  void place_skeleton(const std::vector<std::array<double, 3>>& centres);
  struct Parts;
  Parts* parts_;
  std::vector<std::string> joint_names_;
  std::vector<std::array<double, 3>> rest_centres_;
  std::vector<std::pair<int, int>> sticks_;  // joint pairs joined by a bone stick
  double bounds_[6] = {0, 1, 0, 1, 0, 1};
  int updates_ = 0;
};

// What the controls call: a joint chosen, its three angles set, the method switched, resets and undo; each change
// goes out on the preview stream and poll() draws the newest answer.
class Controller {
 public:
  Controller(Scene& scene, PreviewSession& session);

  // Joints by index in the skeleton's order.
  void select_joint(size_t index);
  const std::string& joint() const { return joint_; }
  // axis 0 flexion, 1 abduction, 2 axial rotation; degrees in the joint's own frame.
  void set_angle(int axis, double degrees);
  void set_method(v1::Method method);
  void set_pose(const PoseAngles& angles);
  void reset_joint();
  void reset_all();
  void undo();
  const PoseAngles& angles() const { return angles_; }
  v1::Method method() const { return method_; }
  uint64_t last_sent() const { return last_sent_; }

  // Draws the newest answer if one came (true); the status line shows round trip and frame rate.
  bool poll();
  double last_round_trip_ms() const { return round_trip_ms_; }

 private:
  void send();
  Scene& scene_;
  PreviewSession& session_;
  std::string joint_;
  PoseAngles angles_;
  std::vector<PoseAngles> history_;
  v1::Method method_ = v1::METHOD_COR;
  uint64_t last_sent_ = 0;
  double round_trip_ms_ = 0.0;
  std::vector<std::chrono::steady_clock::time_point> drawn_;  // the last frames' times, for frames per second
};

}  // namespace posewarp::view
