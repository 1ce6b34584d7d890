// Pose commands: pose (one pose of a rig, written as volumes, surfaces, fields and a report) and animate (a BVH
// range, frame by frame).
#include <chrono>
#include <filesystem>
#include <fstream>
#include <future>
#include <iomanip>
#include <iostream>
#include <optional>
#include <sstream>

#include <nlohmann/json.hpp>

#include "cli_support.h"
#include "dicom_format_options.h"
#include "posewarp/api/dicom.h"
#include "posewarp/api/files.h"
#include "posewarp/api/pose_engine.h"
#include "posewarp/api/rig_file.h"
#include "remote.h"

namespace posewarp::cli {
namespace {

namespace fs = std::filesystem;

struct OutputOptions {
  std::string surface_format = "vtp";
  std::vector<std::string> extra_surfaces;
  std::string method = "cor";
  std::string grid = "input";
  std::string grid_like;
  bool nearest_ct = false;
  int64_t max_output_mb = 0;  // 0 = half the machine's memory
  api::FemOptions fem;        // 0: the engine's defaults
};

struct PoseOptions {
  std::string rig_path;
  std::string pose_path;
  std::string labels_out;
  std::string ct_out;
  std::string surfaces_out;
  std::string field_out;
  std::string report_out;
  // DICOM out: the posed CT as a derived series and the labels as a SEG of the source series' study.
  std::string dicom_out, dicom_source, uid_root = "2.25", series_description;
  DicomFormatOptions dicom_formats;
  Connection connection;  // pose on posewarp-server; rig_path is then a rig id
  OutputOptions output;
};

std::string fixed(double value, int digits) {
  std::ostringstream out;
  out << std::fixed << std::setprecision(digits) << value;
  return out.str();
}

Result<api::PoseRequest> make_request(const OutputOptions& o) {
  api::PoseRequest request;
  POSEWARP_ASSIGN_OR_RETURN(request.method, api::method_from_name(o.method));
  request.fem = o.fem;
  request.ct_interpolation = o.nearest_ct ? api::Interpolation::kNearest : api::Interpolation::kLinear;
  if (!o.grid_like.empty()) {
    POSEWARP_ASSIGN_OR_RETURN(const api::VolumeHeader header, api::read_header(o.grid_like, read_options()));
    request.grid = api::GridPolicy::kGiven;
    request.given_grid = header.geometry;
  } else if (o.grid == "grow") {
    request.grid = api::GridPolicy::kGrow;
  } else if (o.grid != "input") {
    return invalid_argument_error("unknown --grid '" + o.grid + "'; use input or grow (or --grid-like IMAGE)");
  }
  request.limits.max_voxels = global_options().max_voxels;
  request.limits.max_bytes = o.max_output_mb << 20;
  for (const std::string& path : o.extra_surfaces) {
    POSEWARP_ASSIGN_OR_RETURN(SurfaceMesh mesh, api::read_surface(path));
    request.extra_surfaces.push_back(std::move(mesh));
  }
  return request;
}

Status write_surfaces(const api::PoseResult& result, const std::string& dir, const std::string& format) {
  if (dir.empty()) return ok_status();
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) return invalid_argument_error("cannot create " + dir + ": " + ec.message());
  for (const SurfaceMesh& s : result.surfaces) {
    POSEWARP_RETURN_IF_ERROR(api::write_surface(s, (fs::path(dir) / (s.name + "." + format)).string()));
  }
  say("wrote " + std::to_string(result.surfaces.size()) + " surfaces to " + dir);
  return ok_status();
}

void summarize(const api::PoseResult& result) {
  const QualityReport& r = result.report;
  std::string line = "pose '" + r.pose_name + "' (" + r.method + "): " + std::to_string(r.mesh.inverted_tets) +
                     " inverted tets, det " + fixed(r.mesh.det_min, 3) + ".." + fixed(r.mesh.det_max, 3) +
                     ", soft-tissue volume " + fixed(100.0 * r.mesh.soft_tissue_volume_change, 2) +
                     "%, bone rigidity error " + fixed(r.bone_rigidity_error_mm, 4) + " mm, " +
                     std::to_string(r.conflicted_voxels) + " conflicted and " + std::to_string(r.extrapolated_voxels) +
                     " extrapolated voxels";
  say(line);
  if (r.bone_voxels > 0 || !r.voxel_rigidity.empty()) {
    say("bones: " + std::to_string(r.bone_voxels) + " voxels mapped rigidly, largest voxel deviation " +
        fixed(r.bone_voxel_deviation_mm, 2) + " mm, " + std::to_string(r.bone_overlaps.size()) +
        " overlapping pairs; " + std::to_string(r.skin_contact_voxels) +
        " voxels kept from showing tissue across a skin contact");
  }
  for (const JointRegionChange& c : r.joint_regions) {
    say("  " + c.joint + " within " + std::to_string(static_cast<int>(c.radius_mm)) + " mm: soft tissue " +
        fixed(100.0 * c.volume_change, 1) + "%, folded " + fixed(100.0 * c.folded_fraction, 2) + "%, stretched " +
        fixed(100.0 * c.stretched_fraction, 2) + "%, skin passed into the tissue facing it " +
        std::to_string(c.skin_inside_tissue + c.skin_inside_bone) + " of " + std::to_string(c.skin_vertices) +
        " vertices");
  }
  if (!r.labels.vanished.empty()) {
    std::string vanished;
    for (const Label l : r.labels.vanished) vanished += " " + std::to_string(l);
    say("warning: labels vanished in this pose:" + vanished);
  }
  for (const std::string& warning : r.warnings) {
    if (warning.rfind("labels vanished", 0) == 0) continue;  // said above with the values
    say("warning: " + warning);
  }
  std::string timings = "timings:";
  double total = 0.0;
  for (const auto& [stage, seconds] : r.stage_seconds)
    timings += " " + stage + " " + fixed(1000.0 * seconds, 1) + " ms,", total += seconds;
  say(timings + " total " + fixed(1000.0 * total, 1) + " ms");
}

Result<api::PoseEngine> load_engine(const std::string& path) {
  POSEWARP_ASSIGN_OR_RETURN(api::Rig rig, api::load_rig(path));
  return api::PoseEngine::create(std::move(rig), progress_bar());
}

Status foreign_dicom_source(const std::string& path) {
  return invalid_argument_error("--dicom-source '" + path + "' is not the CT series the rig was built from (its grid " +
                                "differs): the derived series would be filed in another study");
}

// Two grids over the same voxels (one may run an axis the other way, as a DICOM series stacks its slices).
bool same_place(const ImageGeometry& a, const ImageGeometry& b) {
  if (a.size != b.size) return false;
  for (int axis = 0; axis < 3; ++axis) {
    if (std::abs(a.spacing[static_cast<size_t>(axis)] - b.spacing[static_cast<size_t>(axis)]) > 1e-3) return false;
  }
  // The corners of one are corners of the other.
  for (int corner = 0; corner < 8; ++corner) {
    const Vec3 index{corner & 1 ? static_cast<double>(a.size[0] - 1) : 0.0,
                     corner & 2 ? static_cast<double>(a.size[1] - 1) : 0.0,
                     corner & 4 ? static_cast<double>(a.size[2] - 1) : 0.0};
    const Vec3 at = b.physical_to_index(a.index_to_physical(index));
    for (int axis = 0; axis < 3; ++axis) {
      const double c = at[static_cast<size_t>(axis)], last = static_cast<double>(b.size[static_cast<size_t>(axis)] - 1);
      const bool on_a_corner = std::abs(c) < 1e-2 || std::abs(c - last) < 1e-2;
      if (!on_a_corner) return false;
    }
  }
  return true;
}

// The posed CT and labels as a derived CT series and a SEG of the source series' study (--dicom-out).
Status write_dicom(const PoseOptions& o, const api::SeriesInfo& source, const api::PoseResult& result,
                   const api::LabelMap& map, const std::string& pose_name) {
  if (!result.ct || !result.labels) return internal_error("the pose returned no CT or labels for the DICOM output");
  api::DerivedSeriesOptions options;
  options.uid_root = o.uid_root;
  o.dicom_formats.apply(&options);
  options.series_description =
      o.series_description.empty() ? "posewarp: " + pose_name + " (" + o.output.method + ")" : o.series_description;
  options.derivation_description =
      "re-posed by posewarp (" + pose_name + ", " + o.output.method + ") from series " + source.series_instance_uid;
  POSEWARP_ASSIGN_OR_RETURN(const api::DicomOutputs outputs,
                            api::encode_dicom_outputs(*result.ct, *result.labels, map, source, options));
  POSEWARP_RETURN_IF_ERROR(api::write_dicom_outputs(outputs, o.dicom_out));
  say("wrote the derived CT (" +
      (outputs.ct.frame_numbers.empty()
           ? std::to_string(outputs.ct_files.size()) + " images"
           : "one Enhanced CT image of " + std::to_string(outputs.ct.slice_count()) + " frames") +
      ") and its " + o.dicom_formats.seg + " SEG to " + o.dicom_out);
  return ok_status();
}

// A pose's DICOM output: the source series (its patient, study and images) and its grid, and the pose's name.
struct DicomOut {
  std::optional<api::SeriesInfo> source;
  std::optional<ImageGeometry> grid;
  std::string pose_name;
};

// The pose on posewarp-server, its files written here.
int pose_remotely(const PoseOptions& o, const api::PoseRequest& request, const DicomOut& dicom) {
  Result<RemotePoser> poser = RemotePoser::open(o.connection, o.rig_path);
  if (!poser.ok()) return report(poser.status());
  // For DICOM out, the rig (its label map names the segments; its grid must be --dicom-source's), before posing.
  std::optional<api::LabelMap> map;
  if (dicom.source) {
    Result<api::Rig> rig = poser->rig();
    if (!rig.ok()) return report(rig.status());
    if (!same_place(*dicom.grid, rig->source_geometry)) return report(foreign_dicom_source(o.dicom_source));
    map = std::move(rig->label_map);
  }
  Result<RemotePoseResult> answer = poser->pose(request);
  if (!answer.ok()) return report(answer.status().with_context("pose file '" + o.pose_path + "'"));
  for (const std::string& warning : answer->warnings) say("warning: " + warning);
  Status written = write_outputs(answer->result, answer->report_json, o.labels_out, o.ct_out, o.field_out,
                                 o.report_out, answer->source_grid);
  if (!written.ok()) return report(written);
  if (dicom.source) {
    if (Status s = write_dicom(o, *dicom.source, answer->result, *map, dicom.pose_name); !s.ok()) return report(s);
  }
  Status surfaces = write_surfaces(answer->result, o.surfaces_out, o.output.surface_format);
  return surfaces.ok() ? 0 : report(surfaces);
}

// The pose in this process: each volume written from its own thread as soon as the engine hands it out.
int pose_locally(const PoseOptions& o, api::PoseRequest request, const DicomOut& dicom) {
  Stopwatch wall;
  std::string breakdown = "wall:";
  const auto lap = [&](const char* step) {
    breakdown += std::string(" ") + step + " " + fixed(wall.lap(), 2) + " s,";
  };
  Result<api::Rig> rig = api::load_rig(o.rig_path);
  if (!rig.ok()) return report(rig.status());
  lap("open");
  Result<api::PoseEngine> engine = api::PoseEngine::create(std::move(*rig), progress_bar());
  if (!engine.ok()) return report(engine.status());
  lap("engine");
  // The derived series is filed in --dicom-source's study: that series must be the one the rig was built from.
  if (dicom.grid && !same_place(*dicom.grid, engine->rig().source_geometry)) {
    return report(foreign_dicom_source(o.dicom_source));
  }
  // Each volume is written as soon as it is posed, while the engine goes on (the CT's warp, the label report); a
  // DICOM output needs both volumes at the end instead.
  std::future<Status> labels_written, ct_written;
  if (o.dicom_out.empty() && !o.labels_out.empty()) {
    request.labels_ready = [&](std::shared_ptr<const LabelVolume> labels) {
      labels_written = std::async(std::launch::async, [&, labels] { return api::write_volume(*labels, o.labels_out); });
    };
  }
  if (o.dicom_out.empty() && !o.ct_out.empty()) {
    request.ct_ready = [&](std::shared_ptr<const IntensityVolume> ct) {
      ct_written = std::async(std::launch::async, [&, ct] { return api::write_volume(*ct, o.ct_out); });
    };
  }
  Result<api::PoseResult> result = engine->pose(request, progress_bar());
  if (!result.ok()) return report(result.status());
  lap("pose");
  summarize(*result);
  for (auto [written, path] : {std::pair{&labels_written, &o.labels_out}, std::pair{&ct_written, &o.ct_out}}) {
    if (!written->valid()) continue;
    if (Status s = written->get(); !s.ok()) return report(s);
    say("wrote " + *path);
  }
  Status written = write_outputs(*result, api::report_to_json(result->report), o.labels_out, o.ct_out, o.field_out,
                                 o.report_out, engine->rig().labels.geometry());
  if (!written.ok()) return report(written);
  lap("write (what the pose did not overlap)");
  say(breakdown + " total " + fixed(wall.seconds(), 2) + " s");
  if (dicom.source) {
    if (Status s = write_dicom(o, *dicom.source, *result, engine->rig().label_map, dicom.pose_name); !s.ok())
      return report(s);
  }
  Status surfaces = write_surfaces(*result, o.surfaces_out, o.output.surface_format);
  if (!surfaces.ok()) return report(surfaces);
  return 0;
}

int run_pose(const PoseOptions& o) {
  std::vector<std::string> inputs{o.rig_path, o.pose_path, o.output.grid_like};
  inputs.insert(inputs.end(), o.output.extra_surfaces.begin(), o.output.extra_surfaces.end());
  std::vector<std::string> outputs{o.labels_out, o.ct_out, o.field_out, o.report_out};
  if (!o.field_out.empty()) outputs.push_back(forward_field_path(o.field_out));
  if (Status s = refuse_overwriting_inputs(outputs, inputs); !s.ok()) return report(s);
  if (Status s = check_output_files(outputs); !s.ok()) return report(s);
  if (Status s = refuse_directories({o.report_out}); !s.ok()) return report(s);
  Result<Pose> pose = api::read_pose(o.pose_path);
  if (!pose.ok()) return report(pose.status());
  // DICOM out needs the source series: its patient, study and images are what the derived series refer to.
  DicomOut dicom;
  dicom.pose_name = fs::path(o.pose_path).stem().string();
  if (std::error_code ec; !o.dicom_out.empty() && fs::exists(o.dicom_out, ec) && !fs::is_empty(o.dicom_out, ec)) {
    return report(already_exists_error("--dicom-out '" + o.dicom_out + "' is not empty; choose a new directory"));
  }
  if (!o.dicom_out.empty()) {
    if (o.dicom_source.empty()) {
      return report(
          invalid_argument_error("--dicom-out needs --dicom-source DIR: the CT series the rig was built "
                                 "from (its patient, study and images are referenced)"));
    }
    Result<api::CtSeries> source = api::read_ct_directory(o.dicom_source);
    if (!source.ok()) return report(source.status().with_context("--dicom-source"));
    dicom.source = source->info;
    dicom.grid = source->ct.geometry();
  }
  Result<api::PoseRequest> request = make_request(o.output);
  if (!request.ok()) return report(request.status());
  request->pose = *pose;
  request->pose_source = "pose file '" + o.pose_path + "'";  // a pose that does not fit the rig names its file
  request->want_labels = !o.labels_out.empty() || !o.report_out.empty() || !o.dicom_out.empty();
  request->want_ct = !o.ct_out.empty() || !o.dicom_out.empty();
  request->want_fields = !o.field_out.empty();
  request->want_surfaces = !o.surfaces_out.empty();
  return o.connection.server.empty() ? pose_locally(o, *request, dicom) : pose_remotely(o, *request, dicom);
}

struct CompareOptions {
  std::string rig_path;
  std::string pose_path;
  std::string json_out;
  std::vector<std::string> methods{"cor", "fem"};
  api::FemOptions fem;    // for the fem method's solve
  Connection connection;  // compare on posewarp-server; rig_path is then a rig id
};

// One request per method of --methods (two to four, none twice), each for the mesh report alone.
Result<std::vector<api::PoseRequest>> compare_requests(const CompareOptions& o) {
  if (o.methods.size() < 2 || o.methods.size() > 4) {
    return invalid_argument_error("--methods takes two to four of cor, dqs, lbs and fem, comma separated");
  }
  std::vector<api::PoseRequest> requests;
  for (const std::string& name : o.methods) {
    Result<api::Method> method = api::method_from_name(name);
    if (!method.ok()) return method.status().with_context("--methods");
    for (const api::PoseRequest& earlier : requests) {
      if (earlier.method == *method) return invalid_argument_error("--methods names '" + name + "' twice");
    }
    api::PoseRequest request;
    request.method = *method;
    request.fem = o.fem;
    request.want_labels = request.want_ct = request.want_surfaces = false;
    requests.push_back(std::move(request));
  }
  return requests;
}

// Each request's quality report as JSON, posed in process or on the server.
Result<std::vector<nlohmann::json>> compare_reports(const CompareOptions& o,
                                                    const std::vector<api::PoseRequest>& requests) {
  std::vector<nlohmann::json> reports;
  if (!o.connection.server.empty()) {
    POSEWARP_ASSIGN_OR_RETURN(RemotePoser poser, RemotePoser::open(o.connection, o.rig_path));
    for (const api::PoseRequest& request : requests) {
      Result<RemotePoseResult> answer = poser.pose(request);
      if (!answer.ok()) return answer.status().with_context("pose file '" + o.pose_path + "'");
      reports.push_back(nlohmann::json::parse(answer->report_json, nullptr, false));
    }
  } else {
    POSEWARP_ASSIGN_OR_RETURN(api::PoseEngine engine, load_engine(o.rig_path));
    for (const api::PoseRequest& request : requests) {
      POSEWARP_ASSIGN_OR_RETURN(api::PoseResult result, engine.pose(request, progress_bar()));
      reports.push_back(nlohmann::json::parse(api::report_to_json(result.report), nullptr, false));
    }
  }
  for (const nlohmann::json& r : reports) {
    if (!r.is_object()) return internal_error("a quality report could not be read back");
  }
  return reports;
}

// The reports' figures side by side: a row per figure (the whole body, then each moved joint's region), a column
// per method.
std::string compare_table(const std::string& pose_name, const std::vector<std::string>& methods,
                          const std::vector<nlohmann::json>& reports) {
  std::vector<std::pair<std::string, std::vector<std::string>>> rows;
  auto row = [&](const std::string& name, auto&& value) {
    std::vector<std::string> cells;
    for (const nlohmann::json& r : reports) cells.push_back(value(r));
    rows.emplace_back(name, std::move(cells));
  };
  auto percent = [](double v) { return (v >= 0 ? "+" : "") + fixed(100.0 * v, 1) + "%"; };
  row("inverted tets", [](const nlohmann::json& r) { return std::to_string(r["tets"].value("inverted", 0)); });
  row("soft tissue, whole body", [&](const nlohmann::json& r) { return percent(r["volume_change"].value("soft_tissue", 0.0)); });
  row("soft tissue, local error", [&](const nlohmann::json& r) {
    return fixed(100.0 * r["volume_change"].value("soft_tissue_local_error", 0.0), 1) + "%";
  });
  const nlohmann::json& regions = reports.front()["moved_joints"];
  for (size_t m = 0; regions.is_array() && m < regions.size(); ++m) {
    const std::string where = regions[m].value("joint", "") + " within " +
                              std::to_string(static_cast<int>(regions[m].value("radius_mm", 0.0))) + " mm: ";
    for (const auto& [key, label] : {std::pair{"volume_change", "soft tissue"}, std::pair{"folded_fraction", "folded"},
                                     std::pair{"stretched_fraction", "stretched"}}) {
      row(where + label, [&, key = key](const nlohmann::json& r) {
        const nlohmann::json& mine = r["moved_joints"];
        if (!mine.is_array() || m >= mine.size()) return std::string("-");
        const double v = mine[m].value(key, 0.0);
        return std::string(key) == "volume_change" ? percent(v) : fixed(100.0 * v, 1) + "%";
      });
    }
    row(where + "skin passed in", [&](const nlohmann::json& r) {
      const nlohmann::json& mine = r["moved_joints"];
      if (!mine.is_array() || m >= mine.size()) return std::string("-");
      return std::to_string(mine[m].value("skin_inside_tissue", 0) + mine[m].value("skin_inside_bone", 0)) + "/" +
             std::to_string(mine[m].value("skin_vertices", 0));
    });
  }
  row("seconds (skinning + fem)", [](const nlohmann::json& r) {
    const nlohmann::json& t = r["stage_seconds"];
    return fixed(t.value("skinning", 0.0) + t.value("fem", 0.0), 2);
  });
  size_t width = 6;
  for (const auto& [name, cells] : rows) width = std::max(width, name.size());
  std::ostringstream table;
  table << std::left << std::setw(static_cast<int>(width)) << ("pose '" + pose_name + "'");
  for (const std::string& method : methods) table << std::right << std::setw(10) << method;
  table << "\n";
  for (const auto& [name, cells] : rows) {
    table << std::left << std::setw(static_cast<int>(width)) << name;
    for (const std::string& cell : cells) table << std::right << std::setw(10) << cell;
    table << "\n";
  }
  return table.str();
}

// One pose with each method, its local figures side by side: the tet mesh only (no volume is warped), so each
// method costs its skinning (and for fem its solve) and the mesh report.
int run_compare(const CompareOptions& o) {
  Result<std::vector<api::PoseRequest>> requests = compare_requests(o);
  if (!requests.ok()) return report(requests.status());
  if (Status s = refuse_overwriting_inputs({o.json_out}, {o.rig_path, o.pose_path}); !s.ok()) return report(s);
  if (Status s = check_output_files({o.json_out}); !s.ok()) return report(s);
  if (Status s = refuse_directories({o.json_out}); !s.ok()) return report(s);
  Result<Pose> pose = api::read_pose(o.pose_path);
  if (!pose.ok()) return report(pose.status());
  for (api::PoseRequest& request : *requests) {
    request.pose = *pose;
    request.pose_source = "pose file '" + o.pose_path + "'";
  }
  Result<std::vector<nlohmann::json>> reports = compare_reports(o, *requests);
  if (!reports.ok()) return report(reports.status());
  std::cout << compare_table(pose->name, o.methods, *reports) << std::flush;
  if (!o.json_out.empty()) {
    nlohmann::json out{{"format", "posewarp.compare"}, {"version", 1}, {"pose", pose->name}, {"methods", o.methods}};
    for (size_t i = 0; i < reports->size(); ++i) out["reports"][o.methods[i]] = (*reports)[i];
    if (Status s = api::write_file_atomically(o.json_out, out.dump(2) + "\n", "comparison"); !s.ok()) return report(s);
  }
  return 0;
}

struct AnimateOptions {
  std::string rig_path;
  std::string bvh_path;
  std::string map_path;
  std::string animation_path;
  std::string frames = "0:-1";
  std::string out_dir;
  std::string surfaces_dir;
  bool labels = true;
  bool ct = true;
  Connection connection;  // animate on posewarp-server; rig_path is then a rig id
  OutputOptions output;
};

int run_animate(const AnimateOptions& o) {
  int first = 0, last = -1;
  {
    const size_t colon = o.frames.find(':');
    try {
      if (colon == std::string::npos) {
        first = last = std::stoi(o.frames);
      } else {
        first = std::stoi(o.frames.substr(0, colon));
        last = std::stoi(o.frames.substr(colon + 1));
      }
    } catch (const std::exception&) {
      return report(invalid_argument_error("--frames takes A:B (0-based, inclusive; B = -1 for the last frame)"));
    }
  }
  // Frames posed in process, or by the server (one connection for every frame).
  std::optional<api::PoseEngine> engine;
  std::optional<RemotePoser> poser;
  if (o.connection.server.empty()) {
    Result<api::PoseEngine> loaded = load_engine(o.rig_path);
    if (!loaded.ok()) return report(loaded.status());
    engine = std::move(loaded).value();
  } else {
    Result<RemotePoser> opened = RemotePoser::open(o.connection, o.rig_path);
    if (!opened.ok()) return report(opened.status());
    poser = std::move(opened).value();
  }
  Result<api::Animation> animation = [&]() -> Result<api::Animation> {
    if (!o.animation_path.empty()) return api::read_animation(o.animation_path);
    if (o.bvh_path.empty() || o.map_path.empty()) {
      return invalid_argument_error("give --bvh FILE with --map MAP (or --animation FILE.json)");
    }
    POSEWARP_ASSIGN_OR_RETURN(const api::BvhMap map, api::read_bvh_map(o.map_path));
    if (engine) return api::read_bvh(o.bvh_path, map, engine->rig(), first, last);
    POSEWARP_ASSIGN_OR_RETURN(const api::Rig rig, poser->rig());  // BVH retargeting needs its skeleton
    return api::read_bvh(o.bvh_path, map, rig, first, last);
  }();
  if (!animation.ok()) return report(animation.status());
  std::error_code ec;
  fs::create_directories(o.out_dir, ec);
  if (ec) return report(invalid_argument_error("cannot create " + o.out_dir + ": " + ec.message()));
  Result<api::PoseRequest> request = make_request(o.output);
  if (!request.ok()) return report(request.status());
  request->want_labels = true;
  request->want_ct = o.ct;
  request->want_surfaces = !o.surfaces_dir.empty();
  const size_t count = animation->frames.size();
  for (size_t f = 0; f < count; ++f) {
    request->pose = animation->frames[f];
    Result<RemotePoseResult> answer = [&]() -> Result<RemotePoseResult> {
      if (poser) return poser->pose(*request);
      POSEWARP_ASSIGN_OR_RETURN(api::PoseResult result, engine->pose(*request, {}));
      const std::string json = api::report_to_json(result.report);
      return RemotePoseResult{std::move(result), engine->rig().labels.geometry(), json, {}};
    }();
    if (!answer.ok()) return report(answer.status().with_context("frame " + std::to_string(f)));
    char stem[32];
    std::snprintf(stem, sizeof(stem), "frame_%04zu", f);
    const fs::path dir(o.out_dir);
    if (Status s =
            write_surfaces(answer->result, o.surfaces_dir.empty() ? "" : (fs::path(o.surfaces_dir) / stem).string(),
                           o.output.surface_format);
        !s.ok()) {
      return report(s);
    }
    Status written = write_outputs(answer->result, answer->report_json,
                                   o.labels ? (dir / (std::string(stem) + "_labels.nii.gz")).string() : "",
                                   o.ct ? (dir / (std::string(stem) + "_ct.nii.gz")).string() : "", "",
                                   (dir / (std::string(stem) + "_report.json")).string(), answer->source_grid);
    if (!written.ok()) return report(written);
    std::fprintf(stderr, "frame %zu/%zu done\n", f + 1, count);
  }
  return 0;
}

void add_fem_options(CLI::App* cmd, api::FemOptions& fem) {
  cmd->add_option("--fem-iterations", fem.max_iterations,
                  "With --method fem: at most this many iterations of the soft tissue's solve (default 20, which the "
                  "untangling that ends the solve completes; more converge further and take longer)")
      ->check(CLI::Range(1, 10000));
  cmd->add_option("--fem-volume-weight", fem.volume_weight,
                  "With --method fem: how much more keeping volume counts than keeping shape (default 100, nearly "
                  "incompressible)")
      ->check(CLI::Range(1e-3, 1e6));
  cmd->add_flag("--fem-contact", fem.contact,
                "With --method fem: push the skin that bending drives into the tissue facing it (back of the knee, "
                "forearm against the belly) back out of it; takes about half as long again");
  cmd->add_option("--fem-refine", fem.refine_iterations,
                  "With --method fem: then this many Newton iterations of the nonlinear material with a volume per "
                  "compressed vertex star and no new folds (default 3; 0: none). They give back the volume a bent hip "
                  "loses to the solve (the body phantom's hip 90 within 50 mm: -6.0 to -7.9% without, -3.3 to -4.4% "
                  "with 3), at 0.1-0.2 s an iteration there. No contact term: skin --fem-contact kept out may pass "
                  "back")
      ->check(CLI::Range(0, 1000));
}

void add_output_options(CLI::App* cmd, OutputOptions& o) {
  cmd->add_option("--method", o.method, "How the tissue moves: cor (centres of rotation), dqs (dual quaternions), lbs (linear "
                  "blend) or fem (CoR refined by the soft tissue's volume-preserving steady state: slower, keeps the "
                  "volume at bent joints)")
      ->check(CLI::IsMember({"cor", "dqs", "lbs", "fem"}))
      ->capture_default_str();
  add_fem_options(cmd, o.fem);
  cmd->add_option("--grid", o.grid, "Output grid: input (the study's grid) or grow (grown to hold the posed body)")
      ->check(CLI::IsMember({"input", "grow"}))
      ->capture_default_str();
  cmd->add_option("--grid-like", o.grid_like, "Output on the grid of this image instead");
  cmd->add_flag("--nearest-ct", o.nearest_ct, "Nearest-neighbour CT instead of trilinear");
  cmd->add_option("--max-output-mb", o.max_output_mb,
                  "Refuse a pose whose outputs would take more memory than this, in MB (0 = half the machine's memory)")
      ->check(CLI::NonNegativeNumber)
      ->capture_default_str();
  cmd->add_option("--surface-format", o.surface_format, "Format of written surfaces")
      ->check(CLI::IsMember({"vtp", "stl", "obj", "ply"}))
      ->capture_default_str();
  cmd->add_option("--surface", o.extra_surfaces,
                  "A mesh of your own in rest space (.stl, .obj, .ply, .vtp) to deform too")
      ->check(CLI::ExistingFile);
}

}  // namespace

void add_pose_commands(CLI::App& app) {
  {
    auto o = std::make_shared<PoseOptions>();
    CLI::App* cmd = app.add_subcommand(
        "pose",
        "Apply a pose to a rig: posed labels (never a new value) and CT, displacement fields and a quality report");
    cmd->add_option("rig", o->rig_path, "Rig file (posewarp rig build), or with --server a rig id")->required();
    cmd->add_option("--pose", o->pose_path, "Pose JSON (see data/poses/)")->required();
    cmd->add_option("--labels-out", o->labels_out, "Posed label volume");
    cmd->add_option("--ct-out", o->ct_out, "Posed CT");
    cmd->add_option("--surfaces-out", o->surfaces_out,
                    "Directory for the deformed surfaces (bones, skin, --surface meshes), one file each");
    cmd->add_option("--field-out", o->field_out,
                    "Inverse displacement field (output grid, for ITK/ANTs/elastix); the forward field goes beside it "
                    "as *_forward");
    cmd->add_option("--report", o->report_out, "Quality report JSON");
    cmd->add_option(
        "--dicom-out", o->dicom_out,
        "Directory for the posed CT as a derived DICOM series (ct/) and the labels as a DICOM SEG (seg.dcm), "
        "in the study of --dicom-source");
    cmd->add_option("--dicom-source", o->dicom_source,
                    "The CT series (a directory of DICOM files) the rig was built from");
    cmd->add_option("--uid-root", o->uid_root,
                    "Root of the new DICOM UIDs (2.25: UUID-derived, no registration needed)")
        ->capture_default_str();
    cmd->add_option("--series-description", o->series_description,
                    "Series Description of the derived series (default: posewarp: POSE (METHOD))");
    add_dicom_format_options(cmd, o->dicom_formats);
    add_connection_options(cmd, o->connection);
    cmd->add_option(
        "--server", o->connection.server,
        "Pose on posewarp-server at HOST:PORT: RIG is then a rig id there; the same files are written here");
    add_output_options(cmd, o->output);
    cmd->callback([o] {
      const int code = run_pose(*o);
      if (code != 0) throw CLI::RuntimeError(code);
    });
  }
  {
    auto o = std::make_shared<CompareOptions>();
    CLI::App* cmd = app.add_subcommand(
        "compare", "One pose with two to four methods, their figures near each moved joint side by side (no volume is "
                   "warped: the tet mesh's report only)");
    cmd->add_option("rig", o->rig_path, "Rig file, or with --server a rig id")->required();
    cmd->add_option("--pose", o->pose_path, "Pose JSON (see data/poses/)")->required();
    cmd->add_option("--methods", o->methods, "Methods to compare, comma separated: cor, dqs, lbs, fem")
        ->delimiter(',')
        ->capture_default_str();
    add_fem_options(cmd, o->fem);
    cmd->add_option("--json", o->json_out, "Also write the figures and each method's whole report as JSON here");
    add_connection_options(cmd, o->connection);
    cmd->add_option("--server", o->connection.server, "Compare on posewarp-server at HOST:PORT: RIG is then a rig id");
    cmd->callback([o] {
      const int code = run_compare(*o);
      if (code != 0) throw CLI::RuntimeError(code);
    });
  }
  {
    auto o = std::make_shared<AnimateOptions>();
    CLI::App* cmd = app.add_subcommand("animate", "Pose a rig frame by frame from a BVH motion (or an animation JSON)");
    cmd->add_option("rig", o->rig_path, "Rig file, or with --server a rig id")->required();
    cmd->add_option("--bvh", o->bvh_path, "BVH motion file");
    cmd->add_option("--map", o->map_path, "BVH joint -> rig joint map JSON");
    cmd->add_option("--animation", o->animation_path, "Animation JSON instead of a BVH");
    cmd->add_option("--frames", o->frames, "Frames A:B, 0-based inclusive (B = -1: to the end)")->capture_default_str();
    cmd->add_option("--out-dir", o->out_dir, "Directory for frame_NNNN_{labels,ct,report} files")->required();
    cmd->add_flag("!--no-ct", o->ct, "Skip the CT");
    cmd->add_option("--surfaces-out", o->surfaces_dir,
                    "Also write each frame's deformed surfaces under DIR/frame_NNNN/");
    add_connection_options(cmd, o->connection);
    cmd->add_option("--server", o->connection.server,
                    "Animate on posewarp-server at HOST:PORT: RIG is then a rig id there; the same files are written "
                    "here (a BVH is retargeted here, on the rig's skeleton downloaded once)");
    add_output_options(cmd, o->output);
    cmd->callback([o] {
      if (int code = run_animate(*o); code != 0) throw CLI::RuntimeError(code);
    });
  }
}

}  // namespace posewarp::cli
