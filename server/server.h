// The server as a library: its configuration and run(), which serves until a signal stops it. main.cpp only parses
// the flags into a ServerConfig; tests build a PosewarpService (service.h) over a store of their own instead.
#pragma once

#include <string>

#include "service.h"
#include "store.h"

namespace posewarp::server {

struct ServerConfig {
  std::string listen = "127.0.0.1:50051";  // HOST:PORT; port 0 picks a free one
  std::string store_dir;
  std::string token_file;  // bearer tokens, re-read on SIGHUP; empty: none needed
  std::string tls_cert, tls_key, tls_client_ca;
  std::string metrics_listen;  // HOST:PORT of /metrics; empty: off
  std::string log_level = "info";
  int max_message_mb = 8;  // largest gRPC message received
  int max_streams = 100;   // concurrent streams per client connection
  double grace_s = 30.0;   // on SIGTERM, seconds running poses get to finish
  ServiceOptions service;
  StoreOptions store;
};

// Opens the store, listens and serves until SIGTERM or SIGINT (SIGHUP re-reads the token file), then stops
// gracefully. The process's exit code: 0 after a stop, 2 when the server could not start (the reason on stderr).
int run(const ServerConfig& config);

}  // namespace posewarp::server
