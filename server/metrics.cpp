// Metrics in Prometheus's text format, served by civetweb.
#include "metrics.h"

#include <civetweb.h>
#include <unistd.h>

#include <cstdio>
#include <fstream>
#include <sstream>

namespace posewarp::server {

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
  }
  if (gauges) {
    for (const auto& [name, value] : gauges()) {
      out << "# TYPE posewarp_" << name << " gauge\nposewarp_" << name << " " << value << "\n";
    }
  }
  out << "# TYPE process_resident_memory_bytes gauge\nprocess_resident_memory_bytes " << resident_bytes() << "\n";
  return out.str();
}

namespace {

int serve_metrics(mg_connection* connection, void* data) {
  const auto* metrics = static_cast<const Metrics*>(data);
  const std::string body = metrics->text();
  mg_printf(connection,
            "HTTP/1.1 200 OK\r\nContent-Type: text/plain; version=0.0.4\r\nContent-Length: %zu\r\n"
            "Connection: close\r\n\r\n",
            body.size());
  mg_write(connection, body.data(), body.size());
  return 200;
}

}  // namespace

MetricsServer::~MetricsServer() {
  if (context_ != nullptr) mg_stop(context_);
}

std::string MetricsServer::start(const std::string& address, const Metrics* metrics) {
  mg_init_library(0);
  const char* options[] = {"listening_ports", address.c_str(), "num_threads", "2", nullptr};
  mg_callbacks callbacks{};
  context_ = mg_start(&callbacks, nullptr, options);
  if (context_ == nullptr) return "cannot serve metrics on " + address + " (in use, or not an address of this machine)";
  mg_set_request_handler(context_, "/metrics", serve_metrics, const_cast<Metrics*>(metrics));
  return "";
}

int64_t resident_bytes() {
  std::ifstream statm("/proc/self/statm");
  int64_t pages = 0, resident = 0;
  statm >> pages >> resident;
  return resident * static_cast<int64_t>(::sysconf(_SC_PAGESIZE));
}

}  // namespace posewarp::server
