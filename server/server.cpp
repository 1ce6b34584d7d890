// run(): the store, the listening port, TLS and tokens, metrics, signals and the graceful stop around PosewarpService.
#include "server.h"

#include <grpcpp/ext/proto_server_reflection_plugin.h>
#include <grpcpp/grpcpp.h>
#include <grpcpp/health_check_service_interface.h>
#include <grpcpp/resource_quota.h>
#include <spdlog/sinks/stdout_color_sinks.h>
#include <spdlog/spdlog.h>

#include <algorithm>
#include <chrono>
#include <csignal>
#include <cstdio>
#include <memory>
#include <string>
#include <thread>

#include "auth.h"
#include "metrics.h"
#include "posewarp/api/files.h"

namespace posewarp::server {
namespace {

bool loopback(const std::string& address) {
  return address.rfind("127.", 0) == 0 || address.rfind("localhost:", 0) == 0 || address.rfind("[::1]:", 0) == 0;
}

// Plaintext without --tls-cert; TLS (mutual with --tls-client-ca) with it.
Result<std::shared_ptr<grpc::ServerCredentials>> credentials(const ServerConfig& config) {
  if (config.tls_cert.empty()) return grpc::InsecureServerCredentials();
  grpc::SslServerCredentialsOptions ssl;
  POSEWARP_ASSIGN_OR_RETURN(const std::string key, api::read_text_input(config.tls_key, "TLS key", int64_t{1} << 20));
  POSEWARP_ASSIGN_OR_RETURN(const std::string cert,
                            api::read_text_input(config.tls_cert, "TLS certificate", int64_t{1} << 20));
  ssl.pem_key_cert_pairs.push_back({key, cert});
  if (!config.tls_client_ca.empty()) {
    POSEWARP_ASSIGN_OR_RETURN(ssl.pem_root_certs,
                              api::read_text_input(config.tls_client_ca, "client CA", int64_t{1} << 20));
    ssl.client_certificate_request = GRPC_SSL_REQUEST_AND_REQUIRE_CLIENT_CERTIFICATE_AND_VERIFY;
  }
  return grpc::SslServerCredentials(ssl);
}

// The gRPC server with health and reflection, listening; null when it cannot listen. `port` gets the port bound.
std::unique_ptr<grpc::Server> start(const ServerConfig& config, PosewarpService& service,
                                    const std::shared_ptr<grpc::ServerCredentials>& credentials, int* port) {
  grpc::EnableDefaultHealthCheckService(true);
  grpc::reflection::InitProtoReflectionServerBuilderPlugin();
  grpc::ServerBuilder builder;
  builder.AddListeningPort(config.listen, credentials, port);
  builder.RegisterService(&service);
  builder.SetMaxReceiveMessageSize(config.max_message_mb << 20);
  // gRPC's own buffers come out of the server's base share.
  grpc::ResourceQuota quota("posewarp-server");
  quota.Resize(size_t{192} << 20);
  builder.SetResourceQuota(quota);
  builder.AddChannelArgument(GRPC_ARG_MAX_CONCURRENT_STREAMS, config.max_streams);
  return builder.BuildAndStart();
}

// Waits for SIGTERM or SIGINT (which it returns), re-reading the token file on each SIGHUP meanwhile.
int wait_for_stop(const sigset_t& signals, Tokens& tokens, const std::string& token_file) {
  int received = 0;
  for (;;) {
    sigwait(&signals, &received);
    if (received != SIGHUP) return received;
    if (token_file.empty()) {
      spdlog::info("SIGHUP: no --token-file to re-read");
    } else if (Status s = tokens.reload(); s.ok()) {
      spdlog::info("SIGHUP: token file re-read, {} token(s)", tokens.size());
    } else {
      spdlog::error("SIGHUP: {}; the tokens in force stay", s.message());
    }
  }
}

int refuse_to_start(const std::string& message) {
  std::fprintf(stderr, "error: %s\n", message.c_str());
  return 2;
}

}  // namespace

int run(const ServerConfig& config) {
  // Logs go to stderr (a service manager or container collects them): one line per call, no patient data.
  spdlog::set_default_logger(spdlog::stderr_color_mt("posewarp-server"));
  spdlog::set_pattern("%Y-%m-%dT%H:%M:%S.%e %^%l%$ %v");
  spdlog::set_level(spdlog::level::from_str(config.log_level));
  Tokens tokens;
  if (Status s = tokens.load(config.token_file); !s.ok()) return refuse_to_start(s.to_string());
  Result<std::unique_ptr<RigStore>> store =
      RigStore::open(config.store_dir, config.store, [](const std::string& line) { spdlog::warn("{}", line); });
  if (!store.ok()) return refuse_to_start(store.status().to_string());
  if (!loopback(config.listen) && config.tls_cert.empty()) {
    spdlog::warn(
        "listening on {} without TLS: tokens and studies cross the network in clear; give --tls-cert and "
        "--tls-key, or keep the server on loopback behind a TLS proxy",
        config.listen);
  }
  // SIGTERM, SIGINT and SIGHUP go to a waiting thread, not to whichever thread runs when they arrive.
  sigset_t signals;
  sigemptyset(&signals);
  sigaddset(&signals, SIGTERM);
  sigaddset(&signals, SIGINT);
  sigaddset(&signals, SIGHUP);
  pthread_sigmask(SIG_BLOCK, &signals, nullptr);
  Metrics metrics;
  MetricsServer metrics_server;
  if (!config.metrics_listen.empty()) {
    if (const std::string error = metrics_server.start(config.metrics_listen, &metrics); !error.empty()) {
      return refuse_to_start(error);
    }
  }
  PosewarpService service(std::move(store).value(), config.service, tokens, metrics);
  Result<std::shared_ptr<grpc::ServerCredentials>> tls = credentials(config);
  if (!tls.ok()) return refuse_to_start(tls.status().to_string());
  int port = 0;
  std::unique_ptr<grpc::Server> server = start(config, service, *tls, &port);
  if (!server || port == 0) {
    return refuse_to_start("cannot listen on " + config.listen + " (in use, or not an address of this machine)");
  }
  server->GetHealthCheckService()->SetServingStatus(true);
  std::printf("posewarp-server listening on %s:%d, store %s\n",
              config.listen.substr(0, config.listen.rfind(':')).c_str(), port, config.store_dir.c_str());
  std::fflush(stdout);
  spdlog::info("serving on port {} ({}{}{})", port, config.tls_cert.empty() ? "plaintext" : "TLS",
               config.tls_client_ca.empty() ? "" : ", client certificates required",
               tokens.enabled() ? ", bearer tokens required" : "");
  const int received = wait_for_stop(signals, tokens, config.token_file);
  spdlog::info("{}: stopping (running poses get {:.0f} s)", received == SIGTERM ? "SIGTERM" : "SIGINT", config.grace_s);
  server->GetHealthCheckService()->SetServingStatus(false);
  service.shutdown();  // builds are cancelled and marked; new requests are refused
  // The calls answering finish before gRPC's shutdown closes each connection as its last stream ends: closed
  // then, a connection whose client was still reading a large answer (and acknowledging it) could be reset under
  // the answer's last bytes. A moment after the last call returns its trailers are on the wire.
  const auto grace = std::chrono::milliseconds(static_cast<int64_t>(config.grace_s * 1000.0));
  const auto until = std::chrono::steady_clock::now() + grace;
  if (service.wait_for_answers(until)) {
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
  } else {
    spdlog::warn("calls still answering after {:.0f} s (--shutdown-grace-s): they are cancelled", config.grace_s);
  }
  server->Shutdown(std::chrono::system_clock::now() +
                   std::max(std::chrono::milliseconds(0), std::chrono::duration_cast<std::chrono::milliseconds>(
                                                              until - std::chrono::steady_clock::now())));
  server->Wait();
  spdlog::info("stopped");
  return 0;
}

}  // namespace posewarp::server
