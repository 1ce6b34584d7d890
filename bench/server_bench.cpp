// The service measured through the real posewarp-server on loopback: pose latency through the server against the
// same pose in process (labels + CT returned), throughput with 1, 4 and 16 clients, preview round trips, upload
// throughput, rig load time from the store, and the server's memory over 100 poses. On the real sample and on the
// mannequin phantom.
// Usage: posewarp_bench_server [--mannequin-mvoxels M (0 = skip)] [--body-mvoxels M (0 = skip, the default)]
//                              [--repeats R] [--latency-only] [--rig-cache DIR (keeps the phantoms' rigs between runs)]
//                              [--pose-threads N (the server's --pose-threads and the same in process: 1 on 2 cores
//                              leaves the client a core of its own)]
//                              [--source-dir DIR (the repository, for its data/ where the build tree is not)]
// Elsewhere than the build tree (a bundle on a bigger machine), POSEWARP_SERVER_BINARY names the server to start.
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstring>
#include <future>
#include <iostream>

#include "posewarp/api/files.h"
#include "posewarp/api/pose_engine.h"
#include "posewarp/api/rig_file.h"
#include "posewarp_client/connection.h"
#include "posewarp_client/pose_answer.h"
#include "posewarp/phantom/phantom.h"
#include "bench_rigs.h"
#include "server_process.h"

namespace {

using namespace posewarp;
using namespace posewarp::testing_server;
using bench::percentile;

// A client's connection to the server under test, as the CLI and the viewer make theirs.
std::unique_ptr<client::Connection> connect_to(const ServerProcess& server) {
  client::CallError error;
  std::unique_ptr<client::Connection> connection =
      client::Connection::open({"127.0.0.1:" + std::to_string(server.port())}, &error);
  if (!connection) throw std::runtime_error(error.message);
  return connection;
}

nlohmann::json bench_case(const std::string& name, const fs::path& work, const std::string& rig_bytes,
                          const std::string& pose_json, int repeats, bool latency_only, int pose_threads) {
  nlohmann::json row{{"case", name}};
  // In process: the engine posing labels + CT, as the server will.
  Result<api::Rig> rig = api::rig_from_bytes(rig_bytes, name);
  if (!rig.ok()) throw std::runtime_error(rig.status().to_string());
  const int64_t voxels = rig->source_geometry.voxel_count();
  row["voxels"] = voxels;
  Result<api::PoseEngine> engine = api::PoseEngine::create(std::move(rig).value());
  api::PoseRequest local;
  local.pose = *api::pose_from_json(pose_json, "bench pose");
  local.want_surfaces = false;  // as the server request below: labels + CT
  ProgressHooks hooks;
  hooks.threads = pose_threads;
  // One pose in process, timed; the stages of the last.
  std::vector<double> local_ms;
  auto pose_locally = [&](bool last) {
    const api::Stopwatch start;
    Result<api::PoseResult> result = engine->pose(local, hooks);
    if (!result.ok()) throw std::runtime_error(result.status().to_string());
    local_ms.push_back(1e3 * start.seconds());
    if (last) {
      std::printf("%-12s local stages (ms):", name.c_str());
      for (const auto& [stage, seconds] : result->report.stage_seconds)
        std::printf(" %s %.1f", stage.c_str(), 1e3 * seconds);
      std::printf("\n");
    }
  };

  const fs::path store = work / ("store-" + name);
  const int metrics_port = free_port();
  std::vector<std::string> server_args{"--metrics-listen", "127.0.0.1:" + std::to_string(metrics_port), "--pose-queue",
                                       "64"};
  if (pose_threads > 0) server_args.insert(server_args.end(), {"--pose-threads", std::to_string(pose_threads)});
  ServerProcess server(store, server_args, {}, work / (name + "-server.log"));
  if (server.port() == 0) throw std::runtime_error("the server did not start: " + server.log());
  auto stub = v1::Posewarp::NewStub(server.channel());
  const std::unique_ptr<client::Connection> connection = connect_to(server);  // poses: the clients' own library
  // Rig upload, then the rig's first load from the store (a cold cache: read, check, engine created).
  v1::Rig uploaded;
  const api::Stopwatch upload_start;
  if (grpc::Status s = upload_rig(*stub, rig_bytes, sha256_hex(rig_bytes), &uploaded); !s.ok()) throw std::runtime_error(s.error_message());
  const double upload_s = upload_start.seconds();
  row["rig_mb"] = static_cast<double>(rig_bytes.size()) / 1e6;
  row["upload_mb_per_s"] = static_cast<double>(rig_bytes.size()) / 1e6 / upload_s;
  {
    ServerProcess cold(store.string() + "-cold", {}, {}, work / (name + "-cold.log"));
    auto cold_stub = v1::Posewarp::NewStub(cold.channel());
    v1::Rig again;
    if (!upload_rig(*cold_stub, rig_bytes, sha256_hex(rig_bytes), &again).ok()) throw std::runtime_error("upload to the cold server failed");
    cold.stop();
  }
  const api::Stopwatch load_start;
  Result<api::Rig> loaded = api::load_rig((store / "rigs" / (uploaded.id() + ".rig")).string());
  row["rig_load_ms"] = 1e3 * load_start.seconds();
  {
    grpc::ClientContext context;
    v1::GetRigRequest get;
    get.set_rig_id(uploaded.id());
    v1::Rig info;
    const api::Stopwatch start;
    if (!stub->GetRig(&context, get, &info).ok()) throw std::runtime_error("GetRig failed");
    row["first_get_rig_ms"] = 1e3 * start.seconds();  // load + engine create, through the server
  }

  v1::PoseRequest request;
  request.set_rig_id(uploaded.id());
  request.set_pose_json(pose_json);
  request.set_want_labels(true);
  request.set_want_ct(true);
  // The labels as runs (what the CLI and the Python client ask for), each repeat also once as one sample per voxel.
  request.set_label_encoding(v1::LABEL_ENCODING_RUNS);
  v1::PoseRequest as_samples = request;
  as_samples.set_label_encoding(v1::LABEL_ENCODING_SAMPLES);
  // Each repeat poses in process, then through the server twice, so that the machine's drift falls on all three.
  std::vector<double> server_ms, samples_ms;
  for (int r = 0; r < repeats; ++r) {
    pose_locally(r + 1 == repeats);
    {
      const api::Stopwatch start;
      client::PoseAnswer answer;
      if (const client::CallError e = client::pose(*connection, as_samples, &answer); e.failed())
        throw std::runtime_error(e.message);
      samples_ms.push_back(1e3 * start.seconds());
    }
    const api::Stopwatch start;
    client::PoseAnswer answer;
    if (const client::CallError e = client::pose(*connection, request, &answer); e.failed()) throw std::runtime_error(e.message);
    server_ms.push_back(1e3 * start.seconds());
    row["volume_mb_per_pose"] = static_cast<double>(answer.labels.size() + answer.ct.size()) / 1e6;
    // The labels' bytes as runs: each run one (value, uint32 count) pair (no run is split between chunks).
    const size_t sample = client::sample_bytes(answer.header.label_sample_type());
    size_t runs = answer.labels.empty() ? 0 : 1;
    for (size_t at = sample; sample > 0 && at < answer.labels.size(); at += sample)
      runs += std::memcmp(answer.labels.data() + at, answer.labels.data() + at - sample, sample) != 0;
    row["label_mb_per_pose"] = {{"samples", static_cast<double>(answer.labels.size()) / 1e6},
                                {"runs", static_cast<double>(runs * (sample + 4)) / 1e6}};
    if (r + 1 == repeats) {
      const nlohmann::json report = nlohmann::json::parse(answer.report.json());
      std::printf("%-12s server stages (ms):", name.c_str());
      for (const auto& [stage, seconds] : report["stage_seconds"].items()) std::printf(" %s %.1f", stage.c_str(), 1e3 * seconds.get<double>());
      std::printf("\n");
    }
  }
  row["local_ms"] = {{"p50", percentile(local_ms, 50)}, {"p99", percentile(local_ms, 99)}};
  row["server_ms"] = {{"p50", percentile(server_ms, 50)}, {"p99", percentile(server_ms, 99)}};
  row["server_over_local"] = percentile(server_ms, 50) / percentile(local_ms, 50);
  row["server_labels_as_samples_ms"] = {{"p50", percentile(samples_ms, 50)}, {"p99", percentile(samples_ms, 99)}};
  std::printf("%-12s %9lld voxels  pose labels+CT: local p50 %7.1f ms p99 %7.1f | server p50 %7.1f ms p99 %7.1f "
              "(x%.2f), %.1f MB of labels + CT per pose\n",
              name.c_str(), static_cast<long long>(voxels), percentile(local_ms, 50), percentile(local_ms, 99),
              percentile(server_ms, 50), percentile(server_ms, 99), percentile(server_ms, 50) / percentile(local_ms, 50),
              row["volume_mb_per_pose"].get<double>());
  std::printf("%-12s the same with labels as one sample per voxel instead of runs: server p50 %7.1f ms p99 %7.1f (x%.2f); "
              "labels %.2f MB as samples, %.2f MB as runs\n",
              name.c_str(), percentile(samples_ms, 50), percentile(samples_ms, 99),
              percentile(samples_ms, 50) / percentile(local_ms, 50),
              row["label_mb_per_pose"]["samples"].get<double>(), row["label_mb_per_pose"]["runs"].get<double>());
  std::printf("%-12s rig %.1f MB: upload %.0f MB/s, load from the store %.0f ms (in process), first GetRig %.0f ms\n",
              name.c_str(), row["rig_mb"].get<double>(), row["upload_mb_per_s"].get<double>(),
              row["rig_load_ms"].get<double>(), row["first_get_rig_ms"].get<double>());
  std::fflush(stdout);
  if (latency_only) {
    server.stop();
    return row;
  }

  // Throughput: C clients, each on its own connection, posing `per_client` times.
  for (const int clients : {1, 4, 16}) {
    const int per_client = std::max(1, repeats * 2 / clients);
    std::vector<std::future<std::vector<double>>> running;
    const api::Stopwatch start;
    for (int c = 0; c < clients; ++c) {
      running.push_back(std::async(std::launch::async, [&] {
        const std::unique_ptr<client::Connection> own = connect_to(server);
        std::vector<double> ms;
        for (int i = 0; i < per_client; ++i) {
          const api::Stopwatch t;
          client::PoseAnswer answer;
          if (const client::CallError e = client::pose(*own, request, &answer); e.failed()) throw std::runtime_error(e.message);
          ms.push_back(1e3 * t.seconds());
        }
        return ms;
      }));
    }
    std::vector<double> all;
    for (auto& r : running) {
      const std::vector<double> ms = r.get();
      all.insert(all.end(), ms.begin(), ms.end());
    }
    const double wall = start.seconds();
    row["throughput"].push_back({{"clients", clients}, {"poses_per_s", static_cast<double>(all.size()) / wall},
                                 {"p99_ms", percentile(all, 99)}, {"errors", 0}});
    std::printf("%-12s %2d clients: %6.2f poses/s, p99 %7.1f ms, 0 errors\n", name.c_str(), clients,
                static_cast<double>(all.size()) / wall, percentile(all, 99));
    std::fflush(stdout);
  }

  // Preview: one update in flight at a time (a slider that waits for its answer), 200 updates.
  {
    grpc::ClientContext context;
    auto stream = stub->Preview(&context);
    std::vector<double> ms;
    v1::PreviewResponse answer;
    for (int i = 0; i < 200; ++i) {
      v1::PreviewRequest update;
      if (i == 0) update.set_rig_id(uploaded.id());
      update.set_sequence(static_cast<uint64_t>(i + 1));
      update.set_pose_json(pose_json);
      const api::Stopwatch start;
      if (!stream->Write(update) || !stream->Read(&answer) || answer.error_code() != 0) {
        throw std::runtime_error("preview failed: " + answer.error_message());
      }
      if (i > 0) ms.push_back(1e3 * start.seconds());  // the first carries the topology
    }
    stream->WritesDone();
    while (stream->Read(&answer)) {
    }
    stream->Finish();
    row["preview_ms"] = {{"p50", percentile(ms, 50)}, {"p99", percentile(ms, 99)}};
    std::printf("%-12s preview round trip p50 %.1f ms, p99 %.1f ms (%d surfaces)\n", name.c_str(), percentile(ms, 50),
                percentile(ms, 99), answer.surfaces_size());
  }

  // Memory: resident bytes after 10 and after 100 poses (no growth expected past the first).
  double after_10 = 0.0, after_100 = 0.0;
  for (int i = 1; i <= 100; ++i) {
    request.set_want_ct(i % 2 == 0);
    client::PoseAnswer answer;
    if (client::pose(*connection, request, &answer).failed()) throw std::runtime_error("pose failed");
    if (i == 10) after_10 = metric(scrape_metrics(metrics_port), "process_resident_memory_bytes");
    if (i == 100) after_100 = metric(scrape_metrics(metrics_port), "process_resident_memory_bytes");
  }
  row["resident_mb_after_10_poses"] = after_10 / 1e6;
  row["resident_mb_after_100_poses"] = after_100 / 1e6;
  std::printf("%-12s server resident memory after 10 poses %.0f MB, after 100 poses %.0f MB\n", name.c_str(),
              after_10 / 1e6, after_100 / 1e6);
  std::fflush(stdout);
  server.stop();
  return row;
}

}  // namespace

int main(int argc, char** argv) {
  double mannequin_mvoxels = 20.0, body_mvoxels = 0.0;
  fs::path source = POSEWARP_SOURCE_DIR;
  int repeats = 10, pose_threads = 0;
  bool latency_only = false;
  fs::path rig_cache;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--mannequin-mvoxels") && i + 1 < argc) {
      mannequin_mvoxels = std::atof(argv[++i]);
    } else if (!std::strcmp(argv[i], "--body-mvoxels") && i + 1 < argc) {
      body_mvoxels = std::atof(argv[++i]);
    } else if (!std::strcmp(argv[i], "--source-dir") && i + 1 < argc) {
      source = argv[++i];
    } else if (!std::strcmp(argv[i], "--repeats") && i + 1 < argc) {
      repeats = std::max(2, std::atoi(argv[++i]));
    } else if (!std::strcmp(argv[i], "--pose-threads") && i + 1 < argc) {
      pose_threads = std::max(0, std::atoi(argv[++i]));
    } else if (!std::strcmp(argv[i], "--latency-only")) {
      latency_only = true;
    } else if (!std::strcmp(argv[i], "--rig-cache") && i + 1 < argc) {
      rig_cache = argv[++i];
    } else {
      std::fprintf(stderr,
                   "usage: %s [--mannequin-mvoxels M (0 = skip)] [--body-mvoxels M (0 = skip)] [--repeats R] "
                   "[--latency-only] [--pose-threads N] [--rig-cache DIR] [--source-dir DIR]\n",
                   argv[0]);
      return 2;
    }
  }
  const fs::path work = fs::temp_directory_path() / ("posewarp-bench-server-" + std::to_string(::getpid()));
  fs::create_directories(work);
  nlohmann::json out;
  try {
    const std::string dir = (source / "data/totalsegmentator_example").string();
    const std::string hip = file_text(source / "data/poses/sample_hip_flexion.json");
    out["cases"].push_back(
        bench_case("real-sample", work, bench::sample_rig_bytes(dir), hip, repeats, latency_only, pose_threads));
    // Volume upload throughput: the sample's CT file, through UploadVolume (checked and stored).
    {
      ServerProcess server(work / "store-upload", {}, {}, work / "upload.log");
      auto stub = v1::Posewarp::NewStub(server.channel());
      const fs::path ct = fs::path(dir) / "ct.nii.gz";
      v1::Volume volume;
      const api::Stopwatch start;
      if (!upload(*stub, ct, v1::VOLUME_KIND_INTENSITY, &volume).ok()) throw std::runtime_error("upload failed");
      const double mb = static_cast<double>(fs::file_size(ct)) / 1e6;
      out["volume_upload_mb_per_s"] = mb / start.seconds();
      std::printf("volume upload (sample CT, %.1f MB .nii.gz, checked and stored): %.1f MB/s\n", mb,
                  out["volume_upload_mb_per_s"].get<double>());
      server.stop();
    }
    const std::string knee = file_text(source / "data/poses/knee_bent.json");
    for (const auto& [kind, mvoxels] :
         {std::pair<std::string, double>{"mannequin", mannequin_mvoxels}, {"body", body_mvoxels}}) {
      if (mvoxels <= 0.0) continue;
      // A phantom's rig takes minutes to build: --rig-cache keeps it between runs.
      const std::string rig_bytes = bench::phantom_rig_bytes(kind, mvoxels, rig_cache);
      out["cases"].push_back(
          bench_case(kind, work, rig_bytes, knee, std::max(2, repeats / 2), latency_only, pose_threads));
    }
  } catch (const std::exception& error) {
    std::fprintf(stderr, "posewarp_bench_server: %s\n", error.what());
    fs::remove_all(work);
    return 1;
  }
  std::cout << out.dump(2) << "\n";
  if (std::getenv("POSEWARP_BENCH_KEEP")) {
    std::fprintf(stderr, "kept %s (server logs)\n", work.c_str());
  } else {
    fs::remove_all(work);
  }
  return 0;
}
