// Scale-out measured on loopback with the real processes: PostgreSQL (the shared index), posewarp-server replicas on
// one store, and nginx with docker/nginx/posewarp.conf.template. Poses of the real sample (labels + CT) by 16
// clients through nginx with 1 and 2 replicas (throughput and p99), one client directly and through nginx (what the
// proxy adds per pose), and a rig's first pose on a replica that just started against its later poses (cold and warm
// cache). The rigs: the sample's rig and copies of it that differ only in a parameter note (so they hash to different
// ids and spread over the replicas as different patients' rigs would).
// Usage: posewarp_bench_scaleout [--rigs N] [--poses-per-client P]
#include <cstring>
#include <future>
#include <iostream>

#include <nlohmann/json.hpp>

#include "../tests/integration/support/cluster.h"
#include "bench_rigs.h"
#include "posewarp/api/rig_file.h"
#include "server_process.h"

namespace {

using namespace posewarp;
using namespace posewarp::testing_server;
using Clock = std::chrono::steady_clock;
using bench::percentile;

double ms_since(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

v1::PoseRequest pose_request(const std::string& rig_id, const std::string& pose_json) {
  v1::PoseRequest request;
  request.set_rig_id(rig_id);
  request.set_pose_json(pose_json);
  request.set_want_labels(true);
  request.set_want_ct(true);
  return request;
}

// One pose through `channel` with the rig id as metadata (as the clients send it for nginx's hash).
double timed_pose(v1::Posewarp::Stub& stub, const v1::PoseRequest& request) {
  grpc::ClientContext context;
  context.AddMetadata("x-posewarp-rig", request.rig_id());
  context.set_deadline(std::chrono::system_clock::now() + std::chrono::minutes(5));
  const auto start = Clock::now();
  auto reader = stub.Pose(&context, request);
  v1::PoseResponse part;
  while (reader->Read(&part)) {
  }
  const grpc::Status status = reader->Finish();
  if (!status.ok()) throw std::runtime_error("pose: " + status.error_message());
  return ms_since(start);
}

std::shared_ptr<grpc::Channel> channel_to(const std::string& address) {
  grpc::ChannelArguments arguments;
  arguments.SetMaxReceiveMessageSize(64 << 20);
  arguments.SetInt("grpc.use_local_subchannel_pool", 1);  // each client its own connection
  auto channel = grpc::CreateCustomChannel(address, grpc::InsecureChannelCredentials(), arguments);
  channel->WaitForConnected(std::chrono::system_clock::now() + std::chrono::seconds(30));
  return channel;
}

// `clients` clients, each on its own connection, posing rig (client % rigs) `per_client` times.
nlohmann::json load(const std::string& address, const std::vector<std::string>& rigs, const std::string& pose_json,
                    int clients, int per_client) {
  std::vector<std::future<std::vector<double>>> running;
  const auto start = Clock::now();
  for (int c = 0; c < clients; ++c) {
    running.push_back(std::async(std::launch::async, [&, c] {
      auto stub = v1::Posewarp::NewStub(channel_to(address));
      const v1::PoseRequest request = pose_request(rigs[c % rigs.size()], pose_json);
      std::vector<double> ms;
      for (int i = 0; i < per_client; ++i) ms.push_back(timed_pose(*stub, request));
      return ms;
    }));
  }
  std::vector<double> all;
  for (auto& r : running) {
    const std::vector<double> ms = r.get();
    all.insert(all.end(), ms.begin(), ms.end());
  }
  const double wall_s = ms_since(start) / 1e3;
  return {{"poses", all.size()},
          {"poses_per_s", static_cast<double>(all.size()) / wall_s},
          {"p50_ms", percentile(all, 50)},
          {"p99_ms", percentile(all, 99)}};
}

}  // namespace

int main(int argc, char** argv) {
  int rig_count = 4, per_client = 4;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--rigs") && i + 1 < argc) {
      rig_count = std::max(1, std::atoi(argv[++i]));
    } else if (!std::strcmp(argv[i], "--poses-per-client") && i + 1 < argc) {
      per_client = std::max(1, std::atoi(argv[++i]));
    } else {
      std::fprintf(stderr, "usage: %s [--rigs N] [--poses-per-client P]\n", argv[0]);
      return 2;
    }
  }
  const fs::path work = fs::temp_directory_path() / ("posewarp-bench-scaleout-" + std::to_string(::getpid()));
  fs::create_directories(work);
  nlohmann::json out;
  try {
    testing_support::PostgresCluster database(work / "postgres");
    if (!database.ok()) throw std::runtime_error(database.error());
    const std::string pose_json = file_text(fs::path(POSEWARP_SOURCE_DIR) / "data/poses/sample_hip_flexion.json");

    // The rigs: the sample's, and copies with a parameter note of their own.
    const std::string sample = bench::sample_rig_bytes(POSEWARP_SAMPLE_DIR);
    std::vector<std::string> rig_files;
    for (int k = 0; k < rig_count; ++k) {
      Result<api::Rig> rig = api::rig_from_bytes(sample, "sample");
      if (!rig.ok()) throw std::runtime_error(rig.status().to_string());
      if (k > 0) {
        nlohmann::json params = nlohmann::json::parse(rig->params_json);
        params["bench_copy"] = k;
        rig->params_json = params.dump();
      }
      rig_files.push_back(api::rig_to_bytes(*rig));
    }

    auto start_replica = [&](const std::string& name) {
      auto server = std::make_unique<ServerProcess>(
          work / "store",
          std::vector<std::string>{"--database", database.conninfo(), "--replica", name, "--pose-queue", "64"},
          std::map<std::string, std::string>{}, work / (name + ".log"));
      if (server->port() == 0) throw std::runtime_error(name + " did not start: " + server->log());
      return server;
    };
    auto r1 = start_replica("r1");
    auto r2 = start_replica("r2");
    std::vector<std::string> rigs;
    {
      auto stub = v1::Posewarp::NewStub(r1->channel());
      for (const std::string& bytes : rig_files) {
        v1::Rig uploaded;
        if (grpc::Status s = upload_rig(*stub, bytes, sha256_hex(bytes), &uploaded); !s.ok()) {
          throw std::runtime_error("rig upload: " + s.error_message());
        }
        rigs.push_back(uploaded.id());
      }
    }
    std::printf("the sample's rig x%d (%.1f MB each), labels + CT per pose\n", rig_count,
                static_cast<double>(sample.size()) / 1e6);

    // Cold and warm: a rig's first pose on a replica (store read, checks, engine made) and its later ones.
    {
      auto stub = v1::Posewarp::NewStub(channel_to(r1->address()));
      const v1::PoseRequest request = pose_request(rigs[0], pose_json);
      const double cold = timed_pose(*stub, request);
      std::vector<double> warm;
      for (int i = 0; i < 8; ++i) warm.push_back(timed_pose(*stub, request));
      out["cold_ms"] = cold;
      out["warm_ms"] = {{"p50", percentile(warm, 50)}, {"p99", percentile(warm, 99)}};
      std::printf("cold cache: first pose on a replica %.0f ms; warm: p50 %.1f ms, p99 %.1f ms\n", cold,
                  percentile(warm, 50), percentile(warm, 99));
    }

    // What nginx adds: one client, one rig, directly and through nginx with one replica.
    {
      testing_support::NginxProxy nginx(work / "nginx-direct", POSEWARP_SOURCE_DIR, {r1->address()});
      if (!nginx.ok()) throw std::runtime_error(nginx.error());
      const v1::PoseRequest request = pose_request(rigs[0], pose_json);
      std::vector<double> direct, proxied;
      auto direct_stub = v1::Posewarp::NewStub(channel_to(r1->address()));
      auto proxied_stub = v1::Posewarp::NewStub(channel_to(nginx.address()));
      (void)timed_pose(*proxied_stub, request);
      for (int i = 0; i < 20; ++i) {  // interleaved, so both see the same machine
        direct.push_back(timed_pose(*direct_stub, request));
        proxied.push_back(timed_pose(*proxied_stub, request));
      }
      out["direct_ms"] = {{"p50", percentile(direct, 50)}, {"p99", percentile(direct, 99)}};
      out["nginx_ms"] = {{"p50", percentile(proxied, 50)}, {"p99", percentile(proxied, 99)}};
      std::printf(
          "one client, one rig: direct p50 %.1f ms p99 %.1f | through nginx p50 %.1f ms p99 %.1f "
          "(+%.1f ms per pose)\n",
          percentile(direct, 50), percentile(direct, 99), percentile(proxied, 50), percentile(proxied, 99),
          percentile(proxied, 50) - percentile(direct, 50));
    }

    // 16 clients through nginx, 1 replica, then 2 (each warmed first: every rig posed once on its replica).
    for (const int replicas : {1, 2}) {
      std::vector<std::string> upstreams{r1->address()};
      if (replicas == 2) upstreams.push_back(r2->address());
      testing_support::NginxProxy nginx(work / ("nginx-" + std::to_string(replicas)), POSEWARP_SOURCE_DIR, upstreams);
      if (!nginx.ok()) throw std::runtime_error(nginx.error());
      (void)load(nginx.address(), rigs, pose_json, static_cast<int>(rigs.size()), 1);  // warm
      nlohmann::json row = load(nginx.address(), rigs, pose_json, 16, per_client);
      row["replicas"] = replicas;
      out["through_nginx"].push_back(row);
      std::printf("16 clients, %d rigs, %d replica(s) through nginx: %.2f poses/s, p50 %.0f ms, p99 %.0f ms\n",
                  rig_count, replicas, row["poses_per_s"].get<double>(), row["p50_ms"].get<double>(),
                  row["p99_ms"].get<double>());
      std::fflush(stdout);
    }
    const double one = out["through_nginx"][0]["poses_per_s"], two = out["through_nginx"][1]["poses_per_s"];
    out["two_over_one"] = two / one;
    std::printf("2 replicas / 1 replica: x%.2f (both share this machine's %u cores)\n", two / one,
                std::thread::hardware_concurrency());
    r1->stop();
    r2->stop();
  } catch (const std::exception& error) {
    std::fprintf(stderr, "posewarp_bench_scaleout: %s\n", error.what());
    fs::remove_all(work);
    return 1;
  }
  std::cout << out.dump(2) << "\n";
  fs::remove_all(work);
  return 0;
}
