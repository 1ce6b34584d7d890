// posewarp match: the pose that brings a rig's bones onto the bones of another scan (api::match_posture), written
// as a pose file any pose command takes, with a table of the residual per bone and an optional JSON report; then,
// when asked, the rig posed by it on the target's grid with its fields and quality report. Locally or on
// posewarp-server (MatchPosture, then Pose).
#include <cstdio>
#include <filesystem>

#include "cli_support.h"
#include "posewarp/api/dicom.h"
#include "posewarp/api/match.h"
#include "posewarp/api/pose_engine.h"
#include "posewarp/api/rig_file.h"
#include "remote.h"

namespace posewarp::cli {
namespace {

namespace fs = std::filesystem;

struct MatchCommandOptions {
  std::string rig_path, target_labels, target_ct, standard, preset, label_map_path, pose_out, report_out;
  // The rig posed by the pose found, on the target's grid (a standard posture: grown to hold the body).
  std::string labels_out, ct_out, field_out, pose_report_out, method = "cor";
  bool free_hinges = false, beyond_range = false;
  Connection connection;  // match on posewarp-server; rig_path is then a rig id
};

bool wants_posed(const MatchCommandOptions& o) {
  return !o.labels_out.empty() || !o.ct_out.empty() || !o.field_out.empty() || !o.pose_report_out.empty();
}

// The pose request for the outputs asked for: on `grid` when given, else grown to hold the posed body.
Result<api::PoseRequest> posed_request(const MatchCommandOptions& o, const Pose& pose, const ImageGeometry* grid) {
  api::PoseRequest request;
  request.pose = pose;
  POSEWARP_ASSIGN_OR_RETURN(request.method, api::method_from_name(o.method));
  request.grid = grid != nullptr ? api::GridPolicy::kGiven : api::GridPolicy::kGrow;
  if (grid != nullptr) request.given_grid = *grid;
  request.want_labels = !o.labels_out.empty();
  request.want_ct = !o.ct_out.empty();
  request.want_fields = !o.field_out.empty();
  request.limits.max_voxels = global_options().max_voxels;
  return request;
}

// The rig posed in this process.
int write_posed(const MatchCommandOptions& o, api::Rig rig, const Pose& pose, const ImageGeometry* grid) {
  if (!wants_posed(o)) return 0;
  if (!o.ct_out.empty() && !rig.ct) {
    return report(
        failed_precondition_error("the rig holds no CT (it was built from labels alone): leave out --ct-out"));
  }
  Result<api::PoseRequest> request = posed_request(o, pose, grid);
  if (!request.ok()) return report(request.status());
  const ImageGeometry source = rig.source_geometry;
  Result<api::PoseEngine> engine = api::PoseEngine::create(std::move(rig));
  if (!engine.ok()) return report(engine.status());
  Result<api::PoseResult> posed = engine->pose(*request, progress_bar());
  if (!posed.ok()) return report(posed.status());
  for (const std::string& warning : posed->report.warnings) say("warning: " + warning);
  const Status written = write_outputs(*posed, api::report_to_json(posed->report), o.labels_out, o.ct_out, o.field_out,
                                       o.pose_report_out, source);
  return written.ok() ? 0 : report(written);
}

// The rig posed on the server.
int write_posed_remotely(const MatchCommandOptions& o, const Pose& pose, const ImageGeometry* grid) {
  if (!wants_posed(o)) return 0;
  Result<api::PoseRequest> request = posed_request(o, pose, grid);
  if (!request.ok()) return report(request.status());
  Result<RemotePoser> poser = RemotePoser::open(o.connection, o.rig_path);
  if (!poser.ok()) return report(poser.status());
  Result<RemotePoseResult> answer = poser->pose(*request);
  if (!answer.ok()) return report(answer.status());
  for (const std::string& warning : answer->warnings) say("warning: " + warning);
  const Status written = write_outputs(answer->result, answer->report_json, o.labels_out, o.ct_out, o.field_out,
                                       o.pose_report_out, answer->source_grid);
  return written.ok() ? 0 : report(written);
}

int write_pose(const MatchCommandOptions& o, const Pose& pose) {
  if (Status s = api::write_file_atomically(o.pose_out, api::pose_to_json(pose), "pose"); !s.ok()) return report(s);
  return 0;
}

void print_standard(const Pose& pose) {
  char line[160];
  for (const JointRotation& j : pose.joints) {
    std::snprintf(line, sizeof line, "%-22s flexion %6.1f  abduction %6.1f  rotation %6.1f", j.joint.c_str(),
                  j.angles_deg->x(), j.angles_deg->y(), j.angles_deg->z());
    say(line);
  }
}

// The table of the residual per bone, and the notes on ranges and names.
void print_match(const api::PostureMatch& match, const std::string& pose_out) {
  char line[256];
  say("segment               joint                   flexion abduction rotation   mean mm  max mm   Dice");
  for (const api::SegmentMatch& s : match.match.segments) {
    if (!s.matched) {
      say(s.segment + ": skipped, " + s.skipped);
      continue;
    }
    std::snprintf(line, sizeof line, "%-21s %-22s %8.1f %9.1f %8.1f %9.2f %7.2f %6.3f", s.segment.c_str(),
                  s.joint.empty() ? "(root)" : s.joint.c_str(), s.angles_deg.x(), s.angles_deg.y(), s.angles_deg.z(),
                  s.mean_distance_mm, s.max_distance_mm, s.dice);
    say(line);
  }
  for (const api::SegmentMatch& s : match.match.segments) {
    if (!s.held_at_range.empty()) {
      say("note: " + s.joint + ": " + s.held_at_range +
          ", the end of its range (anatomy's: --beyond-range lets it follow the target; a hinge's 5 degrees off its "
          "axis: --free-hinges)");
    }
    if (!s.beyond_range.empty()) {
      say("note: " + s.joint + ": " + s.beyond_range + ", beyond the range measured on the rig's study");
    }
  }
  for (const std::string& label : match.unnamed_labels) say("note: the target's label map has no '" + label + "'");
  std::snprintf(line, sizeof line, "wrote %s (%.2f s)", pose_out.c_str(), match.seconds);
  say(line);
}

// The target's labels with the map naming them: a label volume named by `map`, or a DICOM SEG on its CT series
// (its segments' names relabel `map`).
struct Target {
  LabelVolume labels;
  api::LabelMap map;
  std::string file_name;  // what an upload calls it
};

Result<Target> read_target(const MatchCommandOptions& o, api::LabelMap map) {
  Target target;
  if (api::is_dicom_file(o.target_labels)) {
    if (o.target_ct.empty()) {
      return invalid_argument_error("'" + o.target_labels +
                                    "' is a DICOM file: give --target-ct DIR, the CT series the segmentation was made "
                                    "on");
    }
    POSEWARP_ASSIGN_OR_RETURN(api::DicomStudy study, api::read_dicom_study(o.target_ct, o.target_labels, map));
    for (const std::string& w : study.warnings) say("warning: " + w);
    target.labels = std::move(study.labels);
    target.map = std::move(study.label_map);
    target.file_name = fs::path(o.target_labels).stem().string() + ".nii.gz";
    return target;
  }
  POSEWARP_ASSIGN_OR_RETURN(target.labels, api::read_label_volume(o.target_labels, read_options()));
  target.map = std::move(map);
  target.file_name = o.target_labels;
  return target;
}

// The target's names given by --label-map or --preset, if either.
Result<std::optional<api::LabelMap>> given_map(const MatchCommandOptions& o) {
  if (o.label_map_path.empty() && o.preset.empty()) return std::optional<api::LabelMap>();
  POSEWARP_ASSIGN_OR_RETURN(api::LabelMap map,
                            load_label_map(o.label_map_path, o.label_map_path.empty() ? o.preset : ""));
  return std::optional<api::LabelMap>(std::move(map));
}

// On the server: the target uploaded (a label file as it is; a DICOM study read here and sent as NIfTI with its
// SEG's names), MatchPosture, then Pose for the outputs.
int run_match_remotely(const MatchCommandOptions& o) {
  RemoteMatchRequest request;
  request.rig_id = o.rig_path;
  request.standard = o.standard;
  request.free_hinges = o.free_hinges;
  request.beyond_range = o.beyond_range;
  Result<std::optional<api::LabelMap>> map = given_map(o);
  if (!map.ok()) return report(map.status());
  if (!o.target_labels.empty()) {
    if (api::is_dicom_file(o.target_labels)) {
      Result<api::LabelMap> names =
          map->has_value() ? Result<api::LabelMap>(**map) : api::preset_by_name("totalsegmentator");
      if (!names.ok()) return report(names.status());
      Result<Target> target = read_target(o, *names);
      if (!target.ok()) return report(target.status());
      Result<std::string> bytes = api::encode_volume(target->labels, api::VolumeFormat::kNifti, true);
      if (!bytes.ok()) return report(bytes.status());
      request.target = RemoteVolumeFile{target->file_name, std::move(bytes).value()};
      request.label_map_json = api::label_map_to_json(target->map);
    } else {
      Result<std::string> bytes = api::read_text_input(o.target_labels, "volume", int64_t{8} << 30);
      if (!bytes.ok()) return report(bytes.status());
      request.target = RemoteVolumeFile{o.target_labels, std::move(bytes).value()};
      if (!o.label_map_path.empty()) request.label_map_json = api::label_map_to_json(**map);
      request.preset = o.label_map_path.empty() ? o.preset : "";
    }
  }
  Result<RemoteMatch> answer = match_remote(o.connection, request);
  if (!answer.ok()) return report(answer.status());
  const Pose& pose = answer->match.match.pose;
  if (int code = write_pose(o, pose); code != 0) return code;
  if (o.standard.empty()) {
    if (!o.report_out.empty()) {
      if (Status s = api::write_file_atomically(o.report_out, answer->report_json, "match report"); !s.ok()) {
        return report(s);
      }
    }
    print_match(answer->match, o.pose_out);
    return write_posed_remotely(o, pose, &answer->target_grid);
  }
  print_standard(pose);
  say("wrote " + o.pose_out);
  return write_posed_remotely(o, pose, nullptr);
}

// --standard: a named posture instead of a target.
int run_standard(const MatchCommandOptions& o, api::Rig rig) {
  Result<Pose> pose = api::standard_posture(rig, o.standard);
  if (!pose.ok()) return report(pose.status());
  if (int code = write_pose(o, *pose); code != 0) return code;
  print_standard(*pose);
  say("wrote " + o.pose_out);
  return write_posed(o, std::move(rig), *pose, nullptr);
}

int run_match(const MatchCommandOptions& o) {
  std::vector<std::string> outputs{o.pose_out, o.report_out, o.labels_out, o.ct_out, o.field_out, o.pose_report_out};
  if (!o.field_out.empty()) outputs.push_back(forward_field_path(o.field_out));
  if (Status s = refuse_overwriting_inputs(outputs, {o.rig_path, o.target_labels, o.label_map_path, o.target_ct});
      !s.ok()) {
    return report(s);
  }
  if (Status s = check_output_files(outputs); !s.ok()) return report(s);
  if (o.target_labels.empty() == o.standard.empty()) {
    return report(invalid_argument_error("give either --target-labels (another scan to match) or --standard NAME (a "
                                         "standard posture)"));
  }
  if (Result<api::Method> m = api::method_from_name(o.method); !m.ok()) return report(m.status());
  if (!o.connection.server.empty()) return run_match_remotely(o);
  Result<api::Rig> rig = api::load_rig(o.rig_path);
  if (!rig.ok()) return report(rig.status());
  if (!o.standard.empty()) return run_standard(o, std::move(*rig));
  // The target's names: its own map or preset, else the rig's (the same values).
  Result<std::optional<api::LabelMap>> map = given_map(o);
  if (!map.ok()) return report(map.status());
  Result<Target> target = read_target(o, map->has_value() ? **map : rig->label_map);
  if (!target.ok()) return report(target.status());
  api::MatchOptions options;
  options.constrain_hinges = !o.free_hinges;
  options.anatomical_ranges = !o.beyond_range;
  Result<api::PostureMatch> match = api::match_posture(*rig, target->labels, target->map, options);
  if (!match.ok()) return report(match.status());
  if (int code = write_pose(o, match->match.pose); code != 0) return code;
  if (!o.report_out.empty()) {
    if (Status s = api::write_file_atomically(o.report_out, api::posture_match_to_json(*match), "match report");
        !s.ok()) {
      return report(s);
    }
  }
  print_match(*match, o.pose_out);
  // The rig posed by what was found, on the target's grid: voxel for voxel comparable with the target scan.
  return write_posed(o, std::move(*rig), match->match.pose, &target->labels.geometry());
}

}  // namespace

void add_match_command(CLI::App& app) {
  auto o = std::make_shared<MatchCommandOptions>();
  CLI::App* cmd = app.add_subcommand(
      "match",
      "Find the pose that brings the rig's bones onto the same bones in another scan's labels (per-bone rigid "
      "alignment from the root outwards: the root moves and turns, every other bone turns about its joint, a hinge "
      "about its axis give or take 5 degrees, the limbs' joints within anatomy's ranges of motion), and write it as a "
      "pose file; or write "
      "a standard posture of the rig");
  cmd->add_option("rig", o->rig_path, "Rig file (posewarp rig build), or with --server a rig id")->required();
  cmd->add_option("--target-labels", o->target_labels,
                  "The other scan's labels: a label volume (NIfTI, NRRD, ...) or a DICOM SEG (binary or label map)");
  cmd->add_option("--standard", o->standard,
                  "Instead of a target, a standard posture: limbs-straight or supine-arms-down (arms along the body, "
                  "legs straight), arms-up (arms straight over the head, raised through the side; legs straight)");
  cmd->add_option("--target-ct", o->target_ct, "With a DICOM SEG: the directory of the CT series it was made on");
  cmd->add_option("--preset", o->preset, "Built-in label map naming the target's labels (default: the rig's map)");
  cmd->add_option("--label-map", o->label_map_path, "A label map of one's own naming the target's labels");
  cmd->add_option("-o,--pose-out", o->pose_out, "The pose found (pose JSON: anatomical angles per joint)")->required();
  cmd->add_option("--report", o->report_out, "Residual per bone (surface distance, Dice) and the root's motion, JSON");
  cmd->add_option("--labels-out", o->labels_out,
                  "The rig's labels posed by the pose found, on the target's grid (--standard: grown to hold them)");
  cmd->add_option("--ct-out", o->ct_out, "The rig's CT posed the same way");
  cmd->add_option("--field-out", o->field_out,
                  "The displacement fields of that pose: inverse on the target's grid, forward beside it as *_forward");
  cmd->add_option("--pose-report", o->pose_report_out,
                  "The quality report of that pose (soft tissue near each moved joint, bones, folds), as posewarp "
                  "pose --report writes it");
  cmd->add_option("--method", o->method, "How the tissue moves in that pose: cor, dqs, lbs or fem")
      ->capture_default_str();
  cmd->add_flag("--free-hinges", o->free_hinges,
                "Let hinges (knee, elbow, ankle) turn every way (by default each turns about its axis give or take 5 "
                "degrees, what fitting the axis on a scan leaves open)");
  cmd->add_flag("--beyond-range", o->beyond_range,
                "Let the limbs' joints (shoulder, elbow, wrist, hip, knee, ankle) turn past anatomy's range of motion "
                "(by default each is held within it, counted from the rig's own rest posture, and the table notes "
                "where)");
  cmd->add_option("--server", o->connection.server,
                  "Match on posewarp-server at HOST:PORT: RIG is then a rig id there (the target is uploaded); the "
                  "same files are written here");
  add_connection_options(cmd, o->connection);
  cmd->callback([o] {
    if (int code = run_match(*o); code != 0) throw CLI::RuntimeError(code);
  });
}

}  // namespace posewarp::cli
