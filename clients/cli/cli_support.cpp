// Status reporting, progress bars and global options for the CLI.
#include "cli_support.h"

#include <unistd.h>

#include <cstdio>
#include <iostream>

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

int report(const Status& status) {
  if (status.ok()) return 0;
  std::cerr << "error: " << status.message() << " [" << status_code_name(status.code()) << "]\n";
  // Exit codes: 2 for the caller's mistakes, 3 for resource limits, 1 otherwise.
  switch (status.code()) {
    case StatusCode::kInvalidArgument:
    case StatusCode::kNotFound:
    case StatusCode::kAlreadyExists:
    case StatusCode::kFailedPrecondition:
    case StatusCode::kOutOfRange: return 2;
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
  if (!global_options().quiet) std::cout << line << '\n';
}

}  // namespace posewarp::cli
