// The real posewarp-server process for integration tests: started on port 0 (its chosen port read from its first
// line of output) with the test's arguments and environment, its log in a file; stopped by SIGTERM or killed.
#pragma once

#include <arpa/inet.h>
#include <fcntl.h>
#include <grpcpp/grpcpp.h>
#include <netinet/in.h>
#include <signal.h>
#include <sys/socket.h>
#include <sys/wait.h>
#include <unistd.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <map>
#include <string>
#include <thread>
#include <vector>

#include "../support/free_port.h"
#include "posewarp/api/files.h"
#include "posewarp/v1/posewarp.grpc.pb.h"

namespace posewarp::testing_server {

namespace fs = std::filesystem;

inline std::string file_text(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

inline int run(const std::vector<std::string>& args) {
  std::string command;
  for (const std::string& a : args) command += "'" + a + "' ";
  return std::system((command + ">/dev/null 2>&1").c_str());
}

class ServerProcess {
 public:
  ServerProcess(const fs::path& store, std::vector<std::string> extra = {},
                std::map<std::string, std::string> env = {}, const fs::path& log = {}) {
    log_ = log.empty() ? fs::path(store.string() + ".log") : log;
    int out[2];
    if (::pipe(out) != 0) return;
    pid_ = ::fork();
    if (pid_ == 0) {
      ::dup2(out[1], 1);
      ::close(out[0]);
      const int err = ::open(log_.c_str(), O_WRONLY | O_CREAT | O_APPEND, 0644);
      if (err >= 0) ::dup2(err, 2);
      for (const auto& [k, v] : env) ::setenv(k.c_str(), v.c_str(), 1);
      // A port the server picks, unless `extra` names one.
      // POSEWARP_SERVER_BINARY: the server where the build tree's path does not exist (a bench bundle elsewhere).
      const char* binary =
          std::getenv("POSEWARP_SERVER_BINARY") ? std::getenv("POSEWARP_SERVER_BINARY") : POSEWARP_SERVER;
      std::vector<std::string> args{binary, "--store", store.string()};
      if (std::find(extra.begin(), extra.end(), "--listen") == extra.end()) args.insert(args.end(), {"--listen", "127.0.0.1:0"});
      args.insert(args.end(), extra.begin(), extra.end());
      std::vector<char*> argv;
      for (std::string& a : args) argv.push_back(a.data());
      argv.push_back(nullptr);
      ::execv(binary, argv.data());
      ::_exit(127);
    }
    ::close(out[1]);
    std::string line;
    char c = 0;
    while (::read(out[0], &c, 1) == 1 && c != '\n') line += c;
    ::close(out[0]);
    const size_t colon = line.rfind(':', line.find(", store"));
    if (colon != std::string::npos) port_ = std::atoi(line.c_str() + colon + 1);
  }
  ~ServerProcess() { kill(); }
  ServerProcess(const ServerProcess&) = delete;
  ServerProcess& operator=(const ServerProcess&) = delete;

  int port() const { return port_; }
  std::string address() const { return "127.0.0.1:" + std::to_string(port_); }
  pid_t pid() const { return pid_; }
  std::string log() const { return file_text(log_); }
  // kill -9, as a crash.
  void kill() {
    if (pid_ > 0 && !stopped_) {
      ::kill(pid_, SIGKILL);
      ::waitpid(pid_, nullptr, 0);
      stopped_ = true;
    }
  }
  void signal(int number) const { ::kill(pid_, number); }
  // SIGTERM, then the exit code (or -1 after 60 s).
  int stop() {
    ::kill(pid_, SIGTERM);
    return wait_exit(60);
  }
  int wait_exit(int seconds) {
    for (int i = 0; i < seconds * 20; ++i) {
      int status = 0;
      if (::waitpid(pid_, &status, WNOHANG) == pid_) {
        stopped_ = true;
        return WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
      }
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    return -1;
  }
  // Waits until the log holds `text` (true) or `seconds` pass (false).
  bool wait_for_log(const std::string& text, int seconds) const {
    for (int i = 0; i < seconds * 20; ++i) {
      if (log().find(text) != std::string::npos) return true;
      std::this_thread::sleep_for(std::chrono::milliseconds(50));
    }
    return false;
  }

  std::shared_ptr<grpc::Channel> channel(std::shared_ptr<grpc::ChannelCredentials> credentials = nullptr) const {
    grpc::ChannelArguments arguments;
    arguments.SetMaxReceiveMessageSize(64 << 20);
    auto ch = grpc::CreateCustomChannel(address(), credentials ? credentials : grpc::InsecureChannelCredentials(),
                                        arguments);
    ch->WaitForConnected(std::chrono::system_clock::now() + std::chrono::seconds(60));  // a loaded CI machine
    return ch;
  }

 private:
  pid_t pid_ = -1;
  int port_ = 0;
  bool stopped_ = false;
  fs::path log_;
};

// Client helpers over the generated stub.
inline grpc::Status upload(v1::Posewarp::Stub& stub, const fs::path& path, v1::VolumeKind kind, v1::Volume* volume,
                           const std::string& token = "") {
  const std::string bytes = file_text(path);
  grpc::ClientContext context;
  if (!token.empty()) context.AddMetadata("authorization", "Bearer " + token);
  auto writer = stub.UploadVolume(&context, volume);
  v1::UploadVolumeRequest header;
  header.mutable_header()->set_kind(kind);
  header.mutable_header()->set_format(v1::FILE_FORMAT_NIFTI_GZ);
  header.mutable_header()->set_size_bytes(bytes.size());
  header.mutable_header()->set_sha256(sha256_hex(bytes));
  writer->Write(header);
  for (size_t offset = 0; offset < bytes.size(); offset += 1 << 16) {
    v1::UploadVolumeRequest chunk;
    chunk.set_chunk(bytes.substr(offset, 1 << 16));
    writer->Write(chunk);
  }
  writer->WritesDone();
  return writer->Finish();
}

// A rig file through UploadRig: its header (size, claimed SHA-256, name), then 1 MiB chunks.
inline grpc::Status upload_rig(v1::Posewarp::Stub& stub, const std::string& bytes, const std::string& claimed_sha,
                               v1::Rig* rig, const std::string& name = "") {
  grpc::ClientContext context;
  auto writer = stub.UploadRig(&context, rig);
  v1::UploadRigRequest part;
  part.mutable_header()->set_size_bytes(bytes.size());
  part.mutable_header()->set_sha256(claimed_sha);
  part.mutable_header()->set_name(name);
  writer->Write(part);
  for (size_t offset = 0; offset < bytes.size(); offset += 1 << 20) {
    v1::UploadRigRequest chunk;
    chunk.set_chunk(bytes.substr(offset, 1 << 20));
    writer->Write(chunk);
  }
  writer->WritesDone();
  return writer->Finish();
}

// What a command prints on stdout.
inline std::string output_of(const std::vector<std::string>& args) {
  std::string command;
  for (const std::string& a : args) command += "'" + a + "' ";
  std::string out;
  if (FILE* pipe = ::popen((command + "2>/dev/null").c_str(), "r")) {
    char buffer[4096];
    for (size_t n; (n = std::fread(buffer, 1, sizeof buffer, pipe)) > 0;) out.append(buffer, n);
    ::pclose(pipe);
  }
  return out;
}

// Follows an operation to its final state.
inline v1::Operation watch(v1::Posewarp::Stub& stub, const std::string& operation_id) {
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::minutes(5));
  v1::GetOperationRequest request;
  request.set_operation_id(operation_id);
  auto reader = stub.WatchOperation(&context, request);
  v1::Operation state, last;
  while (reader->Read(&state)) last = state;
  reader->Finish();
  return last;
}

struct PoseAnswer {
  grpc::Status status;
  v1::PoseHeader header;
  std::string labels, ct, inverse_field, forward_field;
  int surfaces = 0;
  v1::Surface last_surface;
  v1::QualityReport report;
};

inline PoseAnswer pose_remote(v1::Posewarp::Stub& stub, const v1::PoseRequest& request,
                       std::chrono::milliseconds deadline = std::chrono::minutes(5)) {
  PoseAnswer answer;
  grpc::ClientContext context;
  context.set_deadline(std::chrono::system_clock::now() + deadline);
  auto reader = stub.Pose(&context, request);
  v1::PoseResponse part;
  while (reader->Read(&part)) {
    if (part.has_header()) {
      answer.header = part.header();
      answer.labels.reserve(answer.header.label_bytes());
      answer.ct.reserve(answer.header.ct_bytes());
    }
    if (part.has_labels()) answer.labels += part.labels().data();
    if (part.has_ct()) answer.ct += part.ct().data();
    if (part.has_inverse_field()) answer.inverse_field += part.inverse_field().data();
    if (part.has_forward_field()) answer.forward_field += part.forward_field().data();
    if (part.has_surface()) {
      ++answer.surfaces;
      answer.last_surface = part.surface();
    }
    if (part.has_report()) answer.report = part.report();
  }
  answer.status = reader->Finish();
  return answer;
}

using testing_support::free_port;  // for the metrics listener, which cannot pick its own

// GET /metrics over a plain socket: the Prometheus text (empty when nothing answers).
inline std::string scrape_metrics(int port) {
  const int fd = ::socket(AF_INET, SOCK_STREAM, 0);
  sockaddr_in address{};
  address.sin_family = AF_INET;
  address.sin_addr.s_addr = htonl(INADDR_LOOPBACK);
  address.sin_port = htons(static_cast<uint16_t>(port));
  std::string response;
  if (::connect(fd, reinterpret_cast<sockaddr*>(&address), sizeof address) == 0) {
    const std::string request = "GET /metrics HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n";
    if (::write(fd, request.data(), request.size()) == static_cast<ssize_t>(request.size())) {
      char buffer[4096];
      for (ssize_t n; (n = ::read(fd, buffer, sizeof buffer)) > 0;) response.append(buffer, static_cast<size_t>(n));
    }
  }
  ::close(fd);
  const size_t body = response.find("\r\n\r\n");
  return body == std::string::npos ? "" : response.substr(body + 4);
}

// The value of one metric line ("name{labels}" exactly as printed), or -1.
inline double metric(const std::string& text, const std::string& name) {
  const size_t at = text.find("\n" + name + " ");
  return at == std::string::npos ? -1.0 : std::atof(text.c_str() + at + name.size() + 2);
}

}  // namespace posewarp::testing_server
