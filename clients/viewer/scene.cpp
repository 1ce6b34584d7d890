// The VTK scene: the rig's surfaces and skeleton, the HUD (report, joint list, status), views and snapshots.
#include "scene.h"

#include <vtkActor.h>
#include <vtkAnnotatedCubeActor.h>
#include <vtkAppendPolyData.h>
#include <vtkCallbackCommand.h>
#include <vtkCamera.h>
#include <vtkCellArray.h>
#include <vtkCellPicker.h>
#include <vtkDecimatePro.h>
#include <vtkLegendScaleActor.h>
#include <vtkLineSource.h>
#include <vtkPNGWriter.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkPolyDataMapper.h>
#include <vtkPolyDataNormals.h>
#include <vtkProperty.h>
#include <vtkRenderWindow.h>
#include <vtkRenderer.h>
#include <vtkSphereSource.h>
#include <vtkTextActor.h>
#include <vtkTextProperty.h>
#include <vtkWindowToImageFilter.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <map>
#include <sstream>

namespace posewarp::view {

// Distinct bone colours (Tableau's 10), the skin's and the other tissue's.
constexpr double kBoneColours[][3] = {{0.90, 0.86, 0.72}, {0.31, 0.47, 0.65}, {0.95, 0.56, 0.17}, {0.88, 0.34, 0.35},
                                      {0.46, 0.72, 0.70}, {0.35, 0.63, 0.31}, {0.93, 0.79, 0.28}, {0.69, 0.48, 0.63},
                                      {1.00, 0.62, 0.66}, {0.61, 0.46, 0.38}};
constexpr double kSkin[3] = {0.96, 0.78, 0.66};
constexpr double kTissue[3] = {0.80, 0.35, 0.35};

struct Scene::Parts {
  vtkSmartPointer<vtkRenderWindow> window = vtkSmartPointer<vtkRenderWindow>::New();
  vtkSmartPointer<vtkRenderer> renderer = vtkSmartPointer<vtkRenderer>::New();
  vtkSmartPointer<vtkRenderer> marker_renderer = vtkSmartPointer<vtkRenderer>::New();
  vtkSmartPointer<vtkTextActor> status = vtkSmartPointer<vtkTextActor>::New();
  vtkSmartPointer<vtkCallbackCommand> follow = vtkSmartPointer<vtkCallbackCommand>::New();
  std::pair<vtkRenderer*, vtkRenderer*> cameras;  // the main renderer and the marker's, for follow_camera
  std::vector<vtkSmartPointer<vtkPolyData>> surfaces;
  std::vector<vtkSmartPointer<vtkActor>> surface_actors;
  std::vector<std::string> roles;
  std::vector<std::string> surface_names;
  // A surface drawn with fewer triangles: the server's vertex index of each drawn point (empty: all drawn as sent),
  // and how many vertices the server sends for it.
  std::vector<std::vector<vtkIdType>> source_index;
  std::vector<vtkIdType> sent_vertices;
  vtkSmartPointer<vtkPolyData> skeleton = vtkSmartPointer<vtkPolyData>::New();
  vtkSmartPointer<vtkActor> skeleton_actor = vtkSmartPointer<vtkActor>::New();
  // The side-by-side view: the same surfaces posed by another method, seen by the same camera.
  vtkSmartPointer<vtkRenderer> compare_renderer = vtkSmartPointer<vtkRenderer>::New();
  std::vector<vtkSmartPointer<vtkPolyData>> compare_surfaces;
  std::vector<vtkSmartPointer<vtkActor>> compare_actors;
  vtkSmartPointer<vtkTextActor> method_names[2] = {vtkSmartPointer<vtkTextActor>::New(),
                                                   vtkSmartPointer<vtkTextActor>::New()};
  vtkSmartPointer<vtkTextActor> report = vtkSmartPointer<vtkTextActor>::New();
  vtkSmartPointer<vtkTextActor> warnings = vtkSmartPointer<vtkTextActor>::New();
  vtkSmartPointer<vtkTextActor> joint_list = vtkSmartPointer<vtkTextActor>::New();
  std::string view = "anterior";
  double sphere_radius = 1.0;
  std::vector<std::array<double, 3>> sphere_template;  // a joint sphere's points about its centre
  int width = 0, height = 0;
};

namespace {

// A text actor placed in its renderer's normalized viewport coordinates.
void place_text(vtkTextActor* text, double x, double y, int size, const double colour[3], bool right = false) {
  text->GetTextProperty()->SetFontSize(size);
  text->GetTextProperty()->SetColor(colour[0], colour[1], colour[2]);
  text->GetTextProperty()->SetJustification(right ? VTK_TEXT_RIGHT : VTK_TEXT_LEFT);
  text->GetTextProperty()->SetVerticalJustification(VTK_TEXT_TOP);
  text->GetPositionCoordinate()->SetCoordinateSystemToNormalizedViewport();
  text->GetPositionCoordinate()->SetValue(x, y);
}

// The marker's camera turns with the main one (same direction and up, fixed distance).
void follow_camera(vtkObject*, unsigned long, void* client, void*) {
  auto* pair = static_cast<std::pair<vtkRenderer*, vtkRenderer*>*>(client);
  vtkCamera* main = pair->first->GetActiveCamera();
  vtkCamera* marker = pair->second->GetActiveCamera();
  double direction[3];
  main->GetDirectionOfProjection(direction);
  marker->SetFocalPoint(0, 0, 0);
  marker->SetPosition(-4 * direction[0], -4 * direction[1], -4 * direction[2]);
  marker->SetViewUp(main->GetViewUp());
  pair->second->ResetCameraClippingRange();
}

}  // namespace

Scene::Scene(int width, int height, bool offscreen) : parts_(new Parts) {
  Parts& p = *parts_;
  p.window->SetSize(width, height);
  p.window->SetOffScreenRendering(offscreen ? 1 : 0);
  p.window->SetMultiSamples(0);  // the same pixels on every Mesa
  p.window->SetNumberOfLayers(2);
  p.window->SetWindowName("posewarp-view");
  p.renderer->SetBackground(0.10, 0.11, 0.13);
  p.window->AddRenderer(p.renderer);
  // The orientation marker in the lower left corner: L, P, S (LPS, the server's coordinates) on the cube's faces.
  auto cube = vtkSmartPointer<vtkAnnotatedCubeActor>::New();
  cube->SetXPlusFaceText("L");
  cube->SetXMinusFaceText("R");
  cube->SetYPlusFaceText("P");
  cube->SetYMinusFaceText("A");
  cube->SetZPlusFaceText("S");
  cube->SetZMinusFaceText("I");
  cube->SetFaceTextScale(0.6);
  cube->GetCubeProperty()->SetColor(0.35, 0.38, 0.45);
  p.marker_renderer->AddActor(cube);
  p.marker_renderer->SetViewport(0.0, 0.0, 0.16, 0.16 * width / std::max(1, height));
  p.marker_renderer->SetLayer(1);
  p.marker_renderer->InteractiveOff();
  p.window->AddRenderer(p.marker_renderer);
  p.cameras = {p.renderer.Get(), p.marker_renderer.Get()};
  p.follow->SetCallback(follow_camera);
  p.follow->SetClientData(&p.cameras);
  p.renderer->AddObserver(vtkCommand::StartEvent, p.follow);
  // A scale bar in millimetres along the bottom.
  auto scale = vtkSmartPointer<vtkLegendScaleActor>::New();
  scale->AllAxesOff();
  scale->BottomAxisVisibilityOn();  // ticks labelled in world units: millimetres
  scale->LegendVisibilityOff();
  scale->SetLabelModeToDistance();
  p.renderer->AddViewProp(scale);
  p.status->GetTextProperty()->SetFontSize(14);
  p.status->GetTextProperty()->SetColor(0.9, 0.9, 0.9);
  p.status->SetDisplayPosition(10, height - 24);
  p.renderer->AddViewProp(p.status);
  p.skeleton_actor->GetProperty()->SetColor(1.0, 0.85, 0.1);
  p.skeleton_actor->GetProperty()->SetLineWidth(3.0);
  p.width = width, p.height = height;
  p.compare_renderer->SetBackground(0.10, 0.11, 0.13);
  p.compare_renderer->SetActiveCamera(p.renderer->GetActiveCamera());
  p.compare_renderer->SetViewport(0, 0, 0, 0);
  p.compare_renderer->DrawOff();
  p.compare_renderer->InteractiveOff();
  p.window->AddRenderer(p.compare_renderer);
  const double white[3] = {0.9, 0.9, 0.9}, orange[3] = {1.0, 0.6, 0.2};
  for (int i = 0; i < 2; ++i) {
    place_text(p.method_names[i], 0.5, 0.90, 16, white);
    p.method_names[i]->GetTextProperty()->SetJustificationToCentered();
  }
  for (int i = 0; i < 2; ++i) p.method_names[i]->VisibilityOff();  // shown side by side only
  p.renderer->AddViewProp(p.method_names[0]);
  p.compare_renderer->AddViewProp(p.method_names[1]);
  place_text(p.report, 0.98, 0.97, 13, white, true);
  place_text(p.warnings, 0.98, 0.10, 12, orange, true);
  p.warnings->GetTextProperty()->SetVerticalJustificationToBottom();
  for (vtkTextActor* text : {p.report.Get(), p.warnings.Get()}) {
    text->GetTextProperty()->SetBackgroundColor(0.0, 0.0, 0.0);
    text->GetTextProperty()->SetBackgroundOpacity(0.55);
  }
  place_text(p.joint_list, 0.01, 0.88, 12, white);
  for (vtkTextActor* text : {p.report.Get(), p.warnings.Get(), p.joint_list.Get()}) p.renderer->AddViewProp(text);
  slices_ = std::make_unique<SliceViews>(p.window);
}

Scene::~Scene() {
  delete parts_;
}

vtkRenderWindow* Scene::window() const {
  return parts_->window;
}
vtkRenderer* Scene::renderer() const {
  return parts_->renderer;
}

namespace {

// A surface with about `keep` of its triangles for drawing (vtkDecimatePro collapses edges onto existing vertices,
// so every drawn point is one of the surface's own), and the index of each drawn point among the surface's.
vtkSmartPointer<vtkPolyData> fewer_triangles(vtkPolyData* mesh, double keep, std::vector<vtkIdType>* source_index) {
  auto decimate = vtkSmartPointer<vtkDecimatePro>::New();
  decimate->SetInputData(mesh);
  decimate->SetTargetReduction(1.0 - keep);
  decimate->PreserveTopologyOn();
  decimate->Update();
  vtkPolyData* fewer = decimate->GetOutput();
  std::map<std::array<float, 3>, vtkIdType> index;
  vtkPoints* all = mesh->GetPoints();
  for (vtkIdType i = 0; i < all->GetNumberOfPoints(); ++i) {
    double x[3];
    all->GetPoint(i, x);
    index.emplace(std::array<float, 3>{static_cast<float>(x[0]), static_cast<float>(x[1]), static_cast<float>(x[2])},
                  i);
  }
  source_index->clear();
  for (vtkIdType i = 0; i < fewer->GetNumberOfPoints(); ++i) {
    double x[3];
    fewer->GetPoint(i, x);
    const auto found = index.find({static_cast<float>(x[0]), static_cast<float>(x[1]), static_cast<float>(x[2])});
    if (found == index.end()) return nullptr;  // a point of its own: draw the surface whole
    source_index->push_back(found->second);
  }
  auto result = vtkSmartPointer<vtkPolyData>::New();
  result->DeepCopy(fewer);
  return result;
}

// A surface the server sent as VTK poly data (indices outside its vertices dropped), its bounds joined to lo/hi.
vtkSmartPointer<vtkPolyData> poly_data_of(const v1::Surface& s, double lo[3], double hi[3]) {
  auto points = vtkSmartPointer<vtkPoints>::New();
  for (int i = 0; i + 2 < s.vertices_size(); i += 3) {
    points->InsertNextPoint(s.vertices(i), s.vertices(i + 1), s.vertices(i + 2));
    for (int a = 0; a < 3; ++a) lo[a] = std::min(lo[a], s.vertices(i + a)), hi[a] = std::max(hi[a], s.vertices(i + a));
  }
  auto triangles = vtkSmartPointer<vtkCellArray>::New();
  const int vertices = s.vertices_size() / 3;
  for (int i = 0; i + 2 < s.triangles_size(); i += 3) {
    const vtkIdType ids[3] = {s.triangles(i), s.triangles(i + 1), s.triangles(i + 2)};
    if (std::any_of(ids, ids + 3, [&](vtkIdType id) { return id < 0 || id >= vertices; })) continue;  // not a triangle
    triangles->InsertNextCell(3, ids);
  }
  auto mesh = vtkSmartPointer<vtkPolyData>::New();
  mesh->SetPoints(points);
  mesh->SetPolys(triangles);
  return mesh;
}

// An actor drawing `mesh` with smooth normals.
vtkSmartPointer<vtkActor> actor_of(vtkPolyData* mesh) {
  auto normals = vtkSmartPointer<vtkPolyDataNormals>::New();
  normals->SetInputData(mesh);
  normals->SplittingOff();
  normals->ConsistencyOff();  // the server's surfaces are oriented already; checking them again costs most of a frame
  auto mapper = vtkSmartPointer<vtkPolyDataMapper>::New();
  mapper->SetInputConnection(normals->GetOutputPort());
  auto actor = vtkSmartPointer<vtkActor>::New();
  actor->SetMapper(mapper);
  return actor;
}

// How a surface of each role looks: bones opaque in turn of ten colours, the skin translucent, tissues hidden.
void dress(vtkActor* actor, const std::string& role, int* bone) {
  if (role == "skin") {
    actor->GetProperty()->SetColor(kSkin[0], kSkin[1], kSkin[2]);
    actor->GetProperty()->SetOpacity(0.25);
    // One translucent layer over opaque bones: its near side blended over them in the opaque pass, drawn after
    // everything else (set_rig), instead of VTK's order-independent transparency, which costs half a frame on a
    // software renderer.
    actor->GetProperty()->BackfaceCullingOn();
    actor->ForceOpaqueOn();
  } else if (role == "bone") {
    const double* c = kBoneColours[(*bone)++ % 10];
    actor->GetProperty()->SetColor(c[0], c[1], c[2]);
  } else {
    actor->GetProperty()->SetColor(kTissue[0], kTissue[1], kTissue[2]);
    actor->GetProperty()->SetOpacity(0.6);
    actor->VisibilityOff();  // tissue surfaces are toggled on (key t)
  }
}

}  // namespace

void Scene::set_rig(const RigAssets& assets, int64_t triangle_budget) {
  Parts& p = *parts_;
  int bone = 0;
  double lo[3] = {1e300, 1e300, 1e300}, hi[3] = {-1e300, -1e300, -1e300};
  int64_t triangles_sent = 0;
  for (const v1::Surface& s : assets.surfaces) triangles_sent += s.triangles_size() / 3;
  const double keep = triangle_budget > 0 && triangles_sent > triangle_budget
                          ? static_cast<double>(triangle_budget) / static_cast<double>(triangles_sent)
                          : 1.0;
  for (const v1::Surface& s : assets.surfaces) {
    vtkSmartPointer<vtkPolyData> mesh = poly_data_of(s, lo, hi);
    p.sent_vertices.push_back(mesh->GetNumberOfPoints());
    p.source_index.emplace_back();
    // Over the budget, each large surface is drawn with its share of the triangles (a preview: the posed files keep
    // every triangle).
    if (keep < 1.0 && mesh->GetNumberOfCells() > 2000) {
      if (vtkSmartPointer<vtkPolyData> fewer = fewer_triangles(mesh, keep, &p.source_index.back())) {
        mesh = fewer;
      } else {
        p.source_index.back().clear();
      }
    }
    vtkSmartPointer<vtkActor> actor = actor_of(mesh);
    const std::string role = s.role().empty() ? (s.label() == 0 ? "skin" : "bone") : s.role();
    dress(actor, role, &bone);
    if (role != "skin") p.renderer->AddActor(actor);
    p.surfaces.push_back(mesh);
    p.surface_actors.push_back(actor);
    p.roles.push_back(role);
    p.surface_names.push_back(s.name());
    // The compare view's twin: its own copy of the surface, drawn the same way.
    auto twin = vtkSmartPointer<vtkPolyData>::New();
    twin->DeepCopy(mesh);
    vtkSmartPointer<vtkActor> twin_actor = actor_of(twin);
    twin_actor->SetProperty(actor->GetProperty());
    twin_actor->SetVisibility(actor->GetVisibility());
    twin_actor->SetForceOpaque(actor->GetForceOpaque());
    if (role != "skin") p.compare_renderer->AddActor(twin_actor);
    p.compare_surfaces.push_back(twin);
    p.compare_actors.push_back(twin_actor);
  }
  for (int a = 0; a < 3; ++a) bounds_[2 * a] = lo[a], bounds_[2 * a + 1] = hi[a];
  set_skeleton(assets.skeleton);
  for (size_t i = 0; i < p.roles.size(); ++i) {
    if (p.roles[i] != "skin") continue;
    p.renderer->AddActor(p.surface_actors[i]);
    p.compare_renderer->AddActor(p.compare_actors[i]);
  }
  place_skeleton(rest_centres_);
  set_view("anterior");
}

// The skeleton: a sphere per joint and a stick from each joint to the next one down its chain.
void Scene::set_skeleton(const v1::Skeleton& skeleton) {
  Parts& p = *parts_;
  std::map<std::string, int> joint_with_child;
  for (int j = 0; j < skeleton.joints_size(); ++j) {
    const v1::Joint& joint = skeleton.joints(j);
    joint_names_.push_back(joint.name());
    rest_centres_.push_back(joint.centre_mm_size() == 3
                                ? std::array<double, 3>{joint.centre_mm(0), joint.centre_mm(1), joint.centre_mm(2)}
                                : std::array<double, 3>{0.0, 0.0, 0.0});
    joint_with_child[joint.child()] = j;
  }
  for (int j = 0; j < skeleton.joints_size(); ++j) {
    const auto up = joint_with_child.find(skeleton.joints(j).parent());
    if (up != joint_with_child.end()) sticks_.emplace_back(up->second, j);
  }
  auto mapper = vtkSmartPointer<vtkPolyDataMapper>::New();
  mapper->SetInputData(p.skeleton);
  p.skeleton_actor->SetMapper(mapper);
  p.renderer->AddActor(p.skeleton_actor);
}

void Scene::place_skeleton(const std::vector<std::array<double, 3>>& centres) {
  if (centres.empty()) return;
  Parts& p = *parts_;
  centres_ = centres;
  vtkPoints* points = p.skeleton->GetPoints();
  const vtkIdType sphere_points = static_cast<vtkIdType>(p.sphere_template.size());
  const vtkIdType expected =
      static_cast<vtkIdType>(centres.size()) * sphere_points + 2 * static_cast<vtkIdType>(sticks_.size());
  if (points != nullptr && sphere_points > 0 && points->GetNumberOfPoints() == expected) {
    // The same spheres and sticks moved: only the points change.
    vtkIdType at = 0;
    for (const std::array<double, 3>& c : centres) {
      for (const std::array<double, 3>& t : p.sphere_template)
        points->SetPoint(at++, c[0] + t[0], c[1] + t[1], c[2] + t[2]);
    }
    for (const auto& [a, b] : sticks_) {
      points->SetPoint(at++, centres[static_cast<size_t>(a)].data());
      points->SetPoint(at++, centres[static_cast<size_t>(b)].data());
    }
    points->Modified();
    p.skeleton->Modified();
    return;
  }
  const double diagonal = std::sqrt(std::pow(bounds_[1] - bounds_[0], 2) + std::pow(bounds_[3] - bounds_[2], 2) +
                                    std::pow(bounds_[5] - bounds_[4], 2));
  p.sphere_radius = 0.012 * diagonal;
  auto sphere = vtkSmartPointer<vtkSphereSource>::New();
  sphere->SetRadius(p.sphere_radius);
  sphere->SetThetaResolution(16);
  sphere->SetPhiResolution(12);
  sphere->Update();
  p.sphere_template.clear();
  for (vtkIdType i = 0; i < sphere->GetOutput()->GetNumberOfPoints(); ++i) {
    double x[3];
    sphere->GetOutput()->GetPoint(i, x);
    p.sphere_template.push_back({x[0], x[1], x[2]});
  }
  // Spheres first, then the sticks, in this order (the moves above rely on it).
  auto append = vtkSmartPointer<vtkAppendPolyData>::New();
  for (const std::array<double, 3>& c : centres) {
    auto placed = vtkSmartPointer<vtkSphereSource>::New();
    placed->SetCenter(c[0], c[1], c[2]);
    placed->SetRadius(p.sphere_radius);
    placed->SetThetaResolution(16);
    placed->SetPhiResolution(12);
    append->AddInputConnection(placed->GetOutputPort());
  }
  for (const auto& [a, b] : sticks_) {
    auto line = vtkSmartPointer<vtkLineSource>::New();
    line->SetPoint1(centres[static_cast<size_t>(a)].data());
    line->SetPoint2(centres[static_cast<size_t>(b)].data());
    append->AddInputConnection(line->GetOutputPort());
  }
  append->Update();
  p.skeleton->DeepCopy(append->GetOutput());
}

void Scene::apply(const PreviewSession::Answer& answer, bool compare) {
  Parts& p = *parts_;
  std::vector<vtkSmartPointer<vtkPolyData>>& surfaces = compare ? p.compare_surfaces : p.surfaces;
  for (size_t i = 0; i < answer.vertices.size() && i < surfaces.size(); ++i) {
    vtkPoints* points = surfaces[i]->GetPoints();
    const std::vector<float>& v = answer.vertices[i];
    if (static_cast<vtkIdType>(v.size() / 3) != p.sent_vertices[i]) continue;  // not this rig's surface
    const std::vector<vtkIdType>& from = p.source_index[i];
    // A surface that did not move keeps its normals (most of them, when one joint turns).
    bool moved = false;
    for (vtkIdType k = 0; k < points->GetNumberOfPoints(); ++k) {
      const size_t at = 3 * static_cast<size_t>(from.empty() ? k : from[static_cast<size_t>(k)]);
      double x[3];
      points->GetPoint(k, x);
      if (x[0] != v[at] || x[1] != v[at + 1] || x[2] != v[at + 2]) {
        points->SetPoint(k, v[at], v[at + 1], v[at + 2]);
        moved = true;
      }
    }
    if (!moved) continue;
    points->Modified();
    surfaces[i]->Modified();
  }
  if (!compare && answer.joint_centres.size() == rest_centres_.size()) place_skeleton(answer.joint_centres);
  ++updates_;
}

int64_t Scene::drawn_triangles() const {
  int64_t count = 0;
  for (const auto& surface : parts_->surfaces) count += surface->GetNumberOfPolys();
  return count;
}

void Scene::set_layout(Layout layout) {
  Parts& p = *parts_;
  layout_ = layout;
  const double aspect = static_cast<double>(p.width) / std::max(1, p.height);
  p.renderer->SetViewport(0, layout == Layout::kSlices ? 0.5 : 0.0, layout == Layout::kSingle ? 1.0 : 0.5, 1.0);
  p.compare_renderer->SetViewport(layout == Layout::kCompare ? 0.5 : 0.0, 0, layout == Layout::kCompare ? 1.0 : 0.0,
                                  layout == Layout::kCompare ? 1.0 : 0.0);
  p.compare_renderer->SetDraw(layout == Layout::kCompare ? 1 : 0);
  p.compare_renderer->SetInteractive(layout == Layout::kCompare ? 1 : 0);
  const double marker = layout == Layout::kSingle ? 0.16 : 0.10, bottom = layout == Layout::kSlices ? 0.5 : 0.0;
  p.marker_renderer->SetViewport(0.0, bottom, marker, bottom + marker * aspect);
  for (int i = 0; i < 2; ++i) p.method_names[i]->SetVisibility(layout == Layout::kCompare);
  p.report->SetVisibility(layout == Layout::kSlices);
  p.warnings->SetVisibility(layout == Layout::kSlices);
  if (layout == Layout::kSlices) {
    slices_->set_viewports({{{0.5, 0.5, 1.0, 1.0}, {0.0, 0.0, 0.5, 0.5}, {0.5, 0.0, 1.0, 0.5}}});
  } else {
    slices_->set_viewports({});
  }
  set_view(p.view);
}

void Scene::set_method_names(const std::string& main, const std::string& compare) {
  parts_->method_names[0]->SetInput(main.c_str());
  parts_->method_names[1]->SetInput(compare.c_str());
}

void Scene::set_report(const std::string& title, const v1::QualityReport& report, const v1::QualityReport* compare,
                       const std::string& method, const std::string& compare_method) {
  std::string text = title;
  const std::vector<std::string> lines =
      compare ? compare_report_lines(report, method, *compare, compare_method) : report_lines(report);
  for (const std::string& line : lines) text += "\n" + line;
  report_text_ = text;
  // A table of two methods lines up in a fixed-width font.
  if (compare) {
    parts_->report->GetTextProperty()->SetFontFamilyToCourier();
  } else {
    parts_->report->GetTextProperty()->SetFontFamilyToArial();
  }
  parts_->report->SetInput(text.c_str());
  // The first warnings, wrapped to the 3D view's width (about 7 pixels a character at this size); the report
  // file has them all.
  const size_t columns = static_cast<size_t>(std::max(30, parts_->width / 2 / 7 - 4));
  const int kShown = compare ? 1 : 3;  // a table of two methods takes the room of the others
  std::string warnings;
  for (int i = 0; i < std::min(kShown, report.warnings_size()); ++i) {
    const std::string& w = report.warnings(i);
    size_t width = 0;
    warnings.append("warning:");
    width = 8;
    std::istringstream words(w);
    for (std::string word; words >> word;) {
      if (width + 1 + word.size() > columns) {
        warnings.append("\n  ");
        width = 2;
      }
      warnings.append(" ").append(word);
      width += 1 + word.size();
    }
    warnings.append("\n");
  }
  if (report.warnings_size() > kShown) {
    warnings.append("and ")
        .append(std::to_string(report.warnings_size() - kShown))
        .append(" more warnings (d saves report.json)\n");
  }
  if (!warnings.empty()) warnings.pop_back();
  parts_->warnings->SetInput(warnings.c_str());
}

void Scene::set_joint_list(const std::vector<std::string>& names, const std::string& chosen) {
  // At most 24 lines, around the chosen joint.
  const auto at = std::find(names.begin(), names.end(), chosen);
  const size_t index = at == names.end() ? 0 : static_cast<size_t>(at - names.begin());
  const size_t first = names.size() <= 24 ? 0 : std::min(names.size() - 24, index > 12 ? index - 12 : 0);
  std::string text;
  for (size_t i = first; i < names.size() && i < first + 24; ++i) {
    text += (i == index ? "> " : "   ") + names[i] + "\n";
  }
  parts_->joint_list->SetInput(text.c_str());
}

int Scene::joint_at(int x, int y) const {
  if (centres_.empty()) return -1;
  auto picker = vtkSmartPointer<vtkCellPicker>::New();
  picker->SetTolerance(0.005);
  picker->PickFromListOn();
  picker->AddPickList(parts_->skeleton_actor);
  if (picker->Pick(x, y, 0.0, parts_->renderer) == 0) return -1;
  double picked[3];
  picker->GetPickPosition(picked);
  int nearest = -1;
  double best = 2.0 * parts_->sphere_radius;
  for (size_t j = 0; j < centres_.size(); ++j) {
    const double d = std::hypot(picked[0] - centres_[j][0], picked[1] - centres_[j][1], picked[2] - centres_[j][2]);
    if (d < best) best = d, nearest = static_cast<int>(j);
  }
  return nearest;
}

bool Scene::set_view(const std::string& preset) {
  double direction[3], up[3] = {0, 0, 1};
  if (preset == "anterior") {
    direction[0] = 0, direction[1] = -1, direction[2] = 0;  // the camera in front of the patient (anterior is -y)
  } else if (preset == "lateral") {
    direction[0] = 1, direction[1] = 0, direction[2] = 0;  // from the patient's left
  } else if (preset == "superior") {
    direction[0] = 0, direction[1] = 0, direction[2] = 1;  // from above the head, anterior up
    up[0] = 0, up[1] = -1, up[2] = 0;
  } else {
    return false;
  }
  parts_->view = preset;
  const double centre[3] = {(bounds_[0] + bounds_[1]) / 2, (bounds_[2] + bounds_[3]) / 2,
                            (bounds_[4] + bounds_[5]) / 2};
  vtkCamera* camera = parts_->renderer->GetActiveCamera();
  camera->SetFocalPoint(centre);
  camera->SetPosition(centre[0] + direction[0], centre[1] + direction[1], centre[2] + direction[2]);
  camera->SetViewUp(up);
  parts_->renderer->ResetCamera(bounds_);
  return true;
}

void Scene::set_status(const std::string& text) {
  parts_->status->SetInput(text.c_str());
}

void Scene::show_tissue(bool shown) {
  for (size_t i = 0; i < parts_->roles.size(); ++i) {
    if (parts_->roles[i] != "tissue") continue;
    parts_->surface_actors[i]->SetVisibility(shown);
    parts_->compare_actors[i]->SetVisibility(shown);
  }
}

std::string Scene::next_tissue() {
  Parts& p = *parts_;
  std::vector<int> tissue;
  for (size_t i = 0; i < p.roles.size(); ++i) {
    if (p.roles[i] == "tissue") tissue.push_back(static_cast<int>(i));
  }
  const auto at = std::find(tissue.begin(), tissue.end(), tissue_shown_);
  tissue_shown_ =
      at == tissue.end() ? (tissue.empty() ? -1 : tissue.front()) : (at + 1 == tissue.end() ? -1 : *(at + 1));
  for (int i : tissue) {
    p.surface_actors[static_cast<size_t>(i)]->SetVisibility(i == tissue_shown_);
    p.compare_actors[static_cast<size_t>(i)]->SetVisibility(i == tissue_shown_);
  }
  return tissue_shown_ < 0 ? "" : p.surface_names[static_cast<size_t>(tissue_shown_)];
}

void Scene::render() {
  parts_->window->Render();
}

bool Scene::snapshot(const std::string& png_path, std::string* error) {
  render();
  auto grab = vtkSmartPointer<vtkWindowToImageFilter>::New();
  grab->SetInput(parts_->window);
  grab->SetInputBufferTypeToRGB();
  grab->ReadFrontBufferOff();
  grab->Update();
  auto writer = vtkSmartPointer<vtkPNGWriter>::New();
  const std::string partial = png_path + ".partial";
  writer->SetFileName(partial.c_str());
  writer->SetInputConnection(grab->GetOutputPort());
  writer->Write();
  std::error_code ec;
  if (writer->GetErrorCode() != 0 || !std::filesystem::exists(partial, ec) ||
      std::filesystem::file_size(partial, ec) == 0) {
    std::filesystem::remove(partial, ec);
    *error = "cannot write the snapshot '" + png_path + "' (is its directory there and writable?)";
    return false;
  }
  std::filesystem::rename(partial, png_path, ec);
  if (ec) *error = "cannot write the snapshot '" + png_path + "': " + ec.message();
  return !ec;
}

}  // namespace posewarp::view
