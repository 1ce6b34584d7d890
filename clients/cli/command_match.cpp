// posewarp match: the pose that brings a rig's bones onto the bones of another scan (api::match_posture), written
// as a pose file any pose command takes, with a table of the residual per bone and an optional JSON report.
#include <cstdio>

#include "cli_support.h"
#include "posewarp/api/dicom.h"
#include "posewarp/api/match.h"
#include "posewarp/api/pose_engine.h"
#include "posewarp/api/rig_file.h"

namespace posewarp::cli {
namespace {

struct MatchCommandOptions {
  std::string rig_path, target_labels, target_ct, standard, preset, label_map_path, pose_out, report_out;
  std::string labels_out, ct_out;  // the rig posed by the pose found, on the target's grid
  bool free_hinges = false;
};

// The rig posed on its own grid, grown to hold the posed body, or on `grid` when given.
int write_posed(const MatchCommandOptions& o, api::Rig rig, const Pose& pose, const ImageGeometry* grid) {
  if (o.labels_out.empty() && o.ct_out.empty()) return 0;
  if (!o.ct_out.empty() && !rig.ct) {
    return report(failed_precondition_error("the rig holds no CT (it was built from labels alone): leave out --ct-out"));
  }
  Result<api::PoseEngine> engine = api::PoseEngine::create(std::move(rig));
  if (!engine.ok()) return report(engine.status());
  api::PoseRequest request;
  request.pose = pose;
  request.grid = grid != nullptr ? api::GridPolicy::kGiven : api::GridPolicy::kGrow;
  if (grid != nullptr) request.given_grid = *grid;
  request.want_labels = !o.labels_out.empty();
  request.want_ct = !o.ct_out.empty();
  Result<api::PoseResult> posed = engine->pose(request, progress_bar());
  if (!posed.ok()) return report(posed.status());
  if (posed->labels) {
    if (Status s = api::write_volume(*posed->labels, o.labels_out); !s.ok()) return report(s);
    say("wrote " + o.labels_out);
  }
  if (posed->ct) {
    if (Status s = api::write_volume(*posed->ct, o.ct_out); !s.ok()) return report(s);
    say("wrote " + o.ct_out);
  }
  return 0;
}

// --standard: a named posture instead of a target.
int run_standard(const MatchCommandOptions& o, api::Rig rig) {
  Result<Pose> pose = api::standard_posture(rig, o.standard);
  if (!pose.ok()) return report(pose.status());
  if (Status s = api::write_file_atomically(o.pose_out, api::pose_to_json(*pose), "pose"); !s.ok()) return report(s);
  char line[160];
  for (const JointRotation& j : pose->joints) {
    std::snprintf(line, sizeof line, "%-22s flexion %6.1f  abduction %6.1f  rotation %6.1f", j.joint.c_str(),
                  j.angles_deg->x(), j.angles_deg->y(), j.angles_deg->z());
    say(line);
  }
  say("wrote " + o.pose_out);
  return write_posed(o, std::move(rig), *pose, nullptr);
}

int run_match(const MatchCommandOptions& o) {
  const std::vector<std::string> outputs{o.pose_out, o.report_out, o.labels_out, o.ct_out};
  if (Status s = refuse_overwriting_inputs(outputs, {o.rig_path, o.target_labels, o.label_map_path, o.target_ct});
      !s.ok()) {
    return report(s);
  }
  if (Status s = check_output_files(outputs); !s.ok()) return report(s);
  if (o.target_labels.empty() == o.standard.empty()) {
    return report(invalid_argument_error("give either --target-labels (another scan to match) or --standard NAME (a "
                                         "standard posture)"));
  }
  Result<api::Rig> rig = api::load_rig(o.rig_path);
  if (!rig.ok()) return report(rig.status());
  if (!o.standard.empty()) return run_standard(o, std::move(*rig));
  // The target's names: its own map or preset, else the rig's (the same values).
  api::LabelMap map = rig->label_map;
  if (!o.label_map_path.empty() || !o.preset.empty()) {
    Result<api::LabelMap> given = load_label_map(o.label_map_path, o.label_map_path.empty() ? o.preset : "");
    if (!given.ok()) return report(given.status());
    map = std::move(*given);
  }
  // A DICOM SEG lies on the CT series it was made on; its segments' names relabel the map.
  LabelVolume target;
  if (api::is_dicom_file(o.target_labels)) {
    if (o.target_ct.empty()) {
      return report(invalid_argument_error("'" + o.target_labels +
                                           "' is a DICOM file: give --target-ct DIR, the CT series the segmentation "
                                           "was made on"));
    }
    Result<api::DicomStudy> study = api::read_dicom_study(o.target_ct, o.target_labels, map);
    if (!study.ok()) return report(study.status());
    for (const std::string& w : study->warnings) say("warning: " + w);
    target = std::move(study->labels);
    map = std::move(study->label_map);
  } else {
    Result<LabelVolume> read = api::read_label_volume(o.target_labels, read_options());
    if (!read.ok()) return report(read.status());
    target = std::move(*read);
  }
  api::MatchOptions options;
  options.constrain_hinges = !o.free_hinges;
  Result<api::PostureMatch> match = api::match_posture(*rig, target, map, options);
  if (!match.ok()) return report(match.status());
  if (Status s = api::write_file_atomically(o.pose_out, api::pose_to_json(match->match.pose), "pose"); !s.ok()) {
    return report(s);
  }
  if (!o.report_out.empty()) {
    if (Status s = api::write_file_atomically(o.report_out, api::posture_match_to_json(*match), "match report");
        !s.ok()) {
      return report(s);
    }
  }
  char line[256];
  say("segment               joint                   flexion abduction rotation   mean mm  max mm   Dice");
  for (const api::SegmentMatch& s : match->match.segments) {
    if (!s.matched) {
      say(s.segment + ": skipped, " + s.skipped);
      continue;
    }
    std::snprintf(line, sizeof line, "%-21s %-22s %8.1f %9.1f %8.1f %9.2f %7.2f %6.3f", s.segment.c_str(),
                  s.joint.empty() ? "(root)" : s.joint.c_str(), s.angles_deg.x(), s.angles_deg.y(), s.angles_deg.z(),
                  s.mean_distance_mm, s.max_distance_mm, s.dice);
    say(line);
  }
  for (const api::SegmentMatch& s : match->match.segments) {
    if (!s.beyond_range.empty()) {
      say("note: " + s.joint + ": " + s.beyond_range + ", beyond the range measured on the rig's study");
    }
  }
  for (const std::string& label : match->unnamed_labels) say("note: the target's label map has no '" + label + "'");
  std::snprintf(line, sizeof line, "wrote %s (%.2f s)", o.pose_out.c_str(), match->seconds);
  say(line);
  // The rig posed by what was found, on the target's grid: voxel for voxel comparable with the target scan.
  return write_posed(o, std::move(*rig), match->match.pose, &target.geometry());
}

}  // namespace

void add_match_command(CLI::App& app) {
  auto o = std::make_shared<MatchCommandOptions>();
  CLI::App* cmd = app.add_subcommand(
      "match",
      "Find the pose that brings the rig's bones onto the same bones in another scan's labels (per-bone rigid "
      "alignment from the root outwards: the root moves and turns, every other bone turns about its joint, a hinge "
      "about its axis), and write it as a pose file");
  cmd->add_option("rig", o->rig_path, "Rig file (posewarp rig build)")->required();
  cmd->add_option("--target-labels", o->target_labels,
                  "The other scan's labels: a label volume (NIfTI, NRRD, ...) or a DICOM SEG (binary or label map)");
  cmd->add_option("--standard", o->standard,
                  "Instead of a target, a standard posture: limbs-straight (arms along the body, legs straight)");
  cmd->add_option("--target-ct", o->target_ct, "With a DICOM SEG: the directory of the CT series it was made on");
  cmd->add_option("--preset", o->preset, "Built-in label map naming the target's labels (default: the rig's map)");
  cmd->add_option("--label-map", o->label_map_path, "A label map of one's own naming the target's labels");
  cmd->add_option("-o,--pose-out", o->pose_out, "The pose found (pose JSON: anatomical angles per joint)")->required();
  cmd->add_option("--report", o->report_out, "Residual per bone (surface distance, Dice) and the root's motion, JSON");
  cmd->add_option("--labels-out", o->labels_out,
                  "The rig's labels posed by the pose found, on the target's grid (--standard: grown to hold them)");
  cmd->add_option("--ct-out", o->ct_out, "The rig's CT posed the same way");
  cmd->add_flag("--free-hinges", o->free_hinges, "Let hinges (knee, elbow, ankle) turn every way, not only flex");
  cmd->callback([o] {
    if (int code = run_match(*o); code != 0) throw CLI::RuntimeError(code);
  });
}

}  // namespace posewarp::cli
