// The CLI's remote mode: the same commands through posewarp-server (--server HOST:PORT), writing the same files.
// It talks the proto only; the engine never runs here.
#pragma once

#include <CLI/CLI.hpp>

#include <cstdint>
#include <cstdio>
#include <functional>
#include <memory>
#include <optional>
#include <string>
#include <vector>

#include "posewarp/api/match.h"
#include "posewarp/api/pose_engine.h"

namespace posewarp::cli {

// Where the server is and how to reach it: TLS with a CA of one's own, and a bearer token read from a file.
struct Connection {
  std::string server;      // HOST:PORT
  std::string token_file;  // one line: the token
  std::string tls_ca;      // PEM of the CA that signed the server's certificate; empty: plaintext
  int retries = 3;         // calls refused with UNAVAILABLE are tried again after 0.5, 1, 2, ... s
};

// --token-file and --tls-ca beside a command's --server.
inline void add_connection_options(CLI::App* command, Connection& c) {
  command->add_option("--token-file", c.token_file, "File holding the server's bearer token (with --server)");
  command->add_option("--tls-ca", c.tls_ca, "CA certificate (PEM) of a TLS server (with --server)");
  command
      ->add_option("--retries", c.retries,
                   "Tries again this many times, waiting 0.5, 1, 2, ... s, while the server is unavailable "
                   "(restarting, or not up yet)")
      ->check(CLI::Range(0, 10))
      ->capture_default_str();
}

struct RemoteBuild {
  Connection connection;
  std::string labels_path, ct_path, label_map_path, preset, spec_path, name;
};

// A volume file to upload: its name's extension gives the format (.nii.gz, .nii, .nrrd, .mha), `bytes` its content.
struct RemoteVolumeFile {
  std::string name, bytes;
};

// What a rig is built from on the server, held in memory (a batch's study read from DICOM, or its files).
struct RemoteRigInputs {
  RemoteVolumeFile labels;
  std::optional<RemoteVolumeFile> ct;
  std::string label_map_json, preset, rig_spec_json, name;
};

// A pose answered by the server, in the local engine's types: the local command's writers write the same files.
struct RemotePoseResult {
  api::PoseResult result;     // labels and CT (the study's own voxel types), fields, surfaces, output grid
  ImageGeometry source_grid;  // the forward field's grid
  std::string report_json;    // the CLI's report.json, as the server wrote it
  std::vector<std::string> warnings;
};

// One rig on the server, posed as many times as asked over one connection (animate).
class RemotePoser {
 public:
  static Result<RemotePoser> open(const Connection& connection, const std::string& rig_id);
  RemotePoser(RemotePoser&&) noexcept;
  RemotePoser& operator=(RemotePoser&&) noexcept;
  ~RemotePoser();
  // The engine's request sent as the proto's (pose, method, grid, outputs wanted, the user's meshes, limits).
  Result<RemotePoseResult> pose(const api::PoseRequest& request) const;
  // The whole rig, downloaded, checked and read (its source grid, the label map naming the segments of a DICOM SEG,
  // the skeleton BVH retargeting needs).
  Result<api::Rig> rig() const;

 private:
  struct State;
  explicit RemotePoser(std::unique_ptr<State> state);
  std::unique_ptr<State> state_;
};

// What a match asks of the server (MatchPosture): the target's labels (uploaded first) or a standard posture.
struct RemoteMatchRequest {
  std::string rig_id;
  std::optional<RemoteVolumeFile> target;
  std::string standard, preset, label_map_json;
  bool free_hinges = false, beyond_range = false;
};

// The server's answer in the api's types, so that the local command prints and writes it alike.
struct RemoteMatch {
  api::PostureMatch match;
  std::string report_json;    // the match report as the server wrote it (empty for a standard posture)
  ImageGeometry target_grid;  // the target's grid (a match)
};

// Uploads the volumes (the server keeps one copy of each), starts the build, shows its progress and prints the
// rig id. Exit codes as the local commands.
#ifdef POSEWARP_REMOTE
int run_build_remote(const RemoteBuild& options);
// Uploads what the server does not hold yet, asks for the build (the server builds the same inputs once; a rig it
// has answers at once) and waits for it, reporting its stages to `on_stage` when given. Returns the rig id.
Result<std::string> build_rig_remote(const Connection& connection, const RemoteRigInputs& inputs,
                                     const std::function<void(const std::string&, double)>& on_stage = {});
int run_list_remote(const Connection& connection);
int run_info_remote(const Connection& connection, const std::string& rig_id, bool as_json);
int run_delete_remote(const Connection& connection, const std::string& rig_id);
int run_export_remote(const Connection& connection, const std::string& rig_id, const std::string& rig_out);
// The target uploaded (when there is one), then MatchPosture.
Result<RemoteMatch> match_remote(const Connection& connection, const RemoteMatchRequest& request);
// The standard gRPC health check (grpc.health.v1.Health/Check): exit 0 when the server is serving, 1 otherwise.
int run_health_remote(const Connection& connection, double timeout_s);
#else
// A build tree without the server (-DPOSEWARP_BUILD_SERVER=OFF) has no remote mode.
inline int remote_unavailable() {
  std::fprintf(stderr, "error: this posewarp was built without the gRPC client (POSEWARP_BUILD_SERVER=OFF)\n");
  return 2;
}
inline int run_build_remote(const RemoteBuild&) {
  return remote_unavailable();
}
inline Result<std::string> build_rig_remote(const Connection&, const RemoteRigInputs&,
                                            const std::function<void(const std::string&, double)>& = {}) {
  return unimplemented_error("this posewarp was built without the gRPC client (POSEWARP_BUILD_SERVER=OFF)");
}
struct RemotePoser::State {};
inline RemotePoser::RemotePoser(std::unique_ptr<State> state) : state_(std::move(state)) {}
inline RemotePoser::RemotePoser(RemotePoser&&) noexcept = default;
inline RemotePoser& RemotePoser::operator=(RemotePoser&&) noexcept = default;
inline RemotePoser::~RemotePoser() = default;
inline Result<RemotePoser> RemotePoser::open(const Connection&, const std::string&) {
  return unimplemented_error("this posewarp was built without the gRPC client (POSEWARP_BUILD_SERVER=OFF)");
}
inline Result<RemotePoseResult> RemotePoser::pose(const api::PoseRequest&) const {
  return unimplemented_error("no remote mode");
}
inline Result<api::Rig> RemotePoser::rig() const {
  return unimplemented_error("no remote mode");
}
inline int run_health_remote(const Connection&, double) { return remote_unavailable(); }
inline Result<RemoteMatch> match_remote(const Connection&, const RemoteMatchRequest&) {
  return failed_precondition_error("this posewarp was built without the gRPC client (POSEWARP_BUILD_SERVER=OFF)");
}
inline int run_list_remote(const Connection&) {
  return remote_unavailable();
}
inline int run_info_remote(const Connection&, const std::string&, bool) {
  return remote_unavailable();
}
inline int run_delete_remote(const Connection&, const std::string&) {
  return remote_unavailable();
}
inline int run_export_remote(const Connection&, const std::string&, const std::string&) {
  return remote_unavailable();
}
#endif

}  // namespace posewarp::cli
