// posewarp-server: parses its flags (and --config) into a ServerConfig and runs the server (server.h).
#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <unistd.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <string>
#include <vector>

#include "posewarp/api/files.h"
#include "posewarp/api/support.h"
#include "server.h"

namespace {

// The config file's entries as command-line arguments ("--key value"), placed before the real command line so that
// the command line wins.
posewarp::Result<std::vector<std::string>> config_arguments(int argc, char** argv) {
  using namespace posewarp;
  std::vector<std::string> args;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    std::string path;
    if (arg == "--config" && i + 1 < argc) path = argv[i + 1];
    if (arg.rfind("--config=", 0) == 0) path = arg.substr(9);
    if (path.empty()) continue;
    POSEWARP_ASSIGN_OR_RETURN(const std::string text, api::read_text_input(path, "server config"));
    POSEWARP_ASSIGN_OR_RETURN(const nlohmann::json config,
                              parse_json<nlohmann::json>(text, "server config '" + path + "'"));
    if (!config.is_object()) {
      return invalid_argument_error("server config '" + path +
                                    "' is not a JSON object of options; see --help for their names");
    }
    for (const auto& [key, value] : config.items()) {
      if (value.is_boolean()) {
        if (value.get<bool>()) args.push_back("--" + key);
        continue;
      }
      args.push_back("--" + key);
      args.push_back(value.is_string() ? value.get<std::string>() : value.dump());
    }
  }
  return args;
}

// The flags as given, before the sizes in MB and seconds become the service's bytes and milliseconds.
struct Flags {
  posewarp::server::ServerConfig config;
  std::string config_file;
  int64_t memory_mb = 0;
  int64_t cache_mb = 0;
  double stall_timeout_s = 0.0;
  int64_t upload_mb_per_client = 0;
  int64_t max_upload_mb = 0;
  int64_t max_output_mb = 0;
  int64_t quota_gb = 0;
};

void add_work_options(CLI::App& app, Flags& f) {
  posewarp::server::ServiceOptions& options = f.config.service;
  app.add_option("--config", f.config_file, "JSON config file of these options");
  app.add_option("--listen", f.config.listen, "Address to listen on (HOST:PORT; port 0 picks a free one)")
      ->capture_default_str();
  app.add_option("--store", f.config.store_dir, "Store directory (uploaded volumes, rigs, index.sqlite)")->required();
  app.add_option("--store-quota-gb", f.quota_gb, "Largest store (volumes and rigs), GB; 0 = no quota")
      ->capture_default_str();
  app.add_option("--build-workers", options.build_workers, "Builds running at once")
      ->capture_default_str()
      ->check(CLI::Range(1, 64));
  app.add_option("--build-queue", options.build_queue, "Builds that may wait for a worker")
      ->capture_default_str()
      ->check(CLI::Range(0, 1000));
  app.add_option("--build-threads", options.build_threads, "Threads of a build (0 = all cores)")->capture_default_str();
  app.add_option("--pose-slots", options.pose_slots, "Poses running at once (0 = as many as cores)")
      ->capture_default_str()
      ->check(CLI::Range(0, 256));
  app.add_option("--pose-queue", options.pose_queue, "Poses that may wait for a slot")
      ->capture_default_str()
      ->check(CLI::Range(0, 10000));
  app.add_option("--pose-threads", options.pose_threads, "Threads of one pose (0 = all cores)")->capture_default_str();
  app.add_option("--memory-mb", f.memory_mb,
                 "The server's memory ceiling, MB (default 3/4 of the machine's): loaded rigs (--cache-mb), poses and "
                 "uploads in flight, the last poses' freed outputs kept for the next (a quarter of what poses may use, "
                 "at most 512 MB) and a 256 MB base share it; work that would go past it waits or is refused "
                 "RESOURCE_EXHAUSTED")
      ->capture_default_str()
      ->check(CLI::Range(int64_t{512}, int64_t{1} << 40));
  app.add_option("--kept-output-idle-s", options.kept_output_idle_s,
                 "The last poses' freed outputs that no pose has taken for this long go back to the system, seconds "
                 "(0 = keep none: every pose maps fresh memory and the kept quarter stays with poses)")
      ->capture_default_str()
      ->check(CLI::Range(0, 86400));
  app.add_option("--cache-mb", f.cache_mb,
                 "Loaded rigs kept in memory, MB, out of --memory-mb (0 = a third of it, at "
                 "most 8192)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
}

void add_limit_options(CLI::App& app, Flags& f) {
  posewarp::server::ServiceOptions& options = f.config.service;
  app.add_option("--stall-timeout-s", f.stall_timeout_s,
                 "A call whose stream makes no progress this long (a client that stopped reading its pose, or stopped "
                 "sending its upload) is cancelled and its pose slot and memory freed")
      ->capture_default_str()
      ->check(CLI::Range(0.1, 3600.0));
  app.add_option("--calls-per-client", options.client.calls,
                 "Poses, uploads and downloads one client may have in progress at once (a client is its bearer token, "
                 "else its address)")
      ->capture_default_str()
      ->check(CLI::Range(1, 10000));
  app.add_option("--uploads-per-client", options.client.uploads, "Uploads one client may have in progress at once")
      ->capture_default_str()
      ->check(CLI::Range(1, 1000));
  app.add_option("--upload-mb-per-client", f.upload_mb_per_client,
                 "Declared sizes of one client's uploads in progress together, MB (0 = --max-upload-mb)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  app.add_option("--max-upload-mb", f.max_upload_mb, "Largest uploaded file, MB")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  app.add_option("--max-volume-voxels", options.max_volume_voxels,
                 "Largest uploaded volume, voxels (also what reading it may allocate)")
      ->capture_default_str()
      ->check(CLI::Range(int64_t{1}, int64_t{1} << 31));
  app.add_option("--max-output-voxels", options.max_output_voxels, "Largest pose output grid, voxels")
      ->capture_default_str()
      ->check(CLI::Range(int64_t{1}, int64_t{1} << 31));
  app.add_option("--max-output-mb", f.max_output_mb, "Largest output of one pose, MB (0 = the whole memory budget)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  app.add_option("--max-message-mb", f.config.max_message_mb, "Largest gRPC message received, MB")
      ->capture_default_str()
      ->check(CLI::Range(1, 1024));
  app.add_option("--max-streams", f.config.max_streams, "Concurrent streams per client connection")
      ->capture_default_str()
      ->check(CLI::Range(1, 10000));
  app.add_option("--preview-streams-per-client", options.preview_streams_per_client,
                 "Open preview streams per client address")
      ->capture_default_str()
      ->check(CLI::Range(1, 1000));
}

void add_operation_options(CLI::App& app, Flags& f) {
  posewarp::server::ServerConfig& c = f.config;
  app.add_option("--token-file", c.token_file,
                 "Bearer tokens, one per line: calls without one get UNAUTHENTICATED "
                 "(health stays open); re-read on SIGHUP");
  app.add_option("--tls-cert", c.tls_cert, "TLS certificate chain (PEM); with --tls-key the server speaks TLS only");
  app.add_option("--tls-key", c.tls_key, "TLS private key (PEM)");
  app.add_option("--tls-client-ca", c.tls_client_ca, "CA (PEM) that client certificates must chain to: mutual TLS");
  app.add_option("--metrics-listen", c.metrics_listen, "HOST:PORT for Prometheus metrics at /metrics (off when empty)");
  app.add_option("--shutdown-grace-s", c.grace_s, "On SIGTERM, seconds running poses get to finish")
      ->capture_default_str();
  app.add_option("--log-level", c.log_level, "trace, debug, info, warn, error")->capture_default_str();
  app.add_option("--database", c.store.database,
                 "PostgreSQL index shared by replicas of one store directory (a libpq connection string or "
                 "postgresql:// URL; its password in PGPASSFILE or ~/.pgpass). Empty: SQLite in the store, one "
                 "server");
  app.add_option("--replica", c.service.replica,
                 "This replica's name among those sharing the store (default: host name and process id)");
  app.add_option("--lease-seconds", c.service.lease_s,
                 "With --database: a build whose replica stops renewing its lease this long is failed or taken "
                 "over by another")
      ->capture_default_str()
      ->check(CLI::Range(2, 3600));
}

// The parsed flags as the server's configuration; an empty string, or why they do not go together.
std::string finish_config(Flags& f) {
  posewarp::server::ServiceOptions& options = f.config.service;
  if (f.cache_mb == 0) f.cache_mb = std::min<int64_t>(f.memory_mb / 3, 8192);
  constexpr int64_t kBaseMb = 256;  // the server itself: libraries, gRPC's buffers, the index
  if (f.memory_mb < f.cache_mb + kBaseMb + 256) {
    return "--memory-mb " + std::to_string(f.memory_mb) +
           " leaves less than 256 MB for poses and uploads after "
           "--cache-mb " +
           std::to_string(f.cache_mb) +
           " and the server's own 256 MB; raise --memory-mb or lower "
           "--cache-mb";
  }
  options.cache_bytes = f.cache_mb << 20;
  options.memory_bytes = (f.memory_mb - f.cache_mb - kBaseMb) << 20;
  // A quarter of what poses may use, at most 512 MB, holds the last poses' freed outputs for the next pose.
  options.kept_output_bytes =
      options.kept_output_idle_s > 0 ? std::min<int64_t>(options.memory_bytes / 4, int64_t{512} << 20) : 0;
  options.memory_bytes -= options.kept_output_bytes;
  options.stall_timeout_ms = static_cast<int>(f.stall_timeout_s * 1000.0);
  options.max_upload_bytes = f.max_upload_mb << 20;
  options.client.upload_bytes = (f.upload_mb_per_client > 0 ? f.upload_mb_per_client : f.max_upload_mb) << 20;
  options.max_output_bytes = f.max_output_mb << 20;
  f.config.store.quota_bytes = static_cast<uint64_t>(f.quota_gb) << 30;
  if (f.config.tls_cert.empty() != f.config.tls_key.empty()) return "--tls-cert and --tls-key go together";
  if (!f.config.tls_client_ca.empty() && f.config.tls_cert.empty()) {
    return "--tls-client-ca needs --tls-cert and --tls-key (mutual TLS is TLS first)";
  }
  if (options.replica == "posewarp") {  // not given: host name and pid, unique among replicas
    char host[256] = {};
    ::gethostname(host, sizeof host - 1);
    options.replica = std::string(host) + ":" + std::to_string(::getpid());
  }
  return "";
}

}  // namespace

int main(int argc, char** argv) {
  using namespace posewarp;
  CLI::App app{
      "posewarp-server: uploads, rig builds and poses over gRPC (package posewarp.v1, proto/).\n"
      "Every option can also be given in a JSON config file (--config) under the same name without dashes,\n"
      "e.g. {\"store\": \"/srv/posewarp\", \"pose-slots\": 4, \"token-file\": \"/etc/posewarp/tokens\"};\n"
      "the command line wins over the file. Signals: SIGTERM/SIGINT stop gracefully, SIGHUP re-reads the\n"
      "token file.",
      "posewarp-server"};
  Flags flags;
  const int64_t machine_mb = static_cast<int64_t>(::sysconf(_SC_PHYS_PAGES)) * ::sysconf(_SC_PAGE_SIZE) >> 20;
  flags.memory_mb = machine_mb * 3 / 4;
  flags.stall_timeout_s = flags.config.service.stall_timeout_ms / 1000.0;
  flags.max_upload_mb = flags.config.service.max_upload_bytes >> 20;
  app.option_defaults()->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);  // the command line wins
  add_work_options(app, flags);
  add_limit_options(app, flags);
  add_operation_options(app, flags);
  // Test hooks (crash and shutdown tests): never set in production.
  if (const char* pause = std::getenv("POSEWARP_TEST_PAUSE_IN_RIG_WRITE_S")) {
    flags.config.store.pause_in_rig_write_s = std::atof(pause);
  }
  if (const char* pause = std::getenv("POSEWARP_TEST_PAUSE_IN_POSE_S")) {
    flags.config.service.test_pause_in_pose_s = std::atof(pause);
  }
  Result<std::vector<std::string>> args = config_arguments(argc, argv);
  if (!args.ok()) {
    std::fprintf(stderr, "error: %s\n", args.status().message().c_str());
    return 2;
  }
  for (int i = 1; i < argc; ++i) args->push_back(argv[i]);
  try {
    std::vector<std::string> reversed(args->rbegin(), args->rend());  // CLI11 takes a vector in reverse order
    app.parse(reversed);
  } catch (const CLI::ParseError& error) {
    const int code = app.exit(error);
    return code == 0 ? 0 : 2;
  }
  if (const std::string error = finish_config(flags); !error.empty()) {
    std::fprintf(stderr, "error: %s\n", error.c_str());
    return 2;
  }
  return server::run(flags.config);
}
