// The CLI's remote mode: the same commands through posewarp-server (--server HOST:PORT), writing the same files.
// It talks the proto only; the engine never runs here.
#pragma once

#include <CLI/CLI.hpp>

#include <cstdint>
#include <cstdio>
#include <string>

namespace posewarp::cli {

// Where the server is and how to reach it: TLS with a CA of one's own, and a bearer token read from a file.
struct Connection {
  std::string server;      // HOST:PORT
  std::string token_file;  // one line: the token
  std::string tls_ca;      // PEM of the CA that signed the server's certificate; empty: plaintext
};

// --token-file and --tls-ca beside a command's --server.
inline void add_connection_options(CLI::App* command, Connection& c) {
  command->add_option("--token-file", c.token_file, "File holding the server's bearer token (with --server)");
  command->add_option("--tls-ca", c.tls_ca, "CA certificate (PEM) of a TLS server (with --server)");
}

struct RemoteBuild {
  Connection connection;
  std::string labels_path, ct_path, label_map_path, preset, spec_path, name;
};

struct RemotePose {
  Connection connection;
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
int run_list_remote(const Connection& connection);
int run_info_remote(const Connection& connection, const std::string& rig_id, bool as_json);
int run_delete_remote(const Connection& connection, const std::string& rig_id);
int run_export_remote(const Connection& connection, const std::string& rig_id, const std::string& rig_out);
#else
// A build tree without the server (-DPOSEWARP_BUILD_SERVER=OFF) has no remote mode.
inline int remote_unavailable() {
  std::fprintf(stderr, "error: this posewarp was built without the gRPC client (POSEWARP_BUILD_SERVER=OFF)\n");
  return 2;
}
inline int run_build_remote(const RemoteBuild&) { return remote_unavailable(); }
inline int run_pose_remote(const RemotePose&) { return remote_unavailable(); }
inline int run_list_remote(const Connection&) { return remote_unavailable(); }
inline int run_info_remote(const Connection&, const std::string&, bool) { return remote_unavailable(); }
inline int run_delete_remote(const Connection&, const std::string&) { return remote_unavailable(); }
inline int run_export_remote(const Connection&, const std::string&, const std::string&) { return remote_unavailable(); }
#endif

}  // namespace posewarp::cli
