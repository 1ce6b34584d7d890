// Status reporting, progress bars and global options for the CLI.
#include "cli_support.h"

#include <nlohmann/json.hpp>

#include <filesystem>

#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <mutex>

namespace posewarp::cli {

GlobalOptions& global_options() {
  static GlobalOptions options;
  return options;
}

api::ReadOptions read_options() {
  api::ReadOptions options;
  options.max_voxels = global_options().max_voxels;
  return options;
}

Result<api::LabelMap> load_label_map(const std::string& path, const std::string& preset, std::string_view own_map) {
  Result<api::LabelMap> map = api::load_label_map(path, preset);
  if (map.ok() || !path.empty() || preset.empty()) return map;
  return Status(map.status().code(), map.status().message() + "; to give your own, " + std::string(own_map));
}

int report(const Status& status) {
  if (status.ok()) return 0;
  std::cerr << "error: " << status.message() << " [" << status_code_name(status.code()) << "]\n";
  return exit_code(status.code());
}

Status check_output_files(const std::vector<std::string>& outputs) {
  namespace fs = std::filesystem;
  for (const std::string& output : outputs) {
    if (output.empty()) continue;
    const fs::path parent = fs::path(output).parent_path();
    const std::string dir = parent.empty() ? "." : parent.string();
    std::error_code ec;
    const fs::file_status status = fs::status(dir, ec);
    std::string why;
    if (!fs::exists(status)) {
      why = "the directory does not exist (create it first)";
    } else if (!fs::is_directory(status)) {
      why = "it is not a directory";
    } else if (::access(dir.c_str(), W_OK | X_OK) != 0) {
      why = "the directory is not writable (" + std::string(std::strerror(errno)) + ")";
    }
    if (!why.empty()) {
      return invalid_argument_error("cannot write '" + output + "' in '" + dir + "': " + why);
    }
  }
  return ok_status();
}

Status refuse_directories(const std::vector<std::string>& files) {
  for (const std::string& file : files) {
    std::error_code ec;
    if (!file.empty() && std::filesystem::is_directory(file, ec)) {
      return invalid_argument_error("cannot write '" + file + "': it is a directory; name a file to write (e.g. '" +
                                    (std::filesystem::path(file) / "<name>").string() + "')");
    }
  }
  return ok_status();
}

Status refuse_overwriting_inputs(const std::vector<std::string>& outputs, const std::vector<std::string>& inputs) {
  namespace fs = std::filesystem;
  for (const std::string& output : outputs) {
    if (output.empty()) continue;
    std::error_code ec;
    const fs::path out = fs::weakly_canonical(output, ec);
    for (const std::string& input : inputs) {
      if (input.empty()) continue;
      std::error_code ec_in;
      const bool same =
          fs::exists(output, ec) ? fs::equivalent(output, input, ec_in) : fs::weakly_canonical(input, ec_in) == out;
      if (same && !ec_in) {
        return invalid_argument_error("the output '" + output + "' is the input '" + input +
                                      "'; writing it would destroy the input. Choose another output path");
      }
    }
  }
  return ok_status();
}

int exit_code(StatusCode code) {
  // The one table (README "Exit codes"): 2 for bad input or usage (a damaged file included), 3 for resource
  // limits, 1 for everything else (an internal error, a cancelled or timed-out run).
  switch (code) {
    case StatusCode::kOk: return 0;
    case StatusCode::kInvalidArgument:
    case StatusCode::kNotFound:
    case StatusCode::kAlreadyExists:
    case StatusCode::kFailedPrecondition:
    case StatusCode::kOutOfRange:
    case StatusCode::kPermissionDenied:
    case StatusCode::kDataLoss: return 2;
    case StatusCode::kResourceExhausted: return 3;
    default: return 1;
  }
}

ProgressHooks progress_bar() {
  ProgressHooks hooks;
  if (global_options().quiet) return hooks;
  const bool tty = ::isatty(STDERR_FILENO) != 0;
  hooks.on_progress = [tty](std::string_view stage, double fraction) {
    if (tty) {
      constexpr int kWidth = 30;
      const int filled = static_cast<int>(fraction * kWidth);
      std::fprintf(stderr, "\r%-14.*s [%s%s] %3d%%", static_cast<int>(stage.size()), stage.data(),
                   std::string(static_cast<size_t>(filled), '#').c_str(),
                   std::string(static_cast<size_t>(kWidth - filled), '.').c_str(), static_cast<int>(fraction * 100));
      if (fraction >= 1.0) std::fprintf(stderr, "\n");
    } else if (fraction >= 1.0) {
      std::fprintf(stderr, "%.*s: done\n", static_cast<int>(stage.size()), stage.data());
    }
    std::fflush(stderr);
  };
  return hooks;
}

void say(const std::string& line) {
  static std::mutex mutex;  // a batch's workers say things at once: whole lines each
  if (global_options().quiet) return;
  std::lock_guard<std::mutex> lock(mutex);
  std::cout << line << '\n';
}

std::string joint_range_line(const nlohmann::json& joint) {
  if (!joint.contains("range_deg")) return "";
  std::string line = "      turns before its bones meet another bone (1 ml):";
  for (const auto& [motion, bounds] : joint["range_deg"].items()) {
    const nlohmann::json& stopped = joint["range_stopped_by_bone"][motion];
    char text[160];
    std::snprintf(text, sizeof text, " %s %s%.0f to %s+%.0f deg,", motion.c_str(),
                  stopped[0].get<bool>() ? "" : "beyond ", bounds[0].get<double>(),
                  stopped[1].get<bool>() ? "" : "beyond ", bounds[1].get<double>());
    line += text;
  }
  line.pop_back();
  return line;
}

// "<stem>_forward<ext>" beside a field path (keeps .nii.gz together).
std::string forward_field_path(const std::string& path) {
  for (const std::string ext : {".nii.gz", ".nii", ".nrrd", ".mha"}) {
    if (path.size() > ext.size() && path.compare(path.size() - ext.size(), ext.size(), ext) == 0) {
      return path.substr(0, path.size() - ext.size()) + "_forward" + ext;
    }
  }
  return path + "_forward";
}

// The files of a pose, local or answered by the server (report_json: the report as written).
Status write_outputs(const api::PoseResult& result, const std::string& report_json, const std::string& labels_out,
                     const std::string& ct_out, const std::string& field_out, const std::string& report_out,
                     const ImageGeometry& source) {
  if (!labels_out.empty() && result.labels) {
    POSEWARP_RETURN_IF_ERROR(api::write_volume(*result.labels, labels_out));
    say("wrote " + labels_out);
  }
  if (!ct_out.empty() && result.ct) {
    POSEWARP_RETURN_IF_ERROR(api::write_volume(*result.ct, ct_out));
    say("wrote " + ct_out);
  }
  if (!field_out.empty()) {
    POSEWARP_RETURN_IF_ERROR(api::write_displacement_field(result.inverse_field, result.output_grid, field_out));
    const std::string forward = forward_field_path(field_out);
    POSEWARP_RETURN_IF_ERROR(api::write_displacement_field(result.forward_field, source, forward));
    say("wrote " + field_out + " (inverse, output grid) and " + forward + " (forward, input grid)");
  }
  if (!report_out.empty()) {
    POSEWARP_RETURN_IF_ERROR(api::write_file_atomically(report_out, report_json, "report"));
    say("wrote " + report_out);
  }
  return ok_status();
}

}  // namespace posewarp::cli
