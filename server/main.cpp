// posewarp-server: the gRPC service over a store directory.
#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/health_check_service_interface.h>
#include <grpcpp/resource_quota.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>
#include <CLI/CLI.hpp>
#include <nlohmann/json.hpp>

#include <unistd.h>

#include <algorithm>
#include <csignal>
#include <cstdio>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "auth.h"
#include "metrics.h"
#include "posewarp/api/files.h"
#include "service.h"

namespace {

bool loopback(const std::string& address) {
  return address.rfind("127.", 0) == 0 || address.rfind("localhost:", 0) == 0 || address.rfind("[::1]:", 0) == 0;
}

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
    try {
      const nlohmann::json config = nlohmann::json::parse(text);
      if (!config.is_object()) throw nlohmann::json::type_error::create(302, "not an object", nullptr);
      for (const auto& [key, value] : config.items()) {
        if (value.is_boolean()) {
          if (value.get<bool>()) args.push_back("--" + key);
          continue;
        }
        args.push_back("--" + key);
        args.push_back(value.is_string() ? value.get<std::string>() : value.dump());
      }
    } catch (const nlohmann::json::exception& error) {
      return invalid_argument_error("server config '" + path + "' is not a JSON object of options (" +
                                    error.what() + "); see --help for their names");
    }
  }
  return args;
}

std::string read_pem(const std::string& path, const char* what) {
  posewarp::Result<std::string> text = posewarp::api::read_text_input(path, what, int64_t{1} << 20);
  if (!text.ok()) {
    std::fprintf(stderr, "error: %s\n", text.status().to_string().c_str());
    std::exit(2);
  }
  return *text;
}

}  // namespace

int main(int argc, char** argv) {
  using namespace posewarp;
  CLI::App app{"posewarp-server: uploads, rig builds and poses over gRPC (package posewarp.v1, proto/).\n"
               "Every option can also be given in a JSON config file (--config) under the same name without dashes,\n"
               "e.g. {\"store\": \"/srv/posewarp\", \"pose-slots\": 4, \"token-file\": \"/etc/posewarp/tokens\"};\n"
               "the command line wins over the file. Signals: SIGTERM/SIGINT stop gracefully, SIGHUP re-reads the\n"
               "token file.",
               "posewarp-server"};
  std::string listen = "127.0.0.1:50051";
  std::string store_dir, config, token_file, tls_cert, tls_key, tls_client_ca, metrics_listen, log_level = "info";
  server::ServiceOptions options;
  server::StoreOptions store_options;
  const int64_t machine_mb = static_cast<int64_t>(::sysconf(_SC_PHYS_PAGES)) * ::sysconf(_SC_PAGE_SIZE) >> 20;
  int64_t memory_mb = machine_mb * 3 / 4;
  int64_t cache_mb = 0;
  double stall_timeout_s = options.stall_timeout_ms / 1000.0;
  int64_t upload_mb_per_client = 0;
  int64_t max_upload_mb = options.max_upload_bytes >> 20;
  int64_t max_output_mb = 0;
  int64_t quota_gb = 0;
  int max_message_mb = 8;
  int max_streams = 100;
  double grace_s = 30.0;
  app.option_defaults()->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);  // the command line wins
  app.add_option("--config", config, "JSON config file of these options");
  app.add_option("--listen", listen, "Address to listen on (HOST:PORT; port 0 picks a free one)")->capture_default_str();
  app.add_option("--store", store_dir, "Store directory (uploaded volumes, rigs, index.sqlite)")->required();
  app.add_option("--store-quota-gb", quota_gb, "Largest store (volumes and rigs), GB; 0 = no quota")->capture_default_str();
  app.add_option("--build-workers", options.build_workers, "Builds running at once")->capture_default_str()->check(CLI::Range(1, 64));
  app.add_option("--build-queue", options.build_queue, "Builds that may wait for a worker")
      ->capture_default_str()->check(CLI::Range(0, 1000));
  app.add_option("--build-threads", options.build_threads, "Threads of a build (0 = all cores)")->capture_default_str();
  app.add_option("--pose-slots", options.pose_slots, "Poses running at once (0 = as many as cores)")
      ->capture_default_str()->check(CLI::Range(0, 256));
  app.add_option("--pose-queue", options.pose_queue, "Poses that may wait for a slot")->capture_default_str()->check(CLI::Range(0, 10000));
  app.add_option("--pose-threads", options.pose_threads, "Threads of one pose (0 = all cores)")->capture_default_str();
  app.add_option("--memory-mb", memory_mb,
                 "The server's memory ceiling, MB (default 3/4 of the machine's): loaded rigs (--cache-mb), poses and "
                 "uploads in flight and a 256 MB base share it; work that would go past it waits or is refused "
                 "RESOURCE_EXHAUSTED")
      ->capture_default_str()
      ->check(CLI::Range(int64_t{512}, int64_t{1} << 40));
  app.add_option("--cache-mb", cache_mb,
                 "Loaded rigs kept in memory, MB, out of --memory-mb (0 = a third of it, at "
                 "most 8192)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  app.add_option("--stall-timeout-s", stall_timeout_s,
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
  app.add_option("--upload-mb-per-client", upload_mb_per_client,
                 "Declared sizes of one client's uploads in progress together, MB (0 = --max-upload-mb)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  app.add_option("--max-upload-mb", max_upload_mb, "Largest uploaded file, MB")->capture_default_str()->check(CLI::PositiveNumber);
  app.add_option("--max-volume-voxels", options.max_volume_voxels,
                 "Largest uploaded volume, voxels (also what reading it may allocate)")
      ->capture_default_str()
      ->check(CLI::Range(int64_t{1}, int64_t{1} << 31));
  app.add_option("--max-output-voxels", options.max_output_voxels, "Largest pose output grid, voxels")
      ->capture_default_str()
      ->check(CLI::Range(int64_t{1}, int64_t{1} << 31));
  app.add_option("--max-output-mb", max_output_mb, "Largest output of one pose, MB (0 = the whole memory budget)")
      ->capture_default_str()
      ->check(CLI::NonNegativeNumber);
  app.add_option("--max-message-mb", max_message_mb, "Largest gRPC message received, MB")->capture_default_str()->check(CLI::Range(1, 1024));
  app.add_option("--max-streams", max_streams, "Concurrent streams per client connection")->capture_default_str()->check(CLI::Range(1, 10000));
  app.add_option("--preview-streams-per-client", options.preview_streams_per_client,
                 "Open preview streams per client address")->capture_default_str()->check(CLI::Range(1, 1000));
  app.add_option("--token-file", token_file, "Bearer tokens, one per line: calls without one get UNAUTHENTICATED "
                                             "(health stays open); re-read on SIGHUP");
  app.add_option("--tls-cert", tls_cert, "TLS certificate chain (PEM); with --tls-key the server speaks TLS only");
  app.add_option("--tls-key", tls_key, "TLS private key (PEM)");
  app.add_option("--tls-client-ca", tls_client_ca, "CA (PEM) that client certificates must chain to: mutual TLS");
  app.add_option("--metrics-listen", metrics_listen, "HOST:PORT for Prometheus metrics at /metrics (off when empty)");
  app.add_option("--shutdown-grace-s", grace_s, "On SIGTERM, seconds running poses get to finish")->capture_default_str();
  app.add_option("--log-level", log_level, "trace, debug, info, warn, error")->capture_default_str();
  app.add_option("--database", store_options.database,
                 "PostgreSQL index shared by replicas of one store directory (a libpq connection string or "
                 "postgresql:// URL; its password in PGPASSFILE or ~/.pgpass). Empty: SQLite in the store, one "
                 "server");
  app.add_option("--replica", options.replica,
                 "This replica's name among those sharing the store (default: host name and process id)");
  app.add_option("--lease-seconds", options.lease_s,
                 "With --database: a build whose replica stops renewing its lease this long is failed or taken "
                 "over by another")
      ->capture_default_str()
      ->check(CLI::Range(2, 3600));
  store_options.pause_in_rig_write_s = std::getenv("POSEWARP_TEST_PAUSE_IN_RIG_WRITE_S") != nullptr
                                           ? std::atof(std::getenv("POSEWARP_TEST_PAUSE_IN_RIG_WRITE_S"))
                                           : 0.0;
  // Test hooks (crash and shutdown tests): never set in production.
  if (const char* pause = std::getenv("POSEWARP_TEST_PAUSE_IN_POSE_S")) options.test_pause_in_pose_s = std::atof(pause);
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
  if (cache_mb == 0) cache_mb = std::min<int64_t>(memory_mb / 3, 8192);
  constexpr int64_t kBaseMb = 256;  // the server itself: libraries, gRPC's buffers, the index
  if (memory_mb < cache_mb + kBaseMb + 256) {
    std::fprintf(stderr,
                 "error: --memory-mb %lld leaves less than 256 MB for poses and uploads after --cache-mb %lld "
                 "and the server's own 256 MB; raise --memory-mb or lower --cache-mb\n",
                 static_cast<long long>(memory_mb), static_cast<long long>(cache_mb));
    return 2;
  }
  options.cache_bytes = cache_mb << 20;
  options.memory_bytes = (memory_mb - cache_mb - kBaseMb) << 20;
  options.stall_timeout_ms = static_cast<int>(stall_timeout_s * 1000.0);
  options.max_upload_bytes = max_upload_mb << 20;
  options.client.upload_bytes = (upload_mb_per_client > 0 ? upload_mb_per_client : max_upload_mb) << 20;
  options.max_output_bytes = max_output_mb << 20;
  store_options.quota_bytes = static_cast<uint64_t>(quota_gb) << 30;
  if (tls_cert.empty() != tls_key.empty()) {
    std::fprintf(stderr, "error: --tls-cert and --tls-key go together\n");
    return 2;
  }
  if (!tls_client_ca.empty() && tls_cert.empty()) {
    std::fprintf(stderr, "error: --tls-client-ca needs --tls-cert and --tls-key (mutual TLS is TLS first)\n");
    return 2;
  }

  if (options.replica == "posewarp") {  // not given: host name and pid, unique among replicas
    char host[256] = {};
    ::gethostname(host, sizeof host - 1);
    options.replica = std::string(host) + ":" + std::to_string(::getpid());
  }
  // Logs go to stderr (a service manager or container collects them): one line per call, no patient data.
  spdlog::set_default_logger(spdlog::stderr_color_mt("posewarp-server"));
  spdlog::set_pattern("%Y-%m-%dT%H:%M:%S.%e %^%l%$ %v");
  spdlog::set_level(spdlog::level::from_str(log_level));

  server::Tokens tokens;
  if (Status s = tokens.load(token_file); !s.ok()) {
    std::fprintf(stderr, "error: %s\n", s.to_string().c_str());
    return 2;
  }
  Result<std::unique_ptr<server::RigStore>> store =
      server::RigStore::open(store_dir, store_options, [](const std::string& line) { spdlog::warn("{}", line); });
  if (!store.ok()) {
    std::fprintf(stderr, "error: %s\n", store.status().to_string().c_str());
    return 2;
  }
  if (!loopback(listen) && tls_cert.empty()) {
    spdlog::warn("listening on {} without TLS: tokens and studies cross the network in clear; give --tls-cert and "
                 "--tls-key, or keep the server on loopback behind a TLS proxy", listen);
  }
  // SIGTERM, SIGINT and SIGHUP go to a waiting thread, not to whichever thread runs when they arrive.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGHUP);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);

  server::Metrics metrics;
  server::MetricsServer metrics_server;
  if (!metrics_listen.empty()) {
    if (const std::string error = metrics_server.start(metrics_listen, &metrics); !error.empty()) {
      std::fprintf(stderr, "error: %s\n", error.c_str());
      return 2;
    }
  }
  server::PosewarpService service(std::move(store).value(), options, tokens, metrics);
  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  std::shared_ptr<grpc::ServerCredentials> credentials = grpc::InsecureServerCredentials();
  if (!tls_cert.empty()) {
    grpc::SslServerCredentialsOptions ssl;
    ssl.pem_key_cert_pairs.push_back({read_pem(tls_key, "TLS key"), read_pem(tls_cert, "TLS certificate")});
    if (!tls_client_ca.empty()) {
      ssl.pem_root_certs = read_pem(tls_client_ca, "client CA");
      ssl.client_certificate_request = GRPC_SSL_REQUEST_AND_REQUIRE_CLIENT_CERTIFICATE_AND_VERIFY;
    }
    credentials = grpc::SslServerCredentials(ssl);
  }
  grpc::ServerBuilder builder;
  int port = 0;
  builder.AddListeningPort(listen, credentials, &port);
  builder.RegisterService(&service);
  builder.SetMaxReceiveMessageSize(max_message_mb << 20);
  // gRPC's own buffers come out of the server's base share.
  grpc::ResourceQuota quota("posewarp-server");
  quota.Resize(size_t{192} << 20);
  builder.SetResourceQuota(quota);
  builder.AddChannelArgument(GRPC_ARG_MAX_CONCURRENT_STREAMS, max_streams);
  std::unique_ptr<grpc::Server> server = builder.BuildAndStart();
  if (!server || port == 0) {
    std::fprintf(stderr, "error: cannot listen on %s (in use, or not an address of this machine)\n", listen.c_str());
    return 2;
  }
  server->GetHealthCheckService()->SetServingStatus(true);
  std::printf("posewarp-server listening on %s:%d, store %s\n", listen.substr(0, listen.rfind(':')).c_str(), port,
              store_dir.c_str());
  std::fflush(stdout);
  spdlog::info("serving on port {} ({}{}{})", port, tls_cert.empty() ? "plaintext" : "TLS",
               tls_client_ca.empty() ? "" : ", client certificates required",
               tokens.enabled() ? ", bearer tokens required" : "");

  int received = 0;
  for (;;) {
    sigwait(&signals, &received);
    if (received != SIGHUP) break;
    if (token_file.empty()) {
      spdlog::info("SIGHUP: no --token-file to re-read");
    } else if (Status s = tokens.reload(); s.ok()) {
      spdlog::info("SIGHUP: token file re-read, {} token(s)", tokens.size());
    } else {
      spdlog::error("SIGHUP: {}; the tokens in force stay", s.message());
    }
  }
  spdlog::info("{}: stopping (running poses get {:.0f} s)", received == SIGTERM ? "SIGTERM" : "SIGINT", grace_s);
  server->GetHealthCheckService()->SetServingStatus(false);
  service.shutdown();  // builds are cancelled and marked; new requests are refused
  server->Shutdown(std::chrono::system_clock::now() +
                   std::chrono::milliseconds(static_cast<int64_t>(grace_s * 1000.0)));
  server->Wait();
  spdlog::info("stopped");
  return 0;
}
