// posewarp-view measured against the real posewarp-server on loopback, offscreen: what a slider step costs from the
// moment the control moves to the redrawn frame (preview round trip + applying the answer + render), on the sample
// and on the mannequin phantom. Two ways: steps one after another (each waits for its frame), and a drag that sends
// at 60 Hz for a few seconds while the frames are drawn as answers come (the latest wins), as the window does.
// Run it under xvfb-run -a where there is no display.
// Usage: posewarp_bench_viewer [--mannequin-mvoxels M (0 = skip)] [--steps N] [--rig-cache DIR] [--size WxH]
#include <nlohmann/json.hpp>

#include <algorithm>
#include <iostream>
#include <numeric>
#include <thread>

#include "bench_rigs.h"
#include "scene.h"
#include "server_process.h"

namespace {

using namespace posewarp;
using namespace posewarp::testing_server;
using Clock = std::chrono::steady_clock;

double ms_since(Clock::time_point start) {
  return std::chrono::duration<double, std::milli>(Clock::now() - start).count();
}

using bench::percentile;

// A slider swept from 0 to 90 degrees and back in 2-degree steps, as long as asked.
double slider_angle(int step) {
  const int phase = step % 90;
  return 2.0 * (phase < 45 ? phase : 90 - phase);
}

nlohmann::json bench_case(const std::string& name, const fs::path& work, const std::string& rig_bytes,
                          const std::string& joint, int steps, int width, int height) {
  ServerProcess server(work / ("store-" + name), {}, {}, work / (name + "-server.log"));
  if (server.port() == 0) throw std::runtime_error("the server did not start: " + server.log());
  auto stub = v1::Posewarp::NewStub(server.channel());
  v1::Rig uploaded;
  if (grpc::Status s = upload_rig(*stub, rig_bytes, sha256_hex(rig_bytes), &uploaded); !s.ok()) {
    throw std::runtime_error("rig upload: " + s.error_message());
  }
  view::CallError error;
  auto client = view::ViewerClient::connect({server.address(), "", ""}, &error);
  if (!client) throw std::runtime_error(error.message);
  view::RigAssets assets;
  if (view::CallError e = client->assets(uploaded.id(), &assets); e.failed()) throw std::runtime_error(e.message);
  int64_t vertices = 0, triangles = 0, skin_triangles = 0;
  for (const v1::Surface& s : assets.surfaces) {
    vertices += s.vertices_size() / 3, triangles += s.triangles_size() / 3;
    if (s.role() == "skin") skin_triangles += s.triangles_size() / 3;
  }
  view::Scene scene(width, height, true);
  scene.set_rig(assets);
  // The stream closes before the server stops (a server waits out its grace period for open streams).
  auto session_owner = std::make_unique<view::PreviewSession>(*client, uploaded.id());
  view::PreviewSession& session = *session_owner;
  view::Controller controller(scene, session);
  const auto& joints = scene.joint_names();
  const auto at = std::find(joints.begin(), joints.end(), joint);
  if (at == joints.end()) throw std::runtime_error("the rig has no joint " + joint);
  controller.select_joint(static_cast<size_t>(at - joints.begin()));
  scene.render();
  // Warm up: the server loads the rig into its cache on the first preview.
  controller.set_angle(0, 1.0);
  if (!session.wait_for(controller.last_sent(), 120000)) throw std::runtime_error("no first preview answer");
  controller.poll();
  scene.render();

  // The same frame drawn again, nothing changed: the cost of the pixels alone.
  std::vector<double> still_ms;
  for (int i = 0; i < 20; ++i) {
    const auto start = Clock::now();
    scene.render();
    still_ms.push_back(ms_since(start));
  }
  // Steps one after another: control moved -> answer -> surfaces updated -> frame rendered.
  std::vector<double> step_ms, round_trip_ms, server_ms, render_ms;
  for (int i = 0; i < steps; ++i) {
    const auto start = Clock::now();
    controller.set_angle(0, slider_angle(i + 1));
    if (!session.wait_for(controller.last_sent(), 30000)) throw std::runtime_error("a preview answer did not come");
    controller.poll();
    const auto render_start = Clock::now();
    scene.render();
    render_ms.push_back(ms_since(render_start));
    step_ms.push_back(ms_since(start));
    round_trip_ms.push_back(controller.last_round_trip_ms());
  }
  // A drag: the slider sends at 60 Hz for 3 s; the loop draws whatever answer is newest, as the window's timer.
  const auto drag_start = Clock::now();
  auto next_send = drag_start;
  int sent = 0, frames = 0;
  while (ms_since(drag_start) < 3000.0) {
    if (Clock::now() >= next_send) {
      controller.set_angle(0, slider_angle(++sent));
      next_send += std::chrono::microseconds(16667);
    }
    if (controller.poll()) {
      scene.render();
      ++frames;
    } else {
      std::this_thread::sleep_for(std::chrono::milliseconds(1));
    }
  }
  const double drag_s = ms_since(drag_start) / 1000.0;
  nlohmann::json row{{"case", name},
                     {"surfaces", assets.surfaces.size()},
                     {"vertices", vertices},
                     {"triangles", triangles},
                     {"skin_triangles", skin_triangles},
                     {"window", std::to_string(width) + "x" + std::to_string(height)},
                     {"step_p50_ms", percentile(step_ms, 50)},
                     {"step_p99_ms", percentile(step_ms, 99)},
                     {"steps_per_s", 1000.0 * static_cast<double>(steps) /
                                         std::max(1e-9, std::accumulate(step_ms.begin(), step_ms.end(), 0.0))},
                     {"round_trip_p50_ms", percentile(round_trip_ms, 50)},
                     {"round_trip_p99_ms", percentile(round_trip_ms, 99)},
                     {"render_p50_ms", percentile(render_ms, 50)},
                     {"render_p99_ms", percentile(render_ms, 99)},
                     {"unchanged_render_p50_ms", percentile(still_ms, 50)},
                     {"drag_sent_per_s", sent / drag_s},
                     {"drag_frames_per_s", frames / drag_s}};
  std::printf(
      "%-12s %zu surfaces, %lld vertices, %lld triangles (skin %lld), %s: step p50 %.1f ms p99 %.1f ms (%.1f frames/s; "
      "round trip p50 "
      "%.1f, render p50 %.1f ms, unchanged frame %.1f ms); drag at %.0f Hz: %.1f frames/s\n",
      name.c_str(), assets.surfaces.size(), static_cast<long long>(vertices), static_cast<long long>(triangles),
      static_cast<long long>(skin_triangles), row["window"].get<std::string>().c_str(),
      row["step_p50_ms"].get<double>(), row["step_p99_ms"].get<double>(), row["steps_per_s"].get<double>(),
      row["round_trip_p50_ms"].get<double>(), row["render_p50_ms"].get<double>(),
      row["unchanged_render_p50_ms"].get<double>(), row["drag_sent_per_s"].get<double>(),
      row["drag_frames_per_s"].get<double>());
  std::fflush(stdout);
  session_owner.reset();
  server.stop();
  return row;
}

}  // namespace

int main(int argc, char** argv) {
  double mannequin_mvoxels = 20.0;
  int steps = 200, width = 1024, height = 768;
  fs::path rig_cache;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--mannequin-mvoxels") && i + 1 < argc) {
      mannequin_mvoxels = std::atof(argv[++i]);
    } else if (!std::strcmp(argv[i], "--steps") && i + 1 < argc) {
      steps = std::max(10, std::atoi(argv[++i]));
    } else if (!std::strcmp(argv[i], "--rig-cache") && i + 1 < argc) {
      rig_cache = argv[++i];
    } else if (!std::strcmp(argv[i], "--size") && i + 1 < argc &&
               std::sscanf(argv[i + 1], "%dx%d", &width, &height) == 2) {
      ++i;
    } else {
      std::fprintf(stderr,
                   "usage: %s [--mannequin-mvoxels M (0 = skip)] [--steps N] [--rig-cache DIR] [--size WxH]\n"
                   "(offscreen: run it under xvfb-run -a without a display)\n",
                   argv[0]);
      return 2;
    }
  }
  const fs::path work = fs::temp_directory_path() / ("posewarp-bench-viewer-" + std::to_string(::getpid()));
  fs::create_directories(work);
  nlohmann::json out;
  try {
    out["cases"].push_back(bench_case("real-sample", work, bench::sample_rig_bytes(POSEWARP_SAMPLE_DIR), "hip_left",
                                      steps, width, height));
    if (mannequin_mvoxels > 0.0) {
      // The same cache file as posewarp_bench_server's --rig-cache.
      const std::string rig_bytes = bench::phantom_rig_bytes("mannequin", mannequin_mvoxels, rig_cache);
      out["cases"].push_back(bench_case("mannequin", work, rig_bytes, "knee_left", steps, width, height));
    }
  } catch (const std::exception& error) {
    std::fprintf(stderr, "posewarp_bench_viewer: %s\n", error.what());
    fs::remove_all(work);
    return 1;
  }
  std::cout << out.dump(2) << "\n";
  fs::remove_all(work);
  return 0;
}
