// The posed volume as three orthogonal slices (axial, coronal, sagittal) of the CT with the labels over it, a
// cursor shared by the three, window/level presets and the label opacity; the quality report's key figures go in
// a text block the scene places.
#pragma once

#include <vtkSmartPointer.h>

#include <array>
#include <cstdint>
#include <string>
#include <vector>

#include "viewer_client.h"

class vtkRenderer;
class vtkRenderWindow;

namespace posewarp::view {

// A volume turned so that its index axes run along L, P and S (the nearest axes for an oblique grid): what the
// slices show, in the same LPS millimetres as the surfaces.
struct SliceVolume {
  std::array<int, 3> size{0, 0, 0};
  std::array<double, 3> spacing{1, 1, 1};
  std::array<double, 3> origin{0, 0, 0};  // the centre of voxel (0, 0, 0), LPS mm
  std::vector<float> ct;
  std::vector<int32_t> labels;
  bool oblique = false;  // the grid was not along the axes: shown on its nearest axes
  size_t voxels() const {
    return static_cast<size_t>(size[0]) * static_cast<size_t>(size[1]) * static_cast<size_t>(size[2]);
  }
};

// From the Pose call's raw samples (the header's sample types and grid); false with a message for an answer that
// does not hold what its header says.
bool slice_volume(const PosedVolumes& posed, SliceVolume* volume, std::string* error);

// The soft tissue around each joint the pose moved, at each radius, as the report's JSON gives it.
struct LocalFigures {
  std::string joint;
  double radius_mm = 0.0;
  double volume_change = 0.0, folded_fraction = 0.0;
  int64_t skin_vertices = 0, skin_inside = 0;  // skin passed into tissue or bone facing it
};
std::vector<LocalFigures> local_figures(const v1::QualityReport& report);

// The quality report's key figures, one per line: the whole body's, then for the first three moved joints the soft
// tissue's volume change and folded share within the smallest radius (50 mm).
std::vector<std::string> report_lines(const v1::QualityReport& report);
// Two methods' reports of one pose side by side, fixed-width: a header with the methods' names, then one row per
// figure with each method's value (inverted tets, volume change, then for the first `max_joints` moved joints the
// soft tissue's volume change and folded share within the smallest radius and its volume change within the
// largest). Joints only one report has are left out.
std::vector<std::string> compare_report_lines(const v1::QualityReport& a, const std::string& a_name,
                                              const v1::QualityReport& b, const std::string& b_name,
                                              size_t max_joints = 3);

// Window/level presets in Hounsfield units.
struct WindowLevel {
  const char* name;
  double level, width;
};
constexpr WindowLevel kSoftTissue{"soft tissue", 40.0, 400.0};
constexpr WindowLevel kBone{"bone", 400.0, 1800.0};

class SliceViews {
 public:
  // Three renderers in `window`, hidden until placed by set_viewports.
  explicit SliceViews(vtkRenderWindow* window);
  ~SliceViews();

  void set_volume(SliceVolume volume);
  bool has_volume() const { return volume_.voxels() > 0; }
  const SliceVolume& volume() const { return volume_; }
  // Viewports (xmin, ymin, xmax, ymax) for axial, coronal and sagittal; all zero hides them.
  void set_viewports(const std::array<std::array<double, 4>, 3>& viewports);
  // The cursor in LPS mm, moved onto the nearest voxel centre inside the volume.
  void set_cursor_mm(const std::array<double, 3>& point);
  std::array<double, 3> cursor_mm() const;
  // A click at display (x, y) in one of the slice renderers moves the cursor there; false if it was not one.
  bool click(vtkRenderer* renderer, int x, int y);
  // Moves the slice shown by `renderer` by `steps` voxels; false if it is not a slice renderer.
  bool step(vtkRenderer* renderer, int steps);
  void set_window(const WindowLevel& window);
  const WindowLevel& window() const { return window_; }
  void set_label_opacity(double opacity);
  double label_opacity() const { return opacity_; }
  vtkRenderer* renderer(int view) const;
  // Redraws the slices and cursors after a change (the window's Render() shows them).
  void update();

 private:
  // update's parts for view v (0 axial, 1 coronal, 2 sagittal).
  void paint_slice(int v);
  void place_cursor_lines(int v);
  void place_camera(int v);
  struct Parts;
  Parts* parts_;
  SliceVolume volume_;
  std::array<int, 3> cursor_{0, 0, 0};  // voxel index
  WindowLevel window_ = kSoftTissue;
  double opacity_ = 0.4;
};

}  // namespace posewarp::view
