// The slices of the posed volume: CT through a window, labels blended over it, a cursor shared by the three views.
#include "slices.h"

#include <vtkActor.h>
#include <vtkCamera.h>
#include <vtkImageActor.h>
#include <vtkImageData.h>
#include <vtkImageProperty.h>
#include <vtkLineSource.h>
#include <vtkPolyDataMapper.h>
#include <vtkProperty.h>
#include <vtkRenderWindow.h>
#include <vtkRenderer.h>
#include <vtkTextActor.h>
#include <vtkTextProperty.h>
#include <vtkUnsignedCharArray.h>

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <limits>

namespace posewarp::view {
namespace {

// Each view: the axis it cuts across, its two in-plane axes (screen right, screen up as seen) and its camera.
struct ViewAxes {
  const char* name;
  int normal, across, up;
  double direction[3];  // of projection
  double view_up[3];
  const char *left, *right, *top;
};
// Radiological convention: the patient's right on the screen's left; axial from the feet, anterior up; coronal
// from the front; sagittal from the patient's left, anterior on the left.
constexpr ViewAxes kViews[3] = {
    {"axial", 2, 0, 1, {0, 0, 1}, {0, -1, 0}, "R", "L", "A"},
    {"coronal", 1, 0, 2, {0, 1, 0}, {0, 0, 1}, "R", "L", "S"},
    {"sagittal", 0, 1, 2, {-1, 0, 0}, {0, 0, 1}, "A", "P", "S"},
};
// A view's axes as indices into the volume's arrays: the slice's normal, then across and up the screen.
struct AxisIndex {
  size_t normal, across, up;
};
AxisIndex axis_index(const ViewAxes& axes) {
  return {static_cast<size_t>(axes.normal), static_cast<size_t>(axes.across), static_cast<size_t>(axes.up)};
}

// The cursor line across each view is drawn in the colour of the view it marks (axial red, coronal green,
// sagittal yellow, as in 3D Slicer).
constexpr double kViewColours[3][3] = {{0.95, 0.33, 0.33}, {0.40, 0.85, 0.40}, {0.95, 0.85, 0.30}};

// A label's colour: hues spread by the golden ratio, so neighbouring label values differ.
std::array<unsigned char, 3> label_colour(int32_t label) {
  const double hue = std::fmod(static_cast<double>(label) * 0.618033988749895, 1.0) * 6.0;
  const double s = 0.85, v = 1.0, f = hue - std::floor(hue);
  const double p = v * (1 - s), q = v * (1 - s * f), t = v * (1 - s * (1 - f));
  double r = v, g = t, b = p;
  switch (static_cast<int>(hue)) {
    case 1: r = q, g = v, b = p; break;
    case 2: r = p, g = v, b = t; break;
    case 3: r = p, g = q, b = v; break;
    case 4: r = t, g = p, b = v; break;
    case 5: r = v, g = p, b = q; break;
    default: break;
  }
  return {static_cast<unsigned char>(255 * r), static_cast<unsigned char>(255 * g),
          static_cast<unsigned char>(255 * b)};
}

template <typename T>
double sample(const std::string& bytes, size_t i) {
  T value;
  std::memcpy(&value, bytes.data() + i * sizeof(T), sizeof(T));
  return static_cast<double>(value);
}

double read_sample(const std::string& bytes, v1::PixelType type, size_t i) {
  switch (type) {
    case v1::PIXEL_TYPE_UINT8: return sample<uint8_t>(bytes, i);
    case v1::PIXEL_TYPE_INT8: return sample<int8_t>(bytes, i);
    case v1::PIXEL_TYPE_UINT16: return sample<uint16_t>(bytes, i);
    case v1::PIXEL_TYPE_INT16: return sample<int16_t>(bytes, i);
    case v1::PIXEL_TYPE_UINT32: return sample<uint32_t>(bytes, i);
    case v1::PIXEL_TYPE_INT32: return sample<int32_t>(bytes, i);
    case v1::PIXEL_TYPE_FLOAT32: return sample<float>(bytes, i);
    default: return sample<double>(bytes, i);
  }
}

std::string figure(const char* format, double value) {
  char text[96];
  std::snprintf(text, sizeof text, format, value);
  return text;
}

std::string label_list(const google::protobuf::RepeatedField<int32_t>& labels) {
  if (labels.empty()) return "none";
  std::string text;
  for (int32_t l : labels) text += (text.empty() ? "" : ", ") + std::to_string(l);
  return text;
}

}  // namespace

bool slice_volume(const PosedVolumes& posed, SliceVolume* volume, std::string* error) {
  const v1::Grid& grid = posed.header.grid();
  if (grid.size_size() != 3 || grid.spacing_size() != 3 || grid.origin_size() != 3 || grid.direction_size() != 9) {
    *error = "the server's answer has no grid";
    return false;
  }
  const std::array<int64_t, 3> n{grid.size(0), grid.size(1), grid.size(2)};
  if (std::any_of(n.begin(), n.end(), [](int64_t s) { return s <= 0 || s > (1 << 20); })) {
    *error = "the server's answer has a grid of impossible size";
    return false;
  }
  const size_t voxels = static_cast<size_t>(n[0] * n[1] * n[2]);
  const v1::PixelType label_type = posed.header.label_sample_type(), ct_type = posed.header.ct_sample_type();
  const size_t label_bytes = client::sample_bytes(label_type), ct_bytes = client::sample_bytes(ct_type);
  if (label_bytes == 0 || ct_bytes == 0 || posed.labels.size() != voxels * label_bytes ||
      posed.ct.size() != voxels * ct_bytes) {
    *error = "the server's volumes do not match their header (sizes or sample types)";
    return false;
  }
  // Assign each world axis the index axis most along it (each index axis once), with its sign.
  std::array<int, 3> source_axis{-1, -1, -1};
  std::array<bool, 3> used{false, false, false};
  std::array<double, 3> sign{1, 1, 1};
  volume->oblique = false;
  for (int round = 0; round < 3; ++round) {
    int best_a = -1, best_c = -1;
    double best = -1;
    for (int a = 0; a < 3; ++a) {
      if (source_axis[static_cast<size_t>(a)] >= 0) continue;
      for (int c = 0; c < 3; ++c) {
        const double d = std::abs(grid.direction(3 * a + c));
        if (!used[static_cast<size_t>(c)] && d > best) best = d, best_a = a, best_c = c;
      }
    }
    source_axis[static_cast<size_t>(best_a)] = best_c;
    used[static_cast<size_t>(best_c)] = true;
    sign[static_cast<size_t>(best_a)] = grid.direction(3 * best_a + best_c) < 0 ? -1.0 : 1.0;
    if (best < 0.999) volume->oblique = true;
  }
  // The source index of the new voxel (0, 0, 0), and the world position of its centre.
  std::array<int64_t, 3> first{0, 0, 0};
  for (size_t a = 0; a < 3; ++a) {
    const auto c = static_cast<size_t>(source_axis[a]);
    volume->size[a] = static_cast<int>(n[c]);
    volume->spacing[a] = grid.spacing(static_cast<int>(c));
    if (sign[a] < 0) first[c] = n[c] - 1;
  }
  for (int a = 0; a < 3; ++a) {
    double p = grid.origin(a);
    for (int c = 0; c < 3; ++c)
      p += grid.direction(3 * a + c) * grid.spacing(c) * static_cast<double>(first[static_cast<size_t>(c)]);
    volume->origin[static_cast<size_t>(a)] = p;
  }
  // Source strides per new axis (negative where the axis runs backwards).
  const std::array<int64_t, 3> source_stride{1, n[0], n[0] * n[1]};
  std::array<int64_t, 3> stride{};
  int64_t start = 0;
  for (size_t a = 0; a < 3; ++a) {
    const auto c = static_cast<size_t>(source_axis[a]);
    stride[a] = sign[a] < 0 ? -source_stride[c] : source_stride[c];
    start += first[c] * source_stride[c];
  }
  volume->ct.resize(voxels);
  volume->labels.resize(voxels);
  size_t out = 0;
  for (int z = 0; z < volume->size[2]; ++z) {
    for (int y = 0; y < volume->size[1]; ++y) {
      int64_t at = start + z * stride[2] + y * stride[1];
      for (int x = 0; x < volume->size[0]; ++x, at += stride[0], ++out) {
        volume->ct[out] = static_cast<float>(read_sample(posed.ct, ct_type, static_cast<size_t>(at)));
        volume->labels[out] = static_cast<int32_t>(read_sample(posed.labels, label_type, static_cast<size_t>(at)));
      }
    }
  }
  return true;
}

std::vector<LocalFigures> local_figures(const v1::QualityReport& report) {
  std::vector<LocalFigures> figures;
  const nlohmann::json doc = nlohmann::json::parse(report.json(), nullptr, false);
  if (!doc.is_object() || !doc.contains("moved_joints") || !doc["moved_joints"].is_array()) return figures;
  for (const nlohmann::json& j : doc["moved_joints"]) {
    if (!j.is_object()) continue;
    LocalFigures f;
    f.joint = j.value("joint", std::string());
    f.radius_mm = j.value("radius_mm", 0.0);
    f.volume_change = j.value("volume_change", 0.0);
    f.folded_fraction = j.value("folded_fraction", 0.0);
    f.skin_vertices = j.value("skin_vertices", int64_t{0});
    f.skin_inside = j.value("skin_inside_tissue", int64_t{0}) + j.value("skin_inside_bone", int64_t{0});
    figures.push_back(f);
  }
  return figures;
}

std::vector<std::string> report_lines(const v1::QualityReport& report) {
  std::vector<std::string> lines{"inverted tets: " + std::to_string(report.inverted_tets()),
                                 figure("bone rigidity error: %.2f mm", report.bone_rigidity_error_mm()),
                                 figure("volume change: %+.2f %%", 100.0 * report.volume_change()),
                                 "new labels: " + label_list(report.new_labels()),
                                 "lost labels: " + label_list(report.lost_labels())};
  // The soft tissue within the smallest radius of the first moved joints, one short line each (the panel is a
  // quarter of the window; report.json has every radius).
  const std::vector<LocalFigures> local = local_figures(report);
  double inner = std::numeric_limits<double>::infinity();
  for (const LocalFigures& f : local) inner = std::min(inner, f.radius_mm);
  constexpr size_t kJoints = 3;
  size_t joints = 0;
  for (const LocalFigures& f : local) {
    if (f.radius_mm != inner) continue;
    if (++joints > kJoints) continue;
    char text[160];
    std::snprintf(text, sizeof text, "%s %.0f mm: %+.1f %% tissue, %.1f %% folded", f.joint.c_str(), f.radius_mm,
                  100.0 * f.volume_change, 100.0 * f.folded_fraction);
    lines.emplace_back(text);
  }
  if (joints > kJoints) lines.push_back("and " + std::to_string(joints - kJoints) + " more joints (d saves report.json)");
  return lines;
}

std::vector<std::string> compare_report_lines(const v1::QualityReport& a, const std::string& a_name,
                                              const v1::QualityReport& b, const std::string& b_name, size_t max_joints) {
  char text[160];
  auto row = [&](const std::string& name, const std::string& x, const std::string& y) {
    std::snprintf(text, sizeof text, "%-22.22s %9s %9s", name.c_str(), x.c_str(), y.c_str());
    return std::string(text);
  };
  auto percent = [](double value) { return figure("%+.1f %%", 100.0 * value); };
  std::vector<std::string> lines{row("", a_name, b_name),
                                 row("inverted tets", std::to_string(a.inverted_tets()), std::to_string(b.inverted_tets())),
                                 row("volume change", percent(a.volume_change()), percent(b.volume_change()))};
  const std::vector<LocalFigures> fa = local_figures(a), fb = local_figures(b);
  auto find = [](const std::vector<LocalFigures>& in, const std::string& joint, double radius) -> const LocalFigures* {
    for (const LocalFigures& f : in) {
      if (f.joint == joint && f.radius_mm == radius) return &f;
    }
    return nullptr;
  };
  // Per joint (in the report's order): the soft tissue's volume change and folded share within the smallest
  // radius, its volume change within the largest.
  std::vector<std::string> joints;
  double inner = std::numeric_limits<double>::infinity(), outer = 0.0;
  for (const LocalFigures& f : fa) {
    if (find(fb, f.joint, f.radius_mm) == nullptr) continue;
    if (std::find(joints.begin(), joints.end(), f.joint) == joints.end()) joints.push_back(f.joint);
    inner = std::min(inner, f.radius_mm), outer = std::max(outer, f.radius_mm);
  }
  for (size_t j = 0; j < joints.size() && j < max_joints; ++j) {
    const LocalFigures *x = find(fa, joints[j], inner), *y = find(fb, joints[j], inner);
    if (x && y) {
      lines.push_back(row(joints[j] + figure(" %.0f mm", inner), percent(x->volume_change), percent(y->volume_change)));
      lines.push_back(row("  folded", figure("%.1f %%", 100.0 * x->folded_fraction), figure("%.1f %%", 100.0 * y->folded_fraction)));
    }
    x = find(fa, joints[j], outer), y = find(fb, joints[j], outer);
    if (outer > inner && x && y) {
      lines.push_back(row(joints[j] + figure(" %.0f mm", outer), percent(x->volume_change), percent(y->volume_change)));
    }
  }
  if (joints.size() > max_joints) {
    lines.push_back("and " + std::to_string(joints.size() - max_joints) + " more joints (d saves report.json)");
  }
  return lines;
}

struct SliceViews::Parts {
  struct View {
    vtkSmartPointer<vtkRenderer> renderer = vtkSmartPointer<vtkRenderer>::New();
    vtkSmartPointer<vtkImageData> image = vtkSmartPointer<vtkImageData>::New();
    vtkSmartPointer<vtkImageActor> actor = vtkSmartPointer<vtkImageActor>::New();
    vtkSmartPointer<vtkLineSource> lines[2] = {vtkSmartPointer<vtkLineSource>::New(),
                                               vtkSmartPointer<vtkLineSource>::New()};
    vtkSmartPointer<vtkActor> line_actors[2] = {vtkSmartPointer<vtkActor>::New(), vtkSmartPointer<vtkActor>::New()};
    vtkSmartPointer<vtkTextActor> title = vtkSmartPointer<vtkTextActor>::New();
    vtkSmartPointer<vtkTextActor> sides[3] = {vtkSmartPointer<vtkTextActor>::New(),
                                              vtkSmartPointer<vtkTextActor>::New(),
                                              vtkSmartPointer<vtkTextActor>::New()};
    bool camera_placed = false;
  };
  vtkRenderWindow* window = nullptr;
  View views[3];
};

SliceViews::SliceViews(vtkRenderWindow* window) : parts_(new Parts) {
  parts_->window = window;
  for (int v = 0; v < 3; ++v) {
    Parts::View& view = parts_->views[v];
    view.renderer->SetBackground(0.0, 0.0, 0.0);
    view.renderer->SetViewport(0, 0, 0, 0);
    view.renderer->DrawOff();
    view.actor->InterpolateOff();
    view.actor->GetProperty()->SetInterpolationTypeToNearest();
    view.renderer->AddActor(view.actor);
    for (int l = 0; l < 2; ++l) {
      auto mapper = vtkSmartPointer<vtkPolyDataMapper>::New();
      mapper->SetInputConnection(view.lines[l]->GetOutputPort());
      view.line_actors[l]->SetMapper(mapper);
      view.line_actors[l]->GetProperty()->SetLineWidth(1.5);
      view.line_actors[l]->GetProperty()->LightingOff();
      view.renderer->AddActor(view.line_actors[l]);
    }
    view.title->GetTextProperty()->SetFontSize(13);
    view.title->GetTextProperty()->SetColor(kViewColours[v][0], kViewColours[v][1], kViewColours[v][2]);
    view.title->GetPositionCoordinate()->SetCoordinateSystemToNormalizedViewport();
    view.title->GetPositionCoordinate()->SetValue(0.02, 0.93);
    view.renderer->AddViewProp(view.title);
    const char* letters[3] = {kViews[v].left, kViews[v].right, kViews[v].top};
    const double at[3][2] = {{0.02, 0.48}, {0.95, 0.48}, {0.49, 0.93}};
    for (int s = 0; s < 3; ++s) {
      view.sides[s]->SetInput(letters[s]);
      view.sides[s]->GetTextProperty()->SetFontSize(14);
      view.sides[s]->GetTextProperty()->SetColor(0.85, 0.85, 0.85);
      view.sides[s]->GetPositionCoordinate()->SetCoordinateSystemToNormalizedViewport();
      view.sides[s]->GetPositionCoordinate()->SetValue(at[s][0], at[s][1]);
      view.renderer->AddViewProp(view.sides[s]);
    }
    view.renderer->GetActiveCamera()->ParallelProjectionOn();
    view.renderer->InteractiveOff();
    window->AddRenderer(view.renderer);
  }
}

SliceViews::~SliceViews() {
  delete parts_;
}

vtkRenderer* SliceViews::renderer(int view) const {
  return parts_->views[view].renderer;
}

void SliceViews::set_volume(SliceVolume volume) {
  volume_ = std::move(volume);
  for (Parts::View& view : parts_->views) view.camera_placed = false;
  set_cursor_mm({volume_.origin[0] + volume_.spacing[0] * (volume_.size[0] - 1) / 2.0,
                 volume_.origin[1] + volume_.spacing[1] * (volume_.size[1] - 1) / 2.0,
                 volume_.origin[2] + volume_.spacing[2] * (volume_.size[2] - 1) / 2.0});
}

void SliceViews::set_viewports(const std::array<std::array<double, 4>, 3>& viewports) {
  for (int v = 0; v < 3; ++v) {
    const std::array<double, 4>& p = viewports[static_cast<size_t>(v)];
    Parts::View& view = parts_->views[v];
    view.renderer->SetViewport(p[0], p[1], p[2], p[3]);
    view.renderer->SetDraw(p[2] > p[0] ? 1 : 0);
    view.camera_placed = false;
  }
  update();
}

void SliceViews::set_cursor_mm(const std::array<double, 3>& point) {
  for (size_t a = 0; a < 3; ++a) {
    const double index = std::round((point[a] - volume_.origin[a]) / volume_.spacing[a]);
    cursor_[a] =
        static_cast<int>(std::clamp(std::isfinite(index) ? index : 0.0, 0.0, std::max(0.0, volume_.size[a] - 1.0)));
  }
}

std::array<double, 3> SliceViews::cursor_mm() const {
  return {volume_.origin[0] + volume_.spacing[0] * cursor_[0], volume_.origin[1] + volume_.spacing[1] * cursor_[1],
          volume_.origin[2] + volume_.spacing[2] * cursor_[2]};
}

bool SliceViews::click(vtkRenderer* renderer, int x, int y) {
  for (const ViewAxes& axes : kViews) {
    const int v = static_cast<int>(&axes - kViews);
    if (renderer != parts_->views[v].renderer.Get()) continue;
    renderer->SetDisplayPoint(x, y, 0.0);
    renderer->DisplayToWorld();
    double world[4];
    renderer->GetWorldPoint(world);
    if (world[3] == 0.0) return true;
    std::array<double, 3> point = cursor_mm();
    point[static_cast<size_t>(axes.across)] = world[axes.across] / world[3];
    point[static_cast<size_t>(axes.up)] = world[axes.up] / world[3];
    set_cursor_mm(point);
    update();
    return true;
  }
  return false;
}

bool SliceViews::step(vtkRenderer* renderer, int steps) {
  for (int v = 0; v < 3; ++v) {
    if (renderer != parts_->views[v].renderer.Get()) continue;
    const auto axis = static_cast<size_t>(kViews[v].normal);
    cursor_[axis] = std::clamp(cursor_[axis] + steps, 0, std::max(0, volume_.size[axis] - 1));
    update();
    return true;
  }
  return false;
}

void SliceViews::set_window(const WindowLevel& window) {
  window_ = window;
  update();
}

void SliceViews::set_label_opacity(double opacity) {
  opacity_ = std::clamp(opacity, 0.0, 1.0);
  update();
}

void SliceViews::update() {
  if (!has_volume()) return;
  for (int v = 0; v < 3; ++v) {
    paint_slice(v);
    place_cursor_lines(v);
    Parts::View& view = parts_->views[v];
    const ViewAxes& axes = kViews[v];
    const auto normal = static_cast<size_t>(axes.normal);
    view.title->SetInput((std::string(axes.name) + "  " + std::to_string(cursor_[normal] + 1) + "/" +
                          std::to_string(volume_.size[normal]) +
                          (volume_.oblique ? "  (oblique grid, nearest axes)" : ""))
                             .c_str());
    if (!view.camera_placed) place_camera(v);
  }
}

// The slice of view v as an RGBA image lying in its plane, in LPS mm: the CT in the window, the labels over it.
void SliceViews::paint_slice(int v) {
  const SliceVolume& vol = volume_;
  const double low = window_.level - window_.width / 2.0;
  Parts::View& view = parts_->views[v];
  const ViewAxes& axes = kViews[v];
  const auto [normal, across, up] = axis_index(axes);
  int dims[3] = {vol.size[0], vol.size[1], vol.size[2]};
  dims[normal] = 1;
  double origin[3] = {vol.origin[0], vol.origin[1], vol.origin[2]};
  origin[normal] += vol.spacing[normal] * cursor_[normal];
  view.image->SetDimensions(dims);
  view.image->SetOrigin(origin);
  view.image->SetSpacing(vol.spacing[0], vol.spacing[1], vol.spacing[2]);
  view.image->AllocateScalars(VTK_UNSIGNED_CHAR, 4);
  auto* rgba = static_cast<unsigned char*>(view.image->GetScalarPointer());
  const size_t stride[3] = {1, static_cast<size_t>(vol.size[0]),
                            static_cast<size_t>(vol.size[0]) * static_cast<size_t>(vol.size[1])};
  const size_t base = static_cast<size_t>(cursor_[normal]) * stride[normal];
  // VTK's order in the slice image: x fastest, then y, then z, with the normal axis flat.
  const size_t inner = std::min(across, up), outer = std::max(across, up);
  size_t out = 0;
  for (int b = 0; b < vol.size[outer]; ++b) {
    for (int a = 0; a < vol.size[inner]; ++a, out += 4) {
      const size_t at = base + static_cast<size_t>(a) * stride[inner] + static_cast<size_t>(b) * stride[outer];
      const double grey = std::clamp((vol.ct[at] - low) / window_.width, 0.0, 1.0) * 255.0;
      double rgb[3] = {grey, grey, grey};
      if (const int32_t label = vol.labels[at]; label != 0 && opacity_ > 0.0) {
        const std::array<unsigned char, 3> c = label_colour(label);
        for (int k = 0; k < 3; ++k) rgb[k] = (1.0 - opacity_) * rgb[k] + opacity_ * c[static_cast<size_t>(k)];
      }
      for (int k = 0; k < 3; ++k) rgba[out + static_cast<size_t>(k)] = static_cast<unsigned char>(std::lround(rgb[k]));
      rgba[out + 3] = 255;
    }
  }
  view.image->Modified();
  view.actor->SetInputData(view.image);
  // Which slice of the input an image actor shows is its display extent (by default it takes z = 0).
  view.actor->SetDisplayExtent(view.image->GetExtent());
}

// The cursor in view v: a line along each in-plane axis through the cursor, a little towards the camera, in the
// colour of the view that cuts across it.
void SliceViews::place_cursor_lines(int v) {
  const SliceVolume& vol = volume_;
  Parts::View& view = parts_->views[v];
  const ViewAxes& axes = kViews[v];
  const auto [normal, across, up] = axis_index(axes);
  const std::array<double, 3> c = cursor_mm();
  const double lift = -0.5 * vol.spacing[normal];
  for (int l = 0; l < 2; ++l) {
    const size_t along = l == 0 ? across : up, marks = l == 0 ? up : across;
    double p1[3] = {c[0], c[1], c[2]}, p2[3] = {c[0], c[1], c[2]};
    p1[normal] += lift * axes.direction[normal], p2[normal] += lift * axes.direction[normal];
    p1[along] = vol.origin[along] - 0.5 * vol.spacing[along];
    p2[along] = vol.origin[along] + (vol.size[along] - 0.5) * vol.spacing[along];
    view.lines[l]->SetPoint1(p1);
    view.lines[l]->SetPoint2(p2);
    // A line along `along` at a fixed `marks` coordinate is where the view cutting across `marks` lies.
    const int marked_view = marks == 2 ? 0 : marks == 1 ? 1 : 2;
    view.line_actors[l]->GetProperty()->SetColor(kViewColours[marked_view][0], kViewColours[marked_view][1],
                                                 kViewColours[marked_view][2]);
  }
}

// View v's camera, once per volume: parallel, facing the slice, the whole slice in its viewport.
void SliceViews::place_camera(int v) {
  const SliceVolume& vol = volume_;
  Parts::View& view = parts_->views[v];
  const ViewAxes& axes = kViews[v];
  const auto [normal, across, up] = axis_index(axes);
  int* window_size = parts_->window->GetSize();
  double viewport[4];
  view.renderer->GetViewport(viewport);
  const double pixels_w = std::max(1.0, (viewport[2] - viewport[0]) * window_size[0]);
  const double pixels_h = std::max(1.0, (viewport[3] - viewport[1]) * window_size[1]);
  const double extent_w = vol.size[across] * vol.spacing[across], extent_h = vol.size[up] * vol.spacing[up];
  double centre[3];
  for (size_t a = 0; a < 3; ++a) centre[a] = vol.origin[a] + vol.spacing[a] * (vol.size[a] - 1) / 2.0;
  vtkCamera* camera = view.renderer->GetActiveCamera();
  const double distance = 4.0 * std::max(extent_w, extent_h) + 100.0;
  camera->SetFocalPoint(centre);
  camera->SetPosition(centre[0] - distance * axes.direction[0], centre[1] - distance * axes.direction[1],
                      centre[2] - distance * axes.direction[2]);
  camera->SetViewUp(axes.view_up[0], axes.view_up[1], axes.view_up[2]);
  camera->SetParallelScale(0.53 * std::max(extent_h, extent_w * pixels_h / pixels_w));
  camera->SetClippingRange(1.0, 2.0 * distance + 2.0 * vol.spacing[normal] * vol.size[normal]);
  view.camera_placed = true;
}

}  // namespace posewarp::view
