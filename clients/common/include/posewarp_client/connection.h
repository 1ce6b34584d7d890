// posewarp's client side of the wire, one for every C++ client (the CLI's remote mode and batch, posewarp-view, the
// benches): the channel with TLS and the bearer token, the metadata every call carries, calls tried again while the
// server is unavailable, ListRigs paged to its end, and a Pose answer read and checked (pose_answer.h). It speaks the
// proto only and links no core/ (DESIGN.md: remote clients never link the engine).
#pragma once

#include <grpcpp/grpcpp.h>

#include <chrono>
#include <functional>
#include <memory>
#include <string>
#include <vector>

#include "posewarp/v1/posewarp.grpc.pb.h"

namespace posewarp::client {

struct Address {
  std::string server;      // HOST:PORT
  std::string token_file;  // its first line is the bearer token; empty: no token
  std::string tls_ca;      // PEM of the CA that signed the server's certificate; empty: plaintext
};

// A call that failed, as the user should read it (the server's code and message; UNAVAILABLE says where it tried).
struct CallError {
  grpc::StatusCode code = grpc::StatusCode::OK;
  std::string message;
  bool failed() const { return code != grpc::StatusCode::OK; }
};

// When a call that may pass is tried again: up to `count` more times, waiting wait(n) before try n + 1 (the caller's
// policy: the CLI's is core/common's RetryPolicy). `on_wait` hears of each wait (the CLI says it on stderr).
struct Retries {
  int count = 0;
  std::function<std::chrono::milliseconds(int retry)> wait;
  std::function<void(const grpc::Status& failed, std::chrono::milliseconds wait)> on_wait;
};

// A failed status as the user should read it: UNAVAILABLE says which server it could not reach (OK stays OK).
CallError error_of(const grpc::Status& status, const std::string& server);

class Connection {
 public:
  // The channel; the token and CA files are read here (an error names the file).
  static std::unique_ptr<Connection> open(const Address& address, CallError* error, Retries retries = {});

  const std::string& server() const { return server_; }
  v1::Posewarp::Stub& stub() const { return *stub_; }
  const std::shared_ptr<grpc::Channel>& channel() const { return channel_; }
  // A call's context: the bearer token, and the rig id (so that a load balancer keeps each rig on one replica).
  std::unique_ptr<grpc::ClientContext> context(const std::string& rig_id = "") const;

  // Runs `attempt` (one whole call, streams included) again while it fails with a status that may pass, as the
  // Retries say; the channel reconnects meanwhile, so the next try starts as soon as the server is back.
  grpc::Status with_retries(const std::function<grpc::Status()>& attempt) const;
  // UNAVAILABLE (no server, or a proxy with no replica to reach), or a stream a proxy cut in the middle of its answer
  // because its replica went away (nginx resets the stream: INTERNAL, "RST_STREAM"). Every call of the service is safe
  // to repeat: uploads and rigs are content-addressed, a build joins its operation, poses only read.
  static bool retryable(const grpc::Status& status);

  // A unary call with the token and the rig id, with retries.
  template <typename Request, typename Response>
  grpc::Status unary(grpc::Status (v1::Posewarp::Stub::*method)(grpc::ClientContext*, const Request&, Response*),
                     const Request& request, Response* response, const std::string& rig_id = "") const {
    return with_retries([&] {
      const auto call = context(rig_id);
      return ((*stub_).*method)(call.get(), request, response);
    });
  }

  CallError error_of(const grpc::Status& status) const { return client::error_of(status, server_); }
  // Every rig the server holds, all pages.
  CallError list_rigs(std::vector<v1::Rig>* rigs) const;

 private:
  Connection() = default;
  std::string server_, token_;
  Retries retries_;
  std::shared_ptr<grpc::Channel> channel_;
  std::unique_ptr<v1::Posewarp::Stub> stub_;
};

}  // namespace posewarp::client
