// posewarp health --server HOST:PORT: the server's gRPC health check, for container HEALTHCHECKs, load balancers'
// probes and scripts that wait for a server to come up.
#include <memory>

#include "cli_support.h"
#include "remote.h"

namespace posewarp::cli {

void add_health_command(CLI::App& app) {
  auto connection = std::make_shared<Connection>();
  connection->retries = 0;  // a probe answers now (--retries N waits for a server coming up)
  auto timeout_s = std::make_shared<double>(5.0);
  CLI::App* cmd = app.add_subcommand(
      "health",
      "Ask posewarp-server whether it is serving (the standard gRPC health check): prints SERVING and exits "
      "0, or prints what it got and exits 1 (not serving, unreachable, or past --timeout)");
  cmd->add_option("--server", connection->server, "HOST:PORT of the server")->required();
  add_connection_options(cmd, *connection);
  cmd->add_option("--timeout", *timeout_s, "Seconds to wait for the answer")
      ->capture_default_str()
      ->check(CLI::PositiveNumber);
  cmd->callback([connection, timeout_s] {
    if (int code = run_health_remote(*connection, *timeout_s); code != 0) throw CLI::RuntimeError(code);
  });
}

}  // namespace posewarp::cli
