// The channel, the calls' metadata, retries and ListRigs paging.
#include "posewarp_client/connection.h"

#include <fstream>
#include <sstream>
#include <thread>

namespace posewarp::client {
namespace {

// A small text file whole (a token, a CA certificate); false when it cannot be read or is over `limit` bytes.
bool read_small_file(const std::string& path, std::string* text, size_t limit = 1 << 20) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return false;
  std::ostringstream content;
  content << in.rdbuf();
  *text = content.str();
  return !in.bad() && text->size() <= limit;
}

}  // namespace

std::unique_ptr<Connection> Connection::open(const Address& address, CallError* error, Retries retries) {
  auto connection = std::unique_ptr<Connection>(new Connection());
  connection->server_ = address.server;
  connection->retries_ = std::move(retries);
  std::shared_ptr<grpc::ChannelCredentials> credentials = grpc::InsecureChannelCredentials();
  if (!address.tls_ca.empty()) {
    grpc::SslCredentialsOptions ssl;
    if (!read_small_file(address.tls_ca, &ssl.pem_root_certs)) {
      *error = {grpc::StatusCode::INVALID_ARGUMENT, "cannot read the TLS CA certificate '" + address.tls_ca + "'"};
      return nullptr;
    }
    credentials = grpc::SslCredentials(ssl);
  }
  if (!address.token_file.empty()) {
    std::string token;
    if (!read_small_file(address.token_file, &token, 1 << 16)) {
      *error = {grpc::StatusCode::INVALID_ARGUMENT, "cannot read the token file '" + address.token_file + "'"};
      return nullptr;
    }
    // The first line (a server's token file may hold several; a client sends one).
    const size_t first = token.find_first_not_of(" \t\r\n");
    if (first == std::string::npos) {
      *error = {grpc::StatusCode::INVALID_ARGUMENT, "the token file '" + address.token_file + "' is empty"};
      return nullptr;
    }
    const size_t end = token.find_first_of("\r\n", first);
    const size_t last = token.find_last_not_of(" \t", end == std::string::npos ? std::string::npos : end - 1);
    connection->token_ = token.substr(first, last - first + 1);
  }
  grpc::ChannelArguments arguments;
  arguments.SetMaxReceiveMessageSize(256 << 20);
  // Reconnect as quickly as the retries try again (gRPC's default first backoff is 1 s, growing to 120 s).
  arguments.SetInt(GRPC_ARG_INITIAL_RECONNECT_BACKOFF_MS, 250);
  arguments.SetInt(GRPC_ARG_MIN_RECONNECT_BACKOFF_MS, 250);
  arguments.SetInt(GRPC_ARG_MAX_RECONNECT_BACKOFF_MS, 2000);
  // A server that vanished without closing is noticed within half a minute, not at the next TCP timeout.
  arguments.SetInt(GRPC_ARG_KEEPALIVE_TIME_MS, 20000);
  arguments.SetInt(GRPC_ARG_KEEPALIVE_TIMEOUT_MS, 10000);
  connection->channel_ = grpc::CreateCustomChannel(address.server, credentials, arguments);
  connection->stub_ = v1::Posewarp::NewStub(connection->channel_);
  return connection;
}

std::unique_ptr<grpc::ClientContext> Connection::context(const std::string& rig_id) const {
  auto context = std::make_unique<grpc::ClientContext>();
  if (!token_.empty()) context->AddMetadata("authorization", "Bearer " + token_);
  if (!rig_id.empty()) context->AddMetadata("x-posewarp-rig", rig_id);
  return context;
}

bool Connection::retryable(const grpc::Status& status) {
  return status.error_code() == grpc::StatusCode::UNAVAILABLE ||
         (status.error_code() == grpc::StatusCode::INTERNAL &&
          status.error_message().find("RST_STREAM") != std::string::npos);
}

grpc::Status Connection::with_retries(const std::function<grpc::Status()>& attempt) const {
  grpc::Status status = attempt();
  for (int retry = 1; retry <= retries_.count && retries_.wait && retryable(status); ++retry) {
    const std::chrono::milliseconds wait = retries_.wait(retry);
    if (retries_.on_wait) retries_.on_wait(status, wait);
    // Connecting meanwhile: the next try starts as soon as the server is back, or when the wait is over.
    const auto until = std::chrono::system_clock::now() + wait;
    if (!channel_->WaitForConnected(until)) std::this_thread::sleep_until(until);
    status = attempt();
  }
  return status;
}

CallError error_of(const grpc::Status& status, const std::string& server) {
  if (status.ok()) return {};
  if (status.error_code() == grpc::StatusCode::UNAVAILABLE) {
    return {status.error_code(), "cannot reach posewarp-server at " + server + ": " + status.error_message() +
                                     " (is it running, and is the address right?)"};
  }
  return {status.error_code(), status.error_message()};
}

CallError Connection::list_rigs(std::vector<v1::Rig>* rigs) const {
  v1::ListRigsRequest request;
  request.set_page_size(1000);
  for (;;) {
    v1::ListRigsResponse page;
    const grpc::Status status = with_retries([&] {
      const auto call = context();
      call->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
      return stub_->ListRigs(call.get(), request, &page);
    });
    if (!status.ok()) return error_of(status);
    rigs->insert(rigs->end(), page.rigs().begin(), page.rigs().end());
    if (page.next_page_token().empty()) return {};
    request.set_page_token(page.next_page_token());
  }
}

}  // namespace posewarp::client
