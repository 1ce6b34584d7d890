// The CLI's remote mode: the same commands through posewarp-server (--server HOST:PORT), writing the same files.
// It talks the proto only; the engine never runs here.
#pragma once

#include <cstdint>
#include <cstdio>
#include <string>

namespace posewarp::cli {

struct RemoteBuild {
  std::string server;
  std::string labels_path, ct_path, label_map_path, preset, spec_path, name;
};

struct RemotePose {
  std::string server;
  std::string rig_id;
  std::string pose_path;
  std::string method = "cor";
  std::string grid = "input";
  std::string labels_out, ct_out, surfaces_out, surface_format = "vtp", report_out;
  int64_t max_output_mb = 0;
};

// Uploads the volumes (the server keeps one copy of each), starts the build, shows its progress and prints the
// rig id. Exit codes as the local commands.
#ifdef POSEWARP_REMOTE
int run_build_remote(const RemoteBuild& options);
int run_pose_remote(const RemotePose& options);
int run_list_remote(const std::string& server);
#else
// A build tree without the server (-DPOSEWARP_BUILD_SERVER=OFF) has no remote mode.
inline int remote_unavailable() {
  std::fprintf(stderr, "error: this posewarp was built without the gRPC client (POSEWARP_BUILD_SERVER=OFF)\n");
  return 2;
}
inline int run_build_remote(const RemoteBuild&) { return remote_unavailable(); }
inline int run_pose_remote(const RemotePose&) { return remote_unavailable(); }
inline int run_list_remote(const std::string&) { return remote_unavailable(); }
#endif

}  // namespace posewarp::cli
