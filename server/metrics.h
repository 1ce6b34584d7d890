// Prometheus metrics: request counts and errors by method and code, latency histograms, and gauges the service
// reports at scrape time; served as text format 0.0.4 on a loopback HTTP port. The HTTP side is a small socket loop
// of our own: Debian's civetweb 1.15 failed to start its first worker thread inside this process.
#pragma once

#include <array>
#include <atomic>
#include <cstdint>
#include <functional>
#include <map>
#include <mutex>
#include <string>
#include <thread>
#include <utility>
#include <vector>


namespace posewarp::server {

class Metrics {
 public:
  // One finished call.
  void observe(const std::string& method, const std::string& code, double seconds);
  void count(const std::string& name, int64_t by = 1);  // a counter without labels (posewarp_<name>_total)
  // Poses answered for a rig (posewarp_rig_poses_total{rig="<first 16 hex digits>"}): behind a load balancer with
  // rig affinity, each rig's count grows on one replica only.
  void count_rig_pose(const std::string& rig_id);
  // Gauges sampled at each scrape: name -> value.
  void set_gauges(std::function<std::vector<std::pair<std::string, double>>()> sample);

  std::string text() const;

 private:
  static constexpr std::array<double, 12> kBuckets{0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30};
  struct Histogram {
    std::array<int64_t, kBuckets.size()> buckets{};
    int64_t count = 0;
    double sum = 0.0;
  };
  mutable std::mutex mutex_;
  std::map<std::pair<std::string, std::string>, int64_t> requests_;  // (method, code)
  std::map<std::string, Histogram> latency_;                         // method
  std::map<std::string, int64_t> counters_;
  std::map<std::string, int64_t> rig_poses_;
  std::function<std::vector<std::pair<std::string, double>>()> gauges_;
};

// GET /metrics on `address` (HOST:PORT; loopback unless the operator says otherwise).
class MetricsServer {
 public:
  MetricsServer() = default;
  ~MetricsServer();
  MetricsServer(const MetricsServer&) = delete;
  MetricsServer& operator=(const MetricsServer&) = delete;
  // An error message, empty on success.
  std::string start(const std::string& address, const Metrics* metrics);

 private:
  int listener_ = -1;
  std::atomic<bool> stopping_{false};
  std::thread thread_;
};

// Resident memory of this process in bytes (/proc/self/statm).
int64_t resident_bytes();

}  // namespace posewarp::server
