// Posing throughput: skinning of 1M tet vertices per method, whole poses with CoR and with fem (the soft tissue's
// solve apart), the volume warp against ITK's ResampleImageFilter
// through a DisplacementFieldTransform (same output grid, volume and threads, same run), and whole poses of the
// real sample and of a mannequin.
// Usage: posewarp_bench_pose [--threads N | --threads 1,2,4,8,16] [--mannequin-mvoxels M (0 = skip)]
//                            [--body-mvoxels M (0 = skip)] [--repeats R] [--data-dir DIR] [--rig RIG --pose POSE]
//                            [--quick] [--phases]
// With several thread counts it prints the scaling table instead: per case, the whole pose, each stage and ITK on
// the same warp at each count, and the parallel efficiency from the first count of at least 2 to the last (from the
// first count when only the last is 2 or more).
// --data-dir names the real sample's folder (seg_total.nii.gz, ct.nii.gz) where the build tree's path does not
// exist (a bundle run on another machine).
// --rig RIG --pose POSE.json benches that rig with that pose instead of the built-in cases (a rig of your own data, a
// pose that moves the root), with the same rows. --quick gives only the whole pose and its stages (no surfaces, fem,
// previews or ITK): what a change to a stage is measured by. --phases adds each stage's phases (the warp's maps,
// select, prepare, split, raster, shell and classify; the mesh report's determinants and parts), best of the repeats,
// printed after the stages and, in a sweep, as rows of the table.
#include <nlohmann/json.hpp>

#include <Eigen/Geometry>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <functional>
#include <iostream>
#include <limits>
#include <map>
#include <random>
#include <string>
#include <string_view>
#include <vector>

#include "posewarp/api/files.h"
#include "posewarp/api/pose_engine.h"
#include "posewarp/api/rig_file.h"
#include "posewarp/common/parallel.h"
#include "posewarp/io/itk_reference.h"
#include "posewarp/io/volume_io.h"
#include "posewarp/labels/presets.h"
#include "posewarp/mapping/tet_locator.h"
#include "posewarp/phantom/phantom.h"
#include "posewarp/pose/pose.h"
#include "posewarp/resample/tet_warp.h"
#include "posewarp/skinning/skinning.h"

namespace {

using namespace posewarp;

// Best wall time of `repeats` runs, seconds.
double best_of(int repeats, const std::function<void()>& work) {
  double best = 1e300;
  for (int r = 0; r < repeats; ++r) {
    const auto start = std::chrono::steady_clock::now();
    work();
    best = std::min(best, std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
  }
  return best;
}

// Each stage's phases (ProgressHooks::on_phase: the warp's select, raster, shell, ...; the mesh report's parts), best
// seconds over the runs, in the order they first ran. Asked for with --phases.
class PhaseTimes {
 public:
  // Points `hooks` at this: each phase a run reports adds to that run's figure.
  void attach(ProgressHooks& hooks) {
    hooks.on_phase = [this](std::string_view stage, std::string_view phase, double seconds) {
      const std::string key = std::string(stage) + ": " + std::string(phase);
      if (!run_.count(key) && !best_.count(key)) order_.push_back(key);
      run_[key] += seconds;
    };
  }
  // Ends a run: each phase keeps its best.
  void end_run() {
    for (const auto& [key, seconds] : run_) best_[key] = best_.count(key) ? std::min(best_[key], seconds) : seconds;
    run_.clear();
  }
  const std::vector<std::string>& phases() const { return order_; }
  double best_ms(const std::string& key) const { return best_.count(key) ? 1000.0 * best_.at(key) : 0.0; }
  // A line per stage: "<indent>phases of warp-prepare: maps 0.01 ms select 1.20 ms ...".
  void print(const char* indent) const {
    std::string stage;
    for (const std::string& key : order_) {
      const size_t colon = key.find(": ");
      if (stage.empty() || key.compare(0, colon, stage) != 0) {
        if (!stage.empty()) std::printf("\n");
        stage = key.substr(0, colon);
        std::printf("%sphases of %s:", indent, stage.c_str());
      }
      std::printf(" %s %.2f ms", key.c_str() + colon + 2, best_ms(key));
    }
    if (!order_.empty()) std::printf("\n");
  }
  nlohmann::json json() const {
    nlohmann::json out = nlohmann::json::object();
    for (const std::string& key : order_) out[key] = best_ms(key);
    return out;
  }

 private:
  std::vector<std::string> order_;
  std::map<std::string, double> run_, best_;
};

nlohmann::json bench_skinning(int repeats) {
  // 1M vertices with four influences over 20 segments, blended weights and centres: the cost of skinning does not
  // depend on the mesh's connectivity.
  const int64_t n = 1'000'000;
  const int segments = 20;
  std::mt19937 rng(7);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  Eigen::MatrixXd rest(n, 3);
  SkinWeights weights;
  weights.influences = 4;
  weights.segment_count = segments;
  weights.segment.resize(n, 4);
  weights.weight.resize(n, 4);
  RotationCentres centres;
  centres.centre.resize(n, 3);
  centres.rigid.assign(static_cast<size_t>(n), 0);
  for (int64_t v = 0; v < n; ++v) {
    for (int a = 0; a < 3; ++a) rest(v, a) = 1000.0 * unit(rng);
    const int first = static_cast<int>(unit(rng) * (segments - 4));
    double w[4], total = 0.0;
    for (double& x : w) total += (x = unit(rng));
    std::sort(w, w + 4, std::greater<>());
    for (int i = 0; i < 4; ++i) {
      weights.segment(v, i) = first + i;
      weights.weight(v, i) = static_cast<float>(w[i] / total);
    }
    centres.centre.row(v) = rest.row(v) + Eigen::RowVector3d(5, 5, 5);
    centres.rigid[static_cast<size_t>(v)] = v % 4 == 0;  // a quarter of the vertices sit inside one bone
  }
  skinning::SegmentTransforms transforms;
  for (int s = 0; s < segments; ++s) {
    transforms.rotation.push_back(Eigen::AngleAxisd(0.1 * s, Eigen::Vector3d(1, 2, 3).normalized()).toRotationMatrix());
    transforms.translation.push_back(Eigen::Vector3d(s, -s, 2 * s));
  }
  nlohmann::json row;
  for (const skinning::Method m : {skinning::Method::kLbs, skinning::Method::kDqs, skinning::Method::kCor}) {
    const double seconds = best_of(repeats, [&] { (void)skinning::skin(m, rest, weights, centres, transforms); });
    row[std::string(skinning::method_name(m))] = {{"vertices", n}, {"ms", 1000.0 * seconds}};
    std::printf("skinning %-4s %lld vertices: %7.2f ms\n", std::string(skinning::method_name(m)).c_str(),
                static_cast<long long>(n), 1000.0 * seconds);
  }
  return row;
}

nlohmann::json bench_pose(const std::string& name, api::Rig rig, const pose::Pose& pose, int repeats, bool quick,
                          bool phases) {
  // Once per rig: rest tet frames, rest ownership, bone voxels and body regions.
  const auto created = std::chrono::steady_clock::now();
  Result<api::PoseEngine> engine = api::PoseEngine::create(std::move(rig));
  const double create_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - created).count();
  if (!engine.ok()) {
    std::fprintf(stderr, "%s: %s\n", name.c_str(), engine.status().to_string().c_str());
    return {};
  }
  const ImageGeometry& grid = engine->rig().labels.geometry();
  const double voxels = static_cast<double>(grid.voxel_count());
  nlohmann::json row{{"case", name},
                     {"voxels", grid.voxel_count()},
                     {"tet_vertices", engine->rig().mesh.vertex_count()},
                     {"tets", engine->rig().mesh.tet_count()},
                     {"threads", thread_count()},
                     {"engine_create_ms", 1000.0 * create_s}};
  std::printf("%-14s engine created in %.0f ms\n", name.c_str(), 1000.0 * create_s);

  // Surfaces: 1M points inside the rest mesh, embedded (spatial hash) and deformed.
  if (!quick) {
    const TetMesh& mesh = engine->rig().mesh;
    const int64_t n = 1'000'000;
    std::mt19937 rng(11);
    std::uniform_int_distribution<int64_t> pick(0, mesh.tet_count() - 1);
    std::uniform_real_distribution<double> unit(0.0, 1.0);
    Eigen::MatrixXd points(n, 3);
    for (int64_t i = 0; i < n; ++i) {
      double b[4], total = 0.0;
      for (double& x : b) total += (x = -std::log(std::max(1e-12, unit(rng))));
      const int64_t t = pick(rng);
      Eigen::Vector3d p = Eigen::Vector3d::Zero();
      for (int c = 0; c < 4; ++c) p += (b[c] / total) * mesh.vertices.row(mesh.tets(t, c)).transpose();
      points.row(i) = p.transpose();
    }
    mapping::Embedding embedding;
    const double embed_s =
        best_of(repeats, [&] { embedding = std::move(mapping::embed_points(mesh, points, {})).value(); });
    const double deform_s = best_of(repeats, [&] { (void)mapping::deform_points(embedding, mesh, mesh.vertices); });
    row["embed_1M_ms"] = 1000.0 * embed_s;
    row["deform_1M_ms"] = 1000.0 * deform_s;
    std::printf("%-14s map 1M surface vertices into %lld tets: %7.1f ms (%.2f M/s); deform 1M vertices: %6.2f ms\n",
                name.c_str(), static_cast<long long>(mesh.tet_count()), 1000.0 * embed_s, 1.0 / embed_s,
                1000.0 * deform_s);
  }

  api::PoseRequest whole;
  whole.pose = pose;
  // Each stage's best time over the repeats (the whole pose's best is its own figure).
  std::vector<std::pair<std::string, double>> stages;
  PhaseTimes whole_phases;
  ProgressHooks whole_hooks;
  if (phases) whole_phases.attach(whole_hooks);
  const double whole_s = best_of(repeats, [&] {
    const api::PoseResult result = std::move(engine->pose(whole, whole_hooks)).value();
    whole_phases.end_run();
    if (stages.empty()) stages = result.report.stage_seconds;
    for (size_t i = 0; i < stages.size() && i < result.report.stage_seconds.size(); ++i) {
      stages[i].second = std::min(stages[i].second, result.report.stage_seconds[i].second);
    }
  });
  row["whole_pose_ms"] = 1000.0 * whole_s;
  for (const auto& [stage, seconds] : stages) row["stages_ms"][stage] = 1000.0 * seconds;
  if (phases) row["phases_ms"] = whole_phases.json();
  if (quick) {
    std::printf("%-14s %9.0f voxels: whole pose %7.1f ms; stages:", name.c_str(), voxels, 1000.0 * whole_s);
    for (const auto& [stage, seconds] : stages) std::printf(" %s %.1f ms", stage.c_str(), 1000.0 * seconds);
    std::printf("\n");
    whole_phases.print("               ");
    return row;
  }

  // The same pose with the soft tissue's steady state (fem): CoR, then the solve, then the same warp.
  api::PoseRequest fem = whole;
  fem.method = api::Method::kFem;
  double fem_solve_s = std::numeric_limits<double>::infinity();
  const double fem_s = best_of(repeats, [&] {
    const api::PoseResult result = std::move(engine->pose(fem)).value();
    for (const auto& [stage, seconds] : result.report.stage_seconds) {
      if (stage == "fem") fem_solve_s = std::min(fem_solve_s, seconds);
    }
  });
  row["whole_pose_fem_ms"] = 1000.0 * fem_s;
  row["fem_solve_ms"] = 1000.0 * fem_solve_s;
  std::printf("%-14s whole pose with fem %7.1f ms, of which the soft tissue's solve %7.1f ms\n", name.c_str(),
              1000.0 * fem_s, 1000.0 * fem_solve_s);

  // The preview (posed rest surfaces only): what a slider waits for. 200 calls each (fem 20), p50 and p99.
  int64_t surface_vertices = 0;
  for (const SurfaceMesh& m : engine->rig().surfaces) surface_vertices += m.vertices.rows();
  for (const api::Method method : {api::Method::kCor, api::Method::kDqs, api::Method::kLbs, api::Method::kFem}) {
    std::vector<double> ms;
    const int calls = method == api::Method::kFem ? 20 : 200;  // fem: tenths of a second each
    for (int i = 0; i < calls; ++i) {
      const auto start = std::chrono::steady_clock::now();
      (void)engine->preview(pose, method);
      ms.push_back(1000.0 * std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
    }
    std::sort(ms.begin(), ms.end());
    const std::string method_name(api::method_name(method));
    const double p50 = ms[ms.size() / 2], p99 = ms[ms.size() * 99 / 100 - 1];
    row["preview_ms"][method_name] = {{"p50", p50}, {"p99", p99}};
    std::printf("%-14s preview %-4s (%lld surface vertices): p50 %.2f ms, p99 %.2f ms\n", name.c_str(),
                method_name.c_str(), static_cast<long long>(surface_vertices), p50, p99);
  }

  // The warp alone (prepare + labels + CT) against ITK on the same grid with our inverse field.
  api::PoseRequest fields = whole;
  fields.want_fields = true;
  api::PoseResult with_fields = std::move(engine->pose(fields)).value();
  double warp_ms = 0.0;
  for (const auto& [stage, seconds] : stages) {
    if (stage.rfind("warp", 0) == 0) warp_ms += 1000.0 * seconds;
  }
  const IntensityVolume ct = engine->rig().ct->to_float();  // ITK resamples floats
  const double itk_ct_s = best_of(repeats, [&] {
    (void)io::itk_resample_with_field(ct, with_fields.inverse_field, with_fields.output_grid, -1024.0f);
  });
  const double itk_labels_s = best_of(repeats, [&] {
    (void)io::itk_resample_labels_with_field(engine->rig().labels, with_fields.inverse_field, with_fields.output_grid);
  });
  const double itk_ms = 1000.0 * (itk_ct_s + itk_labels_s);
  // The worst case for posewarp: every tet rasterized, as if the whole body moved off the root's transform.
  const api::Rig& engine_rig = engine->rig();
  const size_t root = static_cast<size_t>(engine_rig.skeleton.root);
  double all_tets_parts[3] = {1e300, 1e300, 1e300};  // best build, labels, CT
  PhaseTimes all_tets_phases;
  ProgressHooks all_tets_hooks;
  if (phases) all_tets_phases.attach(all_tets_hooks);
  const double all_tets_s = best_of(repeats, [&] {
    const auto t0 = std::chrono::steady_clock::now();
    const resample::TetWarp warp =
        std::move(resample::TetWarp::build({.rest = engine_rig.mesh,
                                            .posed = with_fields.posed_vertices,
                                            .source = engine_rig.labels.geometry(),
                                            .output = with_fields.output_grid,
                                            .background_rotation = with_fields.segment_rotation[root],
                                            .background_translation = with_fields.segment_translation[root]},
                                           all_tets_hooks))
            .value();
    all_tets_phases.end_run();
    const auto t1 = std::chrono::steady_clock::now();
    (void)warp.warp_labels(engine_rig.labels);
    const auto t2 = std::chrono::steady_clock::now();
    (void)engine_rig.ct->visit(
        [&](const auto& source) { return warp.warp_intensities(source, resample::Interpolation::kLinear); });
    const auto t3 = std::chrono::steady_clock::now();
    const std::chrono::steady_clock::time_point at[4] = {t0, t1, t2, t3};
    for (int p = 0; p < 3; ++p)
      all_tets_parts[p] = std::min(all_tets_parts[p], std::chrono::duration<double>(at[p + 1] - at[p]).count());
  });
  row["warp_all_tets_ms"] = 1000.0 * all_tets_s;
  row["speedup_vs_itk_all_tets"] = itk_ms / (1000.0 * all_tets_s);
  row["warp_ms"] = warp_ms;
  row["itk_warp_ms"] = itk_ms;
  row["warp_mvoxels_per_s"] = 2.0 * voxels / (warp_ms / 1000.0) / 1e6;
  row["itk_mvoxels_per_s"] = 2.0 * voxels / (itk_ms / 1000.0) / 1e6;
  row["speedup_vs_itk"] = itk_ms / warp_ms;
  std::printf(
      "%-14s %9.0f voxels %8lld tet vertices: whole pose %7.1f ms | warp labels+CT %7.1f ms (%6.1f Mvox/s) vs ITK "
      "%8.1f ms (%5.1f Mvox/s): %4.1fx\n",
      name.c_str(), voxels, static_cast<long long>(engine->rig().mesh.vertex_count()), 1000.0 * whole_s, warp_ms,
      row["warp_mvoxels_per_s"].get<double>(), itk_ms, row["itk_mvoxels_per_s"].get<double>(), itk_ms / warp_ms);
  std::printf(
      "               every tet rasterized (worst case): warp labels+CT %7.1f ms (%6.1f Mvox/s): %4.1fx ITK "
      "(best build %.1f, labels %.1f, CT %.1f ms)\n",
      1000.0 * all_tets_s, 2.0 * voxels / all_tets_s / 1e6, itk_ms / (1000.0 * all_tets_s), 1000.0 * all_tets_parts[0],
      1000.0 * all_tets_parts[1], 1000.0 * all_tets_parts[2]);
  all_tets_phases.print("               every tet rasterized: ");
  if (phases) row["warp_all_tets_phases_ms"] = all_tets_phases.json();
  std::printf("               rasterized tets %lld of %lld; stages:",
              static_cast<long long>(with_fields.report.rasterized_tets),
              static_cast<long long>(engine->rig().mesh.tet_count()));
  for (const auto& [stage, seconds] : stages) std::printf(" %s %.1f ms", stage.c_str(), 1000.0 * seconds);
  std::printf("\n");
  whole_phases.print("               ");
  std::fflush(stdout);
  return row;
}

// One case's scaling: the engine made once, then per thread count the best whole pose, each stage's best and ITK's
// resampler on the same warp (labels + CT; not with `quick`), printed as a table with each row's efficiency.
nlohmann::json bench_scaling(const std::string& name, api::Rig rig, const pose::Pose& pose,
                             const std::vector<int>& counts, int repeats, bool quick, bool phases) {
  const api::PoseEngine engine = std::move(api::PoseEngine::create(std::move(rig))).value();
  api::PoseRequest request;
  request.pose = pose;
  request.want_fields = true;
  const api::PoseResult with_fields = std::move(engine.pose(request)).value();
  request.want_fields = false;
  std::vector<std::string> rows{"whole pose", "warp labels + CT"};
  for (const auto& [stage, seconds] : with_fields.report.stage_seconds) rows.push_back(stage);
  if (!quick) rows.push_back("ITK warp labels + CT");
  std::map<std::string, std::vector<double>> ms;  // row -> per count
  std::vector<PhaseTimes> phase_times(counts.size());
  for (size_t at = 0; at < counts.size(); ++at) {
    const int threads = counts[at];
    ProgressHooks hooks;
    hooks.threads = threads;
    if (phases) phase_times[at].attach(hooks);
    std::map<std::string, double> best;
    const double whole_s = best_of(repeats, [&] {
      const api::PoseResult result = std::move(engine.pose(request, hooks)).value();
      phase_times[at].end_run();
      double warp = 0.0;
      for (const auto& [stage, seconds] : result.report.stage_seconds) {
        best[stage] = best.count(stage) ? std::min(best[stage], seconds) : seconds;
        if (stage.rfind("warp", 0) == 0) warp += seconds;
      }
      best["warp labels + CT"] = best.count("warp labels + CT") ? std::min(best["warp labels + CT"], warp) : warp;
    });
    best["whole pose"] = whole_s;
    if (!quick) {
      const IntensityVolume ct = engine.rig().ct->to_float();  // ITK resamples floats
      run_in_arena(threads, [&] {
        best["ITK warp labels + CT"] = best_of(repeats, [&] {
          (void)io::itk_resample_with_field(ct, with_fields.inverse_field, with_fields.output_grid, -1024.0f);
          (void)io::itk_resample_labels_with_field(engine.rig().labels, with_fields.inverse_field,
                                                   with_fields.output_grid);
        });
      });
    }
    for (const std::string& row : rows) ms[row].push_back(1000.0 * best[row]);
  }
  // Each stage's phases (--phases) as rows of their own, after the stages.
  for (const std::string& phase : phase_times.front().phases()) {
    rows.push_back(phase);
    for (const PhaseTimes& times : phase_times) ms[phase].push_back(times.best_ms(phase));
  }
  // Efficiency from the first count of at least 2 threads (a 2-core machine's figure) to the last; from the first
  // count when only the last is 2 or more.
  size_t from = 0;
  while (from + 2 < counts.size() && counts[from] < 2) ++from;
  const size_t to = counts.size() - 1;
  std::printf("\n%s, %lld voxels, ms by threads (efficiency %d -> %d threads):\n\n| stage |", name.c_str(),
              static_cast<long long>(with_fields.output_grid.voxel_count()), counts[from], counts[to]);
  for (const int threads : counts) std::printf(" %d |", threads);
  std::printf(" efficiency |\n|---|");
  for (size_t c = 0; c <= counts.size(); ++c) std::printf("---|");
  std::printf("\n");
  nlohmann::json table{{"case", name}, {"threads", counts}};
  for (const std::string& row : rows) {
    if (ms[row][from] <= 0.0) continue;  // a stage this pose does not run (fields)
    std::printf("| %s |", row.c_str());
    for (const double value : ms[row]) std::printf(" %.1f |", value);
    const double efficiency =
        ms[row][from] / ms[row][to] / (static_cast<double>(counts[to]) / static_cast<double>(counts[from]));
    std::printf(" %.0f%% |\n", 100.0 * efficiency);
    table["ms"][row] = ms[row];
    table["efficiency"][row] = efficiency;
  }
  std::fflush(stdout);
  return table;
}

pose::Pose flexion(const std::string& joint, double degrees) {
  pose::Pose p;
  p.name = joint + " flexion";
  p.joints.push_back(pose::anatomical_rotation(joint, degrees));
  return p;
}

// The rig of a phantom with default build parameters; prints the error when either step fails.
Result<api::Rig> rig_of(Result<phantom::Phantom> p) {
  if (!p.ok()) {
    std::fprintf(stderr, "%s\n", p.status().to_string().c_str());
    return p.status();
  }
  api::BuildInputs inputs;
  inputs.labels = p->labels;
  inputs.ct = p->ct;
  inputs.label_map = p->label_map;
  Result<api::Rig> rig = api::build_rig(inputs, {}, {});
  if (!rig.ok()) std::fprintf(stderr, "%s\n", rig.status().to_string().c_str());
  return rig;
}

// "1,2,4" -> {1, 2, 4}; empty on anything else.
std::vector<int> thread_counts(const char* text) {
  std::vector<int> counts;
  for (const char* at = text; *at;) {
    char* end = nullptr;
    const long value = std::strtol(at, &end, 10);
    if (end == at || value < 0 || value > 1024) return {};
    counts.push_back(static_cast<int>(value));
    at = *end == ',' ? end + 1 : end;
    if (*end != ',' && *end != '\0') return {};
  }
  return counts;
}

}  // namespace

int main(int argc, char** argv) {
  std::vector<int> counts{0};
  int repeats = 3;
  double mannequin_mvoxels = 20.0, body_mvoxels = 20.0;
  std::string dir = POSEWARP_SAMPLE_DIR;
  std::string rig_path, pose_path;
  bool quick = false, phases = false;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--threads") && i + 1 < argc) {
      counts = thread_counts(argv[++i]);
    } else if (!std::strcmp(argv[i], "--mannequin-mvoxels") && i + 1 < argc) {
      mannequin_mvoxels = std::atof(argv[++i]);
    } else if (!std::strcmp(argv[i], "--body-mvoxels") && i + 1 < argc) {
      body_mvoxels = std::atof(argv[++i]);
    } else if (!std::strcmp(argv[i], "--repeats") && i + 1 < argc) {
      repeats = std::max(1, std::atoi(argv[++i]));
    } else if (!std::strcmp(argv[i], "--data-dir") && i + 1 < argc) {
      dir = argv[++i];
    } else if (!std::strcmp(argv[i], "--quick")) {
      quick = true;
    } else if (!std::strcmp(argv[i], "--phases")) {
      phases = true;
    } else if (!std::strcmp(argv[i], "--rig") && i + 1 < argc) {
      rig_path = argv[++i];
    } else if (!std::strcmp(argv[i], "--pose") && i + 1 < argc) {
      pose_path = argv[++i];
    } else {
      counts.clear();
    }
    if (counts.empty()) {
      std::fprintf(stderr,
                   "usage: %s [--threads N | --threads 1,2,4,8,16] [--mannequin-mvoxels M] [--body-mvoxels M] "
                   "[--repeats R] [--data-dir DIR] [--rig RIG --pose POSE.json] [--quick] [--phases]\n",
                   argv[0]);
      return 2;
    }
  }
  if (rig_path.empty() != pose_path.empty()) {
    std::fprintf(stderr, "--rig and --pose go together: the rig file and the pose file to bench on it\n");
    return 2;
  }
  const bool sweep = counts.size() > 1;
  set_thread_count(sweep ? *std::max_element(counts.begin(), counts.end()) : counts[0]);
  std::printf("threads: %d\n", thread_count());
  // A case: its rig, then either the full bench at the process's thread count or the sweep.
  nlohmann::json out;
  auto bench = [&](const std::string& name, Result<api::Rig> rig, const pose::Pose& pose) {
    if (!rig.ok()) return false;
    if (sweep) {
      out["scaling"].push_back(bench_scaling(name, std::move(rig).value(), pose, counts, repeats, quick, phases));
    } else {
      out["poses"].push_back(bench_pose(name, std::move(rig).value(), pose, repeats, quick, phases));
    }
    return true;
  };
  if (!rig_path.empty()) {
    Result<api::Rig> rig = api::load_rig(rig_path);
    Result<Pose> pose = api::read_pose(pose_path);
    if (!rig.ok() || !pose.ok()) {
      std::fprintf(stderr, "%s\n", (rig.ok() ? pose.status() : rig.status()).to_string().c_str());
      return 1;
    }
    const std::string name = std::filesystem::path(pose_path).stem().string();
    if (!bench(name, std::move(rig), *pose)) return 1;
    std::cout << out.dump(2) << "\n";
    return 0;
  }
  if (!sweep) out["skinning_1M"] = bench_skinning(repeats);

  api::BuildInputs sample;
  Result<LabelVolume> sample_labels = io::read_label_volume(dir + "/seg_total.nii.gz");
  Result<IntensityVolume> sample_ct = io::read_intensity_volume(dir + "/ct.nii.gz");
  if (!sample_labels.ok() || !sample_ct.ok()) {
    std::fprintf(stderr, "the real sample is not in %s (--data-dir DIR): %s\n", dir.c_str(),
                 (sample_labels.ok() ? sample_ct.status() : sample_labels.status()).to_string().c_str());
    return 1;
  }
  sample.labels = std::move(sample_labels).value();
  sample.ct = std::move(sample_ct).value();
  sample.label_map = labels::totalsegmentator_v2_preset();
  Result<api::Rig> sample_rig = api::build_rig(sample, {}, {});
  if (!sample_rig.ok()) std::fprintf(stderr, "%s\n", sample_rig.status().to_string().c_str());
  if (!bench("real-sample", std::move(sample_rig), flexion("hip_left", 30.0))) return 1;

  pose::Pose knee_and_arm = flexion("knee_left", 90.0);
  knee_and_arm.joints.push_back(pose::anatomical_rotation("shoulder_right", 0.0, 90.0));
  if (mannequin_mvoxels > 0.0) {
    phantom::MannequinParams params;
    params.spacing_mm = phantom::mannequin_spacing_for_voxels(params, static_cast<int64_t>(mannequin_mvoxels * 1e6));
    if (!bench("mannequin", rig_of(phantom::make_mannequin(params)), knee_and_arm)) return 1;
  }
  if (body_mvoxels > 0.0) {
    phantom::BodyParams params;
    params.spacing_mm = phantom::body_spacing_for_voxels(params, static_cast<int64_t>(body_mvoxels * 1e6));
    if (!bench("body", rig_of(phantom::make_body(params)), knee_and_arm)) return 1;
  }
  std::cout << out.dump(2) << "\n";
  return 0;
}
