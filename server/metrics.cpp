// Metrics in Prometheus's text format, served over plain HTTP/1.1 on a loopback socket.
#include "metrics.h"

#include <arpa/inet.h>
#include <netinet/in.h>
#include <poll.h>
#include <sys/socket.h>
#include <sys/time.h>
#include <unistd.h>

#include <cerrno>
#include <cmath>
#include <cstdint>
#include <cstring>

#include <cstdio>
#include <fstream>
#include <sstream>

namespace posewarp::server {
namespace {

// A gauge's value as the text format wants it, exactly: a whole number (bytes, counts) in all its digits, anything
// else in as many as round-trip a double (the stream's default six digits printed 16777216 bytes as 1.67772e+07).
std::string gauge_value(double value) {
  if (std::abs(value) < 9007199254740992.0 && value == std::floor(value)) {
    return std::to_string(static_cast<int64_t>(value));
  }
  char text[32];
  std::snprintf(text, sizeof text, "%.17g", value);
  return text;
}

}  // namespace

void Metrics::observe(const std::string& method, const std::string& code, double seconds) {
  std::lock_guard<std::mutex> lock(mutex_);
  ++requests_[{method, code}];
  Histogram& h = latency_[method];
  for (size_t b = 0; b < kBuckets.size(); ++b) {
    if (seconds <= kBuckets[b]) ++h.buckets[b];
  }
  ++h.count;
  h.sum += seconds;
}

void Metrics::count(const std::string& name, int64_t by) {
  std::lock_guard<std::mutex> lock(mutex_);
  counters_[name] += by;
}

void Metrics::count_rig_pose(const std::string& rig_id) {
  std::lock_guard<std::mutex> lock(mutex_);
  ++rig_poses_[rig_id.substr(0, 16)];
}

void Metrics::set_gauges(std::function<std::vector<std::pair<std::string, double>>()> sample) {
  std::lock_guard<std::mutex> lock(mutex_);
  gauges_ = std::move(sample);
}

std::string Metrics::text() const {
  std::function<std::vector<std::pair<std::string, double>>()> gauges;
  std::ostringstream out;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    gauges = gauges_;
    out << "# HELP posewarp_requests_total gRPC calls by method and status code.\n"
           "# TYPE posewarp_requests_total counter\n";
    for (const auto& [key, n] : requests_) {
      out << "posewarp_requests_total{method=\"" << key.first << "\",code=\"" << key.second << "\"} " << n << "\n";
    }
    out << "# HELP posewarp_request_seconds gRPC call latency by method.\n"
           "# TYPE posewarp_request_seconds histogram\n";
    for (const auto& [method, h] : latency_) {
      for (size_t b = 0; b < kBuckets.size(); ++b) {
        out << "posewarp_request_seconds_bucket{method=\"" << method << "\",le=\"" << kBuckets[b] << "\"} "
            << h.buckets[b] << "\n";
      }
      out << "posewarp_request_seconds_bucket{method=\"" << method << "\",le=\"+Inf\"} " << h.count << "\n";
      out << "posewarp_request_seconds_sum{method=\"" << method << "\"} " << h.sum << "\n";
      out << "posewarp_request_seconds_count{method=\"" << method << "\"} " << h.count << "\n";
    }
    for (const auto& [name, n] : counters_) {
      out << "# TYPE posewarp_" << name << "_total counter\nposewarp_" << name << "_total " << n << "\n";
    }
    if (!rig_poses_.empty()) out << "# TYPE posewarp_rig_poses_total counter\n";
    for (const auto& [rig, n] : rig_poses_) out << "posewarp_rig_poses_total{rig=\"" << rig << "\"} " << n << "\n";
  }
  if (gauges) {
    for (const auto& [name, value] : gauges()) {
      out << "# TYPE posewarp_" << name << " gauge\nposewarp_" << name << " " << gauge_value(value) << "\n";
    }
  }
  out << "# TYPE process_resident_memory_bytes gauge\nprocess_resident_memory_bytes " << resident_bytes() << "\n";
  return out.str();
}

namespace {

// One request per connection: read the request head, answer GET /metrics (anything else 404), close.
void answer(int fd, const Metrics& metrics) {
  timeval timeout{2, 0};
  ::setsockopt(fd, SOL_SOCKET, SO_RCVTIMEO, &timeout, sizeof timeout);
  std::string head;
  char buffer[1024];
  while (head.find("\r\n\r\n") == std::string::npos && head.size() < 8192) {
    const ssize_t n = ::read(fd, buffer, sizeof buffer);
    if (n <= 0) return;
    head.append(buffer, static_cast<size_t>(n));
  }
  const bool wanted = head.rfind("GET /metrics ", 0) == 0 || head.rfind("GET /metrics?", 0) == 0;
  const std::string body = wanted ? metrics.text() : "not found: metrics are at /metrics\n";
  const std::string response = std::string(wanted ? "HTTP/1.1 200 OK\r\n" : "HTTP/1.1 404 Not Found\r\n") +
                               "Content-Type: text/plain; version=0.0.4\r\nContent-Length: " +
                               std::to_string(body.size()) + "\r\nConnection: close\r\n\r\n" + body;
  for (size_t sent = 0; sent < response.size();) {
    const ssize_t n = ::send(fd, response.data() + sent, response.size() - sent, MSG_NOSIGNAL);
    if (n <= 0) return;
    sent += static_cast<size_t>(n);
  }
}

}  // namespace

MetricsServer::~MetricsServer() {
  stopping_ = true;
  if (thread_.joinable()) thread_.join();
  if (listener_ >= 0) ::close(listener_);
}

std::string MetricsServer::start(const std::string& address, const Metrics* metrics) {
  const size_t colon = address.rfind(':');
  const std::string host = colon == std::string::npos ? "" : address.substr(0, colon);
  const int port = colon == std::string::npos ? -1 : std::atoi(address.c_str() + colon + 1);
  sockaddr_in where{};
  where.sin_family = AF_INET;
  where.sin_port = htons(static_cast<uint16_t>(port));
  if (port <= 0 || port > 65535 || ::inet_pton(AF_INET, host == "localhost" ? "127.0.0.1" : host.c_str(),
                                                &where.sin_addr) != 1) {
    return "--metrics-listen takes IPV4:PORT (e.g. 127.0.0.1:9464), not '" + address + "'";
  }
  listener_ = ::socket(AF_INET, SOCK_STREAM | SOCK_CLOEXEC, 0);
  const int yes = 1;
  ::setsockopt(listener_, SOL_SOCKET, SO_REUSEADDR, &yes, sizeof yes);
  if (listener_ < 0 || ::bind(listener_, reinterpret_cast<sockaddr*>(&where), sizeof where) != 0 ||
      ::listen(listener_, 16) != 0) {
    return "cannot serve metrics on " + address + ": " + std::strerror(errno);
  }
  thread_ = std::thread([this, metrics] {
    while (!stopping_) {
      pollfd ready{listener_, POLLIN, 0};
      if (::poll(&ready, 1, 200) <= 0) continue;
      const int fd = ::accept4(listener_, nullptr, nullptr, SOCK_CLOEXEC);
      if (fd < 0) continue;
      answer(fd, *metrics);
      ::close(fd);
    }
  });
  return "";
}

int64_t resident_bytes() {
  std::ifstream statm("/proc/self/statm");
  int64_t pages = 0, resident = 0;
  statm >> pages >> resident;
  return resident * static_cast<int64_t>(::sysconf(_SC_PAGESIZE));
}

}  // namespace posewarp::server
