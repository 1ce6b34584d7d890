// Shared pieces of the CLI: status reporting, progress bars, global options.
#pragma once

#include <CLI/CLI.hpp>
#include <nlohmann/json_fwd.hpp>

#include <cstdint>
#include <string>
#include <vector>

#include "posewarp/api/files.h"
#include "posewarp/api/pose_engine.h"
#include "posewarp/api/support.h"

namespace posewarp::cli {

// Options every command shares; filled by CLI11 before a command runs.
struct GlobalOptions {
  int threads = 0;  // 0 = all cores
  int64_t max_voxels = int64_t{1} << 29;
  bool quiet = false;
};

GlobalOptions& global_options();
api::ReadOptions read_options();

// api::load_label_map, with the command line's way to give one's own map (`own_map`, e.g. "pass --label-map FILE.json")
// added to the message when a preset is unknown: the library's message names no flag, since a server's caller has
// none.
Result<api::LabelMap> load_label_map(const std::string& path, const std::string& preset,
                                        std::string_view own_map = "pass --label-map FILE.json");

// Prints "error: <message>" (and the code) to stderr and returns the process exit code for the status.
int report(const Status& status);
// The process exit code of a status code: 0, 2 bad input or usage, 3 over a resource limit, 1 otherwise.
int exit_code(StatusCode code);

// INVALID_ARGUMENT when an output path is, or links to, one of the inputs (checked before any work, so a typo
// never overwrites a study). Empty paths are skipped.
// INVALID_ARGUMENT naming the directory and the reason when an output file could not be created there (missing, not a
// directory, not writable): checked before any work. Empty paths are skipped.
Status check_output_files(const std::vector<std::string>& outputs);
// INVALID_ARGUMENT naming the path when an output that must be a single file (a rig, a report, a VTK export) is an
// existing directory: checked before any work (the final rename would fail only after it). Empty paths are skipped.
Status refuse_directories(const std::vector<std::string>& files);

Status refuse_overwriting_inputs(const std::vector<std::string>& outputs, const std::vector<std::string>& inputs);

// A progress bar on stderr for ProgressHooks; silent when --quiet or stderr is not a terminal (then one line per
// stage at completion).
ProgressHooks progress_bar();

// Prints to stdout unless --quiet.
void say(const std::string& line);

// "<stem>_forward<ext>" beside a field path (keeps .nii.gz together).
std::string forward_field_path(const std::string& path);
// The files of a pose, local or answered by the server (report_json: the report as written; `source`: the forward
// field's grid); each empty path is skipped.
Status write_outputs(const api::PoseResult& result, const std::string& report_json, const std::string& labels_out,
                     const std::string& ct_out, const std::string& field_out, const std::string& report_out,
                     const ImageGeometry& source);

// A joint's range of motion as `rig info` prints it, from its JSON entry (`range_deg`, `range_stopped_by_bone`, as
// local and remote `rig info --json` write them); empty when the entry has none.
std::string joint_range_line(const nlohmann::json& joint);

// Registers the subcommands of each area.
void add_volume_commands(CLI::App& app);
void add_phantom_commands(CLI::App& app);
void add_label_commands(CLI::App& app);
void add_rig_commands(CLI::App& app);
void add_pose_commands(CLI::App& app);
void add_match_command(CLI::App& app);
void add_dicom_commands(CLI::App& app);
void add_batch_command(CLI::App& app);
void add_health_command(CLI::App& app);

}  // namespace posewarp::cli
