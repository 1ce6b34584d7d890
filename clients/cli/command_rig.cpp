// Rig commands: build (the expensive half of the pipeline, once per study), info, export.
#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <filesystem>
#include <iomanip>
#include <iostream>
#include <sstream>

#include "cli_support.h"
#include "posewarp/api/dicom.h"
#include "posewarp/api/files.h"
#include "posewarp/api/rig.h"
#include "posewarp/api/joint_range.h"
#include "posewarp/api/rig_info.h"
#include "posewarp/api/rig_file.h"
#include "posewarp/api/vtk_export.h"
#include "remote.h"

namespace posewarp::cli {
namespace {

using json = nlohmann::json;

struct BuildOptions {
  std::string labels_path;
  std::string ct_path;
  std::string body_path;
  std::string label_map_path;
  std::string preset;
  std::string spec_path;
  std::string out;
  Connection connection;  // remote build on posewarp-server
  std::string name;
  bool sequential = false;
  bool islands_fail = false;
  api::BuildParams params;
};

std::string fixed(double value, int digits) {
  std::ostringstream out;
  out << std::fixed << std::setprecision(digits) << value;
  return out.str();
}

int run_build(BuildOptions& options) {
  const auto start = std::chrono::steady_clock::now();
  if (Status s = refuse_overwriting_inputs({options.out}, {options.labels_path, options.ct_path, options.body_path,
                                                           options.label_map_path, options.spec_path});
      !s.ok()) {
    return report(s);
  }
  if (Status s = check_output_files({options.out}); !s.ok()) return report(s);
  if (Status s = refuse_directories({options.out}); !s.ok()) return report(s);
  api::BuildInputs inputs;
  Result<api::LabelMap> map = load_label_map(options.label_map_path, options.preset);
  if (!map.ok()) return report(map.status());
  inputs.label_map = std::move(map).value();
  if (api::is_dicom_file(options.labels_path)) {
    // A DICOM SEG on a DICOM CT series: the labels are the segments' numbers, the map follows their names.
    if (options.ct_path.empty()) {
      return report(invalid_argument_error("'" + options.labels_path +
                                           "' is a DICOM file: give the CT series it was "
                                           "made on with --ct DIR (a directory of DICOM files)"));
    }
    Result<api::DicomStudy> study = api::read_dicom_study(options.ct_path, options.labels_path, inputs.label_map);
    if (!study.ok()) return report(study.status());
    for (const std::string& warning : study->warnings) say("warning: " + warning);
    inputs.labels = std::move(study->labels);
    inputs.ct = std::move(study->ct.ct);
    inputs.label_map = std::move(study->label_map);
    inputs.labels_source = options.labels_path;
    inputs.ct_source = options.ct_path;
  } else {
    Result<LabelVolume> labels = api::read_label_volume(options.labels_path, read_options());
    if (!labels.ok()) return report(labels.status());
    inputs.labels = std::move(labels).value();
    inputs.labels_source = options.labels_path;
  }
  if (!options.ct_path.empty() && !inputs.ct) {
    Result<IntensityVolume> ct = api::read_intensity_volume(options.ct_path, read_options());
    if (!ct.ok()) return report(ct.status());
    inputs.ct = std::move(ct).value();
    inputs.ct_source = options.ct_path;
  }
  if (!options.body_path.empty()) {
    Result<LabelVolume> body = api::read_label_volume(options.body_path, read_options());
    if (!body.ok()) return report(body.status());
    inputs.body = std::move(body).value();
  }
  if (!options.spec_path.empty()) {
    Result<api::RigSpec> spec = api::read_rig_spec(options.spec_path);
    if (!spec.ok()) return report(spec.status());
    inputs.spec = std::move(spec).value();
  }
  options.params.mesh.parallel = !options.sequential;
  options.params.weights.islands =
      options.islands_fail ? api::IslandPolicy::kFail : api::IslandPolicy::kAttachNearest;
  const double read_seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  Result<api::Rig> rig = api::build_rig(inputs, options.params, progress_bar());
  if (!rig.ok()) return report(rig.status());
  if (Status saved = api::save_rig(*rig, options.out); !saved.ok()) return report(saved);
  const double total = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();

  say("rig " + rig->id() + " written to " + options.out);
  const api::SkeletonInfo skeleton = api::describe_skeleton(*rig);
  say("  " + std::to_string(skeleton.segments.size()) + " segments, " + std::to_string(skeleton.joints.size()) +
      " joints, " + std::to_string(rig->mesh.vertex_count()) + " vertices, " + std::to_string(rig->mesh.tet_count()) +
      " tets");
  for (const std::string& note : skeleton.notes) say("  note: " + note);
  if (!skeleton.missing_segments.empty()) {
    std::string missing;
    for (const std::string& name : skeleton.missing_segments) missing += (missing.empty() ? "" : ", ") + name;
    say("  not in this study: " + missing);
  }
  std::string timings = "  timings: read " + fixed(read_seconds, 2) + " s";
  for (const auto& [stage, seconds] : rig->provenance.stage_seconds)
    timings += ", " + stage + " " + fixed(seconds, 2) + " s";
  say(timings + "; total " + fixed(total, 2) + " s");
  return 0;
}

// One joint of `rig info --json`, with its range of motion.
json joint_json(const api::JointInfo& joint, const std::vector<api::MotionRange>& ranges) {
  auto triple = [](const Eigen::Vector3d& v) { return json::array({v.x(), v.y(), v.z()}); };
  json entry{
      {"name", joint.name},
      {"parent", joint.parent},
      {"child", joint.child},
      {"centre_mm", triple(joint.centre_mm)},
      {"method", joint.method},
      {"placed_because", joint.placed_because},
      {"kind", joint.kind},
      {"side", joint.side},
      {"declared", joint.declared},
      {"contact_area_mm2", joint.contact_area_mm2},
      // Each axis is the one a positive angle turns the child about (right-hand rule, LPS).
      {"flexion_axis", triple(joint.frame.col(0))},
      {"flexion_moves_child", joint.flexion_moves_child},
      {"abduction_axis", triple(joint.frame.col(1))},
      {"internal_rotation_axis", triple(joint.internal_rotation_sign * joint.frame.col(2))},
      {"frame", json::array({triple(joint.frame.col(0)), triple(joint.frame.col(1)), triple(joint.frame.col(2))})},
      {"internal_rotation_sign", joint.internal_rotation_sign}};
  if (joint.method == "sphere-fit" || joint.method == "cylinder-fit") {
    entry["fit_radius_mm"] = joint.fit_radius_mm;
    entry["fit_rms_mm"] = joint.fit_rms_mm;
  }
  if (joint.hinge_axis.norm() > 0.5) entry["hinge_axis"] = triple(joint.hinge_axis);
  // [negative, positive] degrees each way; a bound short of 150 is where the bones meet (more than 1 ml).
  for (const api::MotionRange& m : ranges) {
    entry["range_deg"][m.motion] = {0.0 - m.negative_deg, m.positive_deg};  // 0.0 - x: no "-0"
    entry["range_stopped_by_bone"][m.motion] = {m.negative_stopped, m.positive_stopped};
  }
  return entry;
}

// `rig info --json`: the rig's grid, skeleton (each joint's range of motion: how far it turns before its bones meet
// a bone that does not move with them, measured at build, or here for a rig built before that), mesh, timings,
// statistics, parameters and provenance.
Result<json> info_json(const std::string& path, const api::Rig& rig, const std::string& content_hash,
                       double load_seconds) {
  const api::SkeletonInfo s = api::describe_skeleton(rig);
  json doc;
  doc["path"] = path;
  doc["id"] = rig.id();
  doc["content_hash"] = content_hash;
  doc["load_seconds"] = load_seconds;
  doc["source_grid"] = {{"size", rig.source_geometry.size},
                        {"spacing_mm", rig.source_geometry.spacing},
                        {"origin_mm", rig.source_geometry.origin},
                        {"direction", rig.source_geometry.direction}};
  json segments = json::array();
  for (const api::SegmentInfo& segment : s.segments) {
    segments.push_back({{"name", segment.name},
                        {"labels", segment.labels},
                        {"voxels", segment.voxels},
                        {"centroid_mm", {segment.centroid_mm.x(), segment.centroid_mm.y(), segment.centroid_mm.z()}}});
  }
  std::vector<std::vector<api::MotionRange>> ranges;
  for (const api::JointInfo& joint : s.joints) ranges.push_back(joint.ranges);
  if (std::any_of(s.joints.begin(), s.joints.end(), [](const api::JointInfo& joint) { return joint.ranges.empty(); })) {
    POSEWARP_ASSIGN_OR_RETURN(const std::vector<api::JointRange> measured, api::joint_ranges(rig));
    for (size_t j = 0; j < ranges.size() && j < measured.size(); ++j) ranges[j] = measured[j].motions;
  }
  json joints = json::array();
  for (size_t index = 0; index < s.joints.size(); ++index) joints.push_back(joint_json(s.joints[index], ranges[index]));
  doc["root"] = s.root;
  doc["segments"] = segments;
  doc["joints"] = joints;
  doc["missing_segments"] = s.missing_segments;
  doc["notes"] = s.notes;
  doc["mesh"] = {{"vertices", rig.mesh.vertex_count()}, {"tets", rig.mesh.tet_count()}};
  json stages = json::object();
  for (const auto& [stage, seconds] : rig.provenance.stage_seconds) stages[stage] = seconds;
  doc["stage_seconds"] = stages;
  doc["stats"] = json::parse(rig.provenance.stats_json.empty() ? "{}" : rig.provenance.stats_json);
  doc["params"] = json::parse(rig.params_json.empty() ? "{}" : rig.params_json);
  doc["provenance"] = {{"software_version", rig.provenance.software_version},
                       {"labels", rig.provenance.labels_source},
                       {"ct", rig.provenance.ct_source},
                       {"labels_hash", rig.labels_hash},
                       {"ct_hash", rig.ct_hash}};
  return doc;
}

// `rig info` for a reader: the same document, in lines.
void print_info(const std::string& path, const api::Rig& rig, const json& doc, double load_seconds) {
  const json& provenance = doc["provenance"];
  const std::string ct = provenance["ct"].get<std::string>();
  std::cout
      << "rig " << doc["id"].get<std::string>() << " (" << path << ", loaded in " << fixed(load_seconds, 3) << " s)\n"
      << "  built by posewarp " << provenance["software_version"].get<std::string>() << " from "
      << provenance["labels"].get<std::string>() << (ct.empty() ? "" : " + " + ct) << "\n"
      << "  mesh: " << doc["mesh"]["vertices"].get<int64_t>() << " vertices, " << doc["mesh"]["tets"].get<int64_t>()
      << " tets\n"
      << "  root: " << doc["root"].get<std::string>() << "\n"
      << "  joints (axes in LPS: x patient left, y posterior, z superior; a positive angle turns the child about\n"
      << "  the axis by the right-hand rule: flexion moves the child's far end the way shown, abduction away\n"
      << "  from the midline (midline joints: toward the left), internal rotation turns its front medially):\n";
  auto axis_text = [](const json& v) {
    return "(" + fixed(v[0], 2) + ", " + fixed(v[1], 2) + ", " + fixed(v[2], 2) + ")";
  };
  for (const json& joint : doc["joints"]) {
    const auto& c = joint["centre_mm"];
    std::cout << "    " << std::left << std::setw(20) << joint["name"].get<std::string>() << std::setw(16)
              << joint["parent"].get<std::string>() << "-> " << std::setw(16) << joint["child"].get<std::string>()
              << std::right << " (" << fixed(c[0], 1) << ", " << fixed(c[1], 1) << ", " << fixed(c[2], 1) << ") mm  "
              << joint["method"].get<std::string>() << ", " << joint["kind"].get<std::string>() << ", "
              << joint["side"].get<std::string>() << "\n"
              << "      placed: " << joint["placed_because"].get<std::string>() << "\n"
              << "      flexion about " << axis_text(joint["flexion_axis"]) << " ("
              << joint["flexion_moves_child"].get<std::string>() << "), abduction about "
              << axis_text(joint["abduction_axis"]) << ", internal rotation about "
              << axis_text(joint["internal_rotation_axis"]) << "\n";
    if (const std::string line = joint_range_line(joint); !line.empty()) std::cout << line << "\n";
  }
  if (doc["stats"].contains("weights")) {
    const json& w = doc["stats"]["weights"];
    std::cout << "  weights: raw range [" << w.value("min_raw_weight", 0.0) << ", " << w.value("max_raw_weight", 0.0)
              << "], partition of unity error " << w.value("max_partition_error", 0.0) << ", solver "
              << w.value("solver", std::string("?")) << "\n";
  }
  std::cout << "  timings:";
  for (const auto& [stage, seconds] : rig.provenance.stage_seconds) std::cout << " " << stage << " " << fixed(seconds, 2) << " s";
  std::cout << "\n";
  for (const json& note : doc["notes"]) std::cout << "  note: " << note.get<std::string>() << "\n";
}

int run_info(const std::string& path, bool as_json) {
  api::remove_stale_partial_files(std::filesystem::path(path).parent_path().string());
  const Stopwatch stopwatch;
  std::string content_hash;  // the file's own: encoding every section again to hash it took a second on a body
  Result<api::Rig> rig = api::load_rig(path, content_hash);
  if (!rig.ok()) return report(rig.status());
  const double load_seconds = stopwatch.seconds();
  Result<json> doc = info_json(path, *rig, content_hash, load_seconds);
  if (!doc.ok()) return report(doc.status());
  if (as_json) {
    std::cout << doc->dump(2) << '\n';
  } else {
    print_info(path, *rig, *doc, load_seconds);
  }
  return 0;
}

int run_export(const std::string& path, const std::string& mesh_out, const std::string& skeleton_out) {
  if (mesh_out.empty() && skeleton_out.empty()) {
    return report(invalid_argument_error("nothing to export: give --mesh OUT.vtu and/or --skeleton OUT.vtp"));
  }
  if (Status s = refuse_directories({mesh_out, skeleton_out}); !s.ok()) return report(s);
  Result<api::Rig> rig = api::load_rig(path);
  if (!rig.ok()) return report(rig.status());
  if (!mesh_out.empty()) {
    if (Status s = api::export_mesh_vtu(*rig, mesh_out); !s.ok()) return report(s);
    say("wrote " + mesh_out);
  }
  if (!skeleton_out.empty()) {
    if (Status s = api::export_skeleton_vtp(*rig, skeleton_out); !s.ok()) return report(s);
    say("wrote " + skeleton_out);
  }
  return 0;
}

// Writes the rig at `path` again with what this version keeps in a rig and it lacks (complete_rig), to `out` (the same
// file when empty, replaced whole).
int run_upgrade(const std::string& path, const std::string& out) {
  const std::string to = out.empty() ? path : out;
  if (Status s = refuse_directories({to}); !s.ok()) return report(s);
  Result<api::Rig> rig = api::load_rig(path);
  if (!rig.ok()) return report(rig.status());
  const std::string what = api::missing_from_rig(*rig);
  Result<bool> added = api::complete_rig(*rig, progress_bar());
  if (!added.ok()) return report(added.status().with_context(path));
  if (!*added && out.empty()) {
    say(path + " already holds everything this version keeps in a rig; left as it is");
    return 0;
  }
  if (Status saved = api::save_rig(*rig, to); !saved.ok()) return report(saved);
  say((what.empty() ? std::string("nothing to add; ") : "added " + what + "; ") + "rig " + rig->id() + " written to " +
      to);
  return 0;
}

// posewarp rig build: locally into a file, or on a server.
void add_rig_build(CLI::App* group) {
  auto o = std::make_shared<BuildOptions>();
  CLI::App* cmd = group->add_subcommand("build",
                                        "Build a rig from a segmentation: automatic joints, tetrahedral mesh of the "
                                        "body, Laplace skinning weights and\n"
                                        "centres of rotation, written as one checksummed file");
  cmd->add_option("--labels", o->labels_path,
                  "Label volume (segmentation), or a DICOM SEG made on --ct (a DICOM series)")
      ->required();
  cmd->add_option("--ct", o->ct_path, "CT on the same grid (joins the body mask; kept for posing)");
  cmd->add_option("--body", o->body_path, "Body mask on the same grid (non-zero = body) instead of the computed one");
  cmd->add_option("--label-map", o->label_map_path, "Label map JSON");
  cmd->add_option("--preset", o->preset, "Built-in label map (default: totalsegmentator)")
      ->check(CLI::IsMember(api::preset_names()));
  cmd->add_option("--rig-spec", o->spec_path,
                  "Rig spec JSON: group labels, choose the root, add/move/re-parent joints");
  cmd->add_option("-o,--out", o->out, "Rig file to write (local builds)");
  add_connection_options(cmd, o->connection);
  cmd->add_option(
      "--server", o->connection.server,
      "Build on posewarp-server at HOST:PORT instead: uploads the volumes, shows the build's progress and "
      "prints the rig id (default parameters; the mesh options here apply to local builds)");
  cmd->add_option("--name", o->name, "Name of the rig on the server (default: the labels' file name)");
  auto& p = o->params;
  cmd->add_option("--contact-distance", p.skeleton.contact_distance_mm, "Bone contact distance, mm (0 = 3.5 voxels)")
      ->capture_default_str();
  cmd->add_option("--facet-size", p.mesh.facet_size_mm, "Largest boundary triangle, mm")->capture_default_str();
  cmd->add_option("--facet-distance", p.mesh.facet_distance_mm, "Largest boundary approximation error, mm")
      ->capture_default_str();
  cmd->add_option("--bone-size", p.mesh.bone_cell_size_mm, "Largest tet size in and near bone, mm")
      ->capture_default_str();
  cmd->add_option("--soft-size", p.mesh.soft_cell_size_mm, "Largest tet size deep in soft tissue, mm")
      ->capture_default_str();
  cmd->add_option("--joint-size", p.mesh.joint_cell_size_mm,
                  "Largest tet size within --joint-radius of each joint's centre (not the spine's plane joints), mm (0: no finer mesh "
                  "there; finer tets let the fem method bend the tissue of a joint over several layers)")
      ->check(CLI::Range(0.0, 1000.0));
  cmd->add_option("--joint-radius", p.mesh.joint_radius_mm, "Reach of --joint-size around each joint centre, mm")
      ->check(CLI::Range(0.0, 1000.0))
      ->capture_default_str();
  cmd->add_flag("!--keep-bone-gaps", p.mesh.split_bone_gaps,
                "Leave the tet edges between two bones (a joint's gap) whole, as rigs built before 2026-11-28 did; by "
                "default each is split at its midpoint, so that the fem method can move the gap's tissue instead of "
                "folding it where the bones hold every corner");
  cmd->add_flag("!--weld-joint-gaps", p.mesh.slide_joint_gaps,
                "Leave each joint's gap whole, as rigs built before 2026-11-29 did; by default it is cut along its "
                "middle (after the weights), so that the fem method slides its two sides past each other instead of "
                "folding the tissue between them (cor, dqs and lbs move both sides alike)");
  cmd->add_option("--voxel-budget", p.mesh.voxel_budget, "Mesher grid voxels before downsampling")
      ->capture_default_str();
  cmd->add_flag("--sequential", o->sequential, "Sequential, seeded mesher: the same inputs give the same mesh");
  cmd->add_option("--seed", p.mesh.seed, "Seed of the sequential mesher")->capture_default_str();
  cmd->add_option("--influences", p.weights.max_influences, "Bones kept per vertex")->capture_default_str();
  cmd->add_flag("--fail-on-islands", o->islands_fail, "Fail on soft tissue without bone instead of attaching it");
  cmd->add_option("--sigma", p.cor.sigma, "CoR similarity width (paper: < 0.1)")->capture_default_str();
  cmd->callback([o] {
    int code = 0;
    if (!o->connection.server.empty()) {
      if (!o->out.empty() || !o->body_path.empty()) {
        throw CLI::ValidationError("--server",
                                   "a remote build keeps its rig on the server (no -o) and takes no "
                                   "--body mask yet");
      }
      code = run_build_remote(
          {o->connection, o->labels_path, o->ct_path, o->label_map_path, o->preset, o->spec_path, o->name});
    } else {
      if (o->out.empty()) throw CLI::RequiredError("-o,--out (or --server)");
      code = run_build(*o);
    }
    if (code != 0) throw CLI::RuntimeError(code);
  });
}

// posewarp rig list: a server's rigs.
void add_rig_list(CLI::App* group) {
  auto connection = std::make_shared<Connection>();
  CLI::App* cmd = group->add_subcommand("list", "The rigs a posewarp-server holds: id, name, size, created");
  cmd->add_option("--server", connection->server, "posewarp-server at HOST:PORT")->required();
  add_connection_options(cmd, *connection);
  cmd->callback([connection] {
    if (int code = run_list_remote(*connection); code != 0) throw CLI::RuntimeError(code);
  });
}

// posewarp rig info: a rig file's or a server's rig's joints, segments, mesh and provenance.
void add_rig_info(CLI::App* group) {
  auto path = std::make_shared<std::string>();
  auto as_json = std::make_shared<bool>(false);
  auto connection = std::make_shared<Connection>();
  CLI::App* cmd =
      group->add_subcommand("info", "Joints, segments, mesh size, weight statistics, timings, provenance");
  cmd->add_option("rig", *path, "Rig file (or, with --server, a rig id there)")->required();
  cmd->add_flag("--json", *as_json, "Machine-readable output");
  cmd->add_option("--server", connection->server, "Describe a rig that posewarp-server at HOST:PORT holds");
  add_connection_options(cmd, *connection);
  cmd->callback([path, as_json, connection] {
    const int code =
        connection->server.empty() ? run_info(*path, *as_json) : run_info_remote(*connection, *path, *as_json);
    if (code != 0) throw CLI::RuntimeError(code);
  });
}

// posewarp rig upgrade: a rig from an earlier version, completed.
void add_rig_upgrade(CLI::App* group) {
  auto path = std::make_shared<std::string>();
  auto out = std::make_shared<std::string>();
  CLI::App* cmd = group->add_subcommand(
      "upgrade",
      "Write a rig from an earlier posewarp again with what this version keeps in a rig and it lacks (the engine's "
      "per-voxel tables and its summary of them, the mesh's skin vertices), made from the rig itself, so that opening "
      "it and its first pose "
      "compute nothing; its mesh, weights and volumes stay as they are (no rebuild, the same rig id)");
  cmd->add_option("rig", *path, "Rig file")->required();
  cmd->add_option("-o,--out", *out, "Where to write it (default: replace the rig file, atomically)");
  cmd->callback([path, out] {
    if (int code = run_upgrade(*path, *out); code != 0) throw CLI::RuntimeError(code);
  });
}

// posewarp rig delete: a rig on a server.
void add_rig_delete(CLI::App* group) {
  auto id = std::make_shared<std::string>();
  auto connection = std::make_shared<Connection>();
  CLI::App* cmd = group->add_subcommand("delete", "Delete a rig from posewarp-server (its file and index row)");
  cmd->add_option("rig", *id, "Rig id (64 hex digits)")->required();
  cmd->add_option("--server", connection->server, "posewarp-server at HOST:PORT")->required();
  add_connection_options(cmd, *connection);
  cmd->callback([id, connection] {
    if (int code = run_delete_remote(*connection, *id); code != 0) throw CLI::RuntimeError(code);
  });
}

// posewarp rig export: the tet mesh and skeleton for ParaView, or a server's rig file.
void add_rig_export(CLI::App* group) {
  auto path = std::make_shared<std::string>();
  auto mesh_out = std::make_shared<std::string>();
  auto skeleton_out = std::make_shared<std::string>();
  auto rig_out = std::make_shared<std::string>();
  auto connection = std::make_shared<Connection>();
  CLI::App* cmd = group->add_subcommand("export",
                                        "Write the tet mesh (.vtu, with weights) and skeleton (.vtp) for "
                                        "ParaView; with --server, download the rig file (--rig-out)");
  cmd->add_option("rig", *path, "Rig file (or, with --server, a rig id there)")->required();
  cmd->add_option("--mesh", *mesh_out, "Tet mesh with labels and per-bone weights (.vtu)");
  cmd->add_option("--skeleton", *skeleton_out, "Skeleton as lines (.vtp)");
  cmd->add_option("--rig-out", *rig_out, "With --server: where to write the downloaded rig file");
  cmd->add_option("--server", connection->server, "posewarp-server at HOST:PORT holding the rig");
  add_connection_options(cmd, *connection);
  cmd->callback([path, mesh_out, skeleton_out, rig_out, connection] {
    int code = 0;
    if (!connection->server.empty()) {
      if (rig_out->empty() || !mesh_out->empty() || !skeleton_out->empty()) {
        throw CLI::ValidationError("--server",
                                   "a remote export downloads the rig file: give --rig-out F (then "
                                   "`posewarp rig export F --mesh ...` locally)");
      }
      code = run_export_remote(*connection, *path, *rig_out);
    } else {
      code = run_export(*path, *mesh_out, *skeleton_out);
    }
    if (code != 0) throw CLI::RuntimeError(code);
  });
}

}  // namespace

void add_rig_commands(CLI::App& app) {
  CLI::App* group = app.add_subcommand(
      "rig", "Build a rig once per study (skeleton, tet mesh, weights, centres), inspect and export it");
  group->require_subcommand(1);
  add_rig_build(group);
  add_rig_list(group);
  add_rig_info(group);
  add_rig_upgrade(group);
  add_rig_delete(group);
  add_rig_export(group);
}

}  // namespace posewarp::cli
