// posewarp-view's scene (the rest surfaces, bones opaque and the skin translucent, the skeleton as joint spheres and
// bone sticks, an L/P/S orientation marker, a scale bar, camera presets) and the controller the sliders drive.
#pragma once

#include <vtkSmartPointer.h>

#include <chrono>
#include <memory>
#include <string>
#include <vector>

#include "slices.h"
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

  // The rest surfaces and skeleton. Rigs whose surfaces add up to more than `triangle_budget` triangles (0: no
  // limit) are drawn with fewer (each large surface its share), so a slider keeps up on a software renderer.
  void set_rig(const RigAssets& assets, int64_t triangle_budget = kTriangleBudget);
  static constexpr int64_t kTriangleBudget = 30000;
  // Posed surfaces and joints from a preview answer (vertices in the rest surfaces' order); `compare` draws them
  // in the side-by-side view instead.
  void apply(const PreviewSession::Answer& answer, bool compare = false);

  // The window's layout: the 3D view alone, two methods side by side, or the 3D view with the three slices.
  enum class Layout { kSingle, kCompare, kSlices };
  void set_layout(Layout layout);
  Layout layout() const { return layout_; }
  // Names the methods shown (the side-by-side view's two, or the 3D view's one).
  void set_method_names(const std::string& main, const std::string& compare);
  SliceViews& slices() { return *slices_; }
  // The quality report's key figures beside the slices, warnings highlighted; `title` says which pose it is. With
  // `compare` (the same pose with another method), the two methods' figures side by side, named `method` and
  // `compare_method`; the warnings stay `report`'s.
  void set_report(const std::string& title, const v1::QualityReport& report, const v1::QualityReport* compare = nullptr,
                  const std::string& method = "", const std::string& compare_method = "");
  // The text set_report shows (for tests and scripts).
  const std::string& report_text() const { return report_text_; }
  // The joint list down the left side, the chosen one marked (empty: hidden).
  void set_joint_list(const std::vector<std::string>& names, const std::string& chosen);
  // The joint whose sphere is under display (x, y) in the 3D view, or -1.
  int joint_at(int x, int y) const;
  // "anterior", "lateral" (from the patient's left) or "superior"; false for another name.
  bool set_view(const std::string& preset);
  void set_status(const std::string& text);
  void show_tissue(bool shown);
  // Shows the next tissue surface alone (after the last, none); its name, or "" when none is shown.
  std::string next_tissue();
  void render();
  // Renders and writes a PNG; false with a message when it cannot.
  bool snapshot(const std::string& png_path, std::string* error);

  vtkRenderWindow* window() const;
  vtkRenderer* renderer() const;
  int updates() const { return updates_; }
  // Triangles of the surfaces as drawn (fewer than the rig's over the budget).
  int64_t drawn_triangles() const;
  const std::vector<std::string>& joint_names() const { return joint_names_; }

 private:
  void set_skeleton(const v1::Skeleton& skeleton);
  void place_skeleton(const std::vector<std::array<double, 3>>& centres);
  struct Parts;
  Parts* parts_;
  std::unique_ptr<SliceViews> slices_;
  Layout layout_ = Layout::kSingle;
  std::string report_text_;
  std::vector<std::array<double, 3>> centres_;  // as drawn now
  std::vector<std::string> joint_names_;
  std::vector<std::array<double, 3>> rest_centres_;
  std::vector<std::pair<int, int>> sticks_;  // joint pairs joined by a bone stick
  double bounds_[6] = {0, 1, 0, 1, 0, 1};
  int updates_ = 0;
  int tissue_shown_ = -1;  // next_tissue's surface
};

// What the controls call: a joint (or the root) chosen, its three angles set, the method switched, resets and
// undo; each change goes out on the preview stream (and on the side-by-side view's, when shown) and poll() draws
// the newest answers.
class Controller {
 public:
  Controller(Scene& scene, PreviewSession& session);

  // Joints by index in the skeleton's order; select_root() chooses the root, whose three angles turn the whole
  // body about L-R, A-P and S-I.
  void select_joint(size_t index);
  void select_root();
  bool at_root() const { return at_root_; }
  // The chosen joint's name ("root" for the root).
  const std::string& joint() const { return joint_; }
  // The chosen joint's three angles (degrees): flexion, abduction, axial rotation; the root's about L-R, A-P, S-I.
  std::array<double, 3> chosen_angles() const;
  // axis 0 flexion, 1 abduction, 2 axial rotation; degrees in the joint's own frame (or the root's axes).
  void set_angle(int axis, double degrees);
  void set_method(v1::Method method);
  void set_pose(const Pose& pose);
  void reset_joint();
  void reset_all();
  void undo();
  const Pose& pose() const { return pose_; }
  v1::Method method() const { return method_; }
  uint64_t last_sent() const { return last_sent_; }

  // A stream to use from now on (after reconnecting); the current pose goes out on it.
  void set_session(PreviewSession& session);
  // A second stream posing the same angles with `method`, drawn side by side; nullptr ends the comparison.
  void set_compare(PreviewSession* session, v1::Method method);
  v1::Method compare_method() const { return compare_method_; }

  // Draws the newest answers if any came (true); the status line shows round trip and frame rate.
  bool poll();
  double last_round_trip_ms() const { return round_trip_ms_; }
  // Why the server refused the last answered update (OK when it was drawn).
  const CallError& last_error() const { return last_error_; }
  double frames_per_second() const { return static_cast<double>(drawn_.size()); }

 private:
  void send();
  void remember();  // the pose before a change, for undo
  Scene& scene_;
  PreviewSession* session_;
  PreviewSession* compare_ = nullptr;
  v1::Method compare_method_ = v1::METHOD_DQS;
  std::string joint_;
  bool at_root_ = false;
  Pose pose_;
  std::vector<Pose> history_;
  std::string last_control_;  // "joint/axis" of the last angle set, for coalescing a drag
  std::chrono::steady_clock::time_point last_change_;
  v1::Method method_ = v1::METHOD_COR;
  uint64_t last_sent_ = 0;
  double round_trip_ms_ = 0.0;
  CallError last_error_;
  std::vector<std::chrono::steady_clock::time_point> drawn_;  // the last second's frames, for frames per second
};

// "CoR", "DQS" or "LBS".
const char* method_name(v1::Method method);

}  // namespace posewarp::view
