// posewarp-server: the gRPC service over a store directory.
#include <CLI/CLI.hpp>
#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/health_check_service_interface.h>
#include <nlohmann/json.hpp>

#include <csignal>
#include <cstdio>
#include <fstream>
#include <iterator>
#include <memory>
#include <string>
#include <thread>
#include <vector>

#include "posewarp/api/files.h"
#include "service.h"

namespace {

bool loopback(const std::string& address) {
  return address.rfind("127.", 0) == 0 || address.rfind("localhost:", 0) == 0 || address.rfind("[::1]:", 0) == 0;
}

}  // namespace

int main(int argc, char** argv) {
  using namespace posewarp;
  CLI::App app{"posewarp-server: uploads, rig builds and poses over gRPC (package posewarp.v1, proto/).\n"
               "Every option can also be given in a JSON config file (--config) under the same name without dashes.",
               "posewarp-server"};
  std::string listen = "127.0.0.1:50051";
  std::string store_dir;
  std::string config;
  server::ServiceOptions options;
  int64_t cache_mb = options.cache_bytes >> 20;
  int64_t max_upload_mb = options.max_upload_bytes >> 20;
  int64_t max_output_mb = 0;
  double grace_s = 30.0;
  app.option_defaults()->multi_option_policy(CLI::MultiOptionPolicy::TakeLast);  // the command line wins
  app.add_option("--config", config, "JSON config file: {\"store\": \"/srv/posewarp\", \"pose-slots\": 4, ...}");
  app.add_option("--listen", listen, "Address to listen on (HOST:PORT; port 0 picks a free one)")->capture_default_str();
  app.add_option("--store", store_dir, "Store directory (uploaded volumes and rigs)")->required();
  app.add_option("--build-queue", options.build_queue, "Builds that may wait behind the running one")
      ->capture_default_str()->check(CLI::Range(0, 1000));
  app.add_option("--build-threads", options.build_threads, "Threads of a build (0 = all cores)")->capture_default_str();
  app.add_option("--pose-slots", options.pose_slots, "Poses running at once")->capture_default_str()->check(CLI::Range(1, 256));
  app.add_option("--pose-queue", options.pose_queue, "Poses that may wait for a slot")->capture_default_str()->check(CLI::Range(0, 10000));
  app.add_option("--pose-threads", options.pose_threads, "Threads of one pose (0 = all cores)")->capture_default_str();
  app.add_option("--cache-mb", cache_mb, "Loaded rigs kept in memory, MB")->capture_default_str()->check(CLI::PositiveNumber);
  app.add_option("--max-upload-mb", max_upload_mb, "Largest uploaded file, MB")->capture_default_str()->check(CLI::PositiveNumber);
  app.add_option("--max-output-mb", max_output_mb, "Largest pose output, MB (0 = half the machine's memory)")->capture_default_str();
  app.add_option("--shutdown-grace-s", grace_s, "On SIGTERM, seconds running poses get to finish")->capture_default_str();
  // The config file's entries go first, as if typed before the command line's own.
  std::vector<std::string> args;
  for (int i = 1; i < argc; ++i) {
    const std::string arg = argv[i];
    std::string path;
    if (arg == "--config" && i + 1 < argc) path = argv[i + 1];
    if (arg.rfind("--config=", 0) == 0) path = arg.substr(9);
    if (path.empty()) continue;
    Result<std::string> text = api::read_text_input(path, "server config");
    if (!text.ok()) {
      std::fprintf(stderr, "error: %s\n", text.status().to_string().c_str());
      return 2;
    }
    try {
      for (const auto& [key, value] : nlohmann::json::parse(*text).items()) {
        args.push_back("--" + key);
        args.push_back(value.is_string() ? value.get<std::string>() : value.dump());
      }
    } catch (const nlohmann::json::exception& error) {
      std::fprintf(stderr, "error: server config '%s' is not a JSON object of options: %s\n", path.c_str(),
                   error.what());
      return 2;
    }
  }
  for (int i = 1; i < argc; ++i) args.push_back(argv[i]);
  try {
    std::vector<std::string> reversed(args.rbegin(), args.rend());  // CLI11 takes a vector in reverse order
    app.parse(reversed);
  } catch (const CLI::ParseError& error) {
    const int code = app.exit(error);
    return code == 0 ? 0 : 2;
  }
  options.cache_bytes = cache_mb << 20;
  options.max_upload_bytes = max_upload_mb << 20;
  options.max_output_bytes = max_output_mb << 20;

  Result<server::RigStore> store = server::RigStore::open(store_dir);
  if (!store.ok()) {
    std::fprintf(stderr, "error: %s\n", store.status().to_string().c_str());
    return 2;
  }
  if (!loopback(listen)) {
    std::fprintf(stderr, "warning: listening on %s without TLS: anyone who can reach it can upload and pose "
                         "(TLS and tokens are not built yet; keep the server on loopback or behind a TLS proxy)\n",
                 listen.c_str());
  }
  // SIGTERM and SIGINT go to a waiting thread, not to whichever thread runs when they arrive.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGINT);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);

  server::PosewarpService service(std::move(store).value(), options);
  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  int port = 0;
  builder.AddListeningPort(listen, grpc::InsecureServerCredentials(), &port);
  builder.RegisterService(&service);
  builder.SetMaxReceiveMessageSize(8 << 20);
  std::unique_ptr<grpc::Server> server = builder.BuildAndStart();
  if (!server || port == 0) {
    std::fprintf(stderr, "error: cannot listen on %s (in use, or not an address of this machine)\n", listen.c_str());
    return 2;
  }
  server->GetHealthCheckService()->SetServingStatus(true);
  std::printf("posewarp-server listening on %s:%d, store %s\n", listen.substr(0, listen.rfind(':')).c_str(), port,
              store_dir.c_str());
  std::fflush(stdout);

  int received = 0;
  sigwait(&signals, &received);
  std::fprintf(stderr, "posewarp-server: %s, stopping (running poses get %.0f s)\n",
               received == SIGTERM ? "SIGTERM" : "SIGINT", grace_s);
  server->GetHealthCheckService()->SetServingStatus(false);
  service.shutdown();  // builds are cancelled and marked; new requests are refused
  server->Shutdown(std::chrono::system_clock::now() +
                   std::chrono::milliseconds(static_cast<int64_t>(grace_s * 1000.0)));
  server->Wait();
  std::fprintf(stderr, "posewarp-server: stopped\n");
  return 0;
}
