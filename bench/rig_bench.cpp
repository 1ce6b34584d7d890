// Rig build stage timings for the mannequin at ~1M, ~5M and ~20M voxels, the anatomical body phantom at ~20M voxels
// (oblique, anisotropic, arms against the trunk) and the real sample.
// Usage: posewarp_bench_rig [--threads N] [--sizes 1,5,20] [--body-mvoxels M (0 = skip)] [--no-sample]
// Prints one line per case with voxels, vertices, tets and seconds per stage, and a JSON summary at the end.
#include <nlohmann/json.hpp>

#include <chrono>
#include <cstdio>
#include <cstring>
#include <iostream>
#include <sstream>
#include <string>
#include <vector>

#include "posewarp/api/rig.h"
#include "posewarp/common/parallel.h"
#include "posewarp/io/volume_io.h"
#include "posewarp/labels/presets.h"
#include "posewarp/phantom/phantom.h"

namespace {

using namespace posewarp;

nlohmann::json run_case(const std::string& name, api::BuildInputs inputs) {
  const auto start = std::chrono::steady_clock::now();
  Result<api::Rig> rig = api::build_rig(inputs, api::BuildParams{}, {});
  const double total = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  nlohmann::json row{{"case", name}, {"voxels", inputs.labels.voxel_count()}, {"threads", thread_count()}};
  if (!rig.ok()) {
    row["error"] = rig.status().to_string();
    std::printf("%-16s %10lld voxels  FAILED: %s\n", name.c_str(), static_cast<long long>(inputs.labels.voxel_count()),
                rig.status().to_string().c_str());
    return row;
  }
  row["vertices"] = rig->mesh.vertex_count();
  row["tets"] = rig->mesh.tet_count();
  row["joints"] = rig->skeleton.joints.size();
  row["total_s"] = total;
  std::printf("%-16s %10lld voxels %8lld vertices %9lld tets %3zu joints  total %6.2f s:", name.c_str(),
              static_cast<long long>(inputs.labels.voxel_count()), static_cast<long long>(rig->mesh.vertex_count()),
              static_cast<long long>(rig->mesh.tet_count()), rig->skeleton.joints.size(), total);
  for (const auto& [stage, seconds] : rig->provenance.stage_seconds) {
    row["stages"][stage] = seconds;
    std::printf(" %s %.2f", stage.c_str(), seconds);
  }
  std::printf("\n");
  std::fflush(stdout);
  return row;
}

}  // namespace

int main(int argc, char** argv) {
  int threads = 0;
  std::vector<int> sizes{1, 5, 20};
  bool sample = true;
  double body_mvoxels = 20.0;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--threads") && i + 1 < argc) {
      threads = std::atoi(argv[++i]);
    } else if (!std::strcmp(argv[i], "--sizes") && i + 1 < argc) {
      sizes.clear();
      std::stringstream list(argv[++i]);
      std::string item;
      while (std::getline(list, item, ',')) sizes.push_back(std::atoi(item.c_str()));
    } else if (!std::strcmp(argv[i], "--body-mvoxels") && i + 1 < argc) {
      body_mvoxels = std::atof(argv[++i]);
    } else if (!std::strcmp(argv[i], "--no-sample")) {
      sample = false;
    } else {
      std::fprintf(stderr, "usage: %s [--threads N] [--sizes 1,5,20] [--body-mvoxels M] [--no-sample]\n", argv[0]);
      return 2;
    }
  }
  set_thread_count(threads);
  nlohmann::json rows = nlohmann::json::array();
  if (sample) {
    const std::string dir = POSEWARP_SAMPLE_DIR;
    api::BuildInputs inputs;
    inputs.labels = *io::read_label_volume(dir + "/seg_total.nii.gz");
    inputs.ct = *io::read_intensity_volume(dir + "/ct.nii.gz");
    inputs.label_map = labels::totalsegmentator_v2_preset();
    rows.push_back(run_case("real-sample", inputs));
  }
  for (const int millions : sizes) {
    phantom::MannequinParams params;
    params.spacing_mm = phantom::mannequin_spacing_for_voxels(params, int64_t{millions} * 1'000'000);
    Result<phantom::Phantom> m = phantom::make_mannequin(params);
    if (!m.ok()) {
      std::fprintf(stderr, "%s\n", m.status().to_string().c_str());
      return 1;
    }
    api::BuildInputs inputs;
    inputs.labels = m->labels;
    inputs.ct = m->ct;
    inputs.label_map = m->label_map;
    rows.push_back(run_case("mannequin-" + std::to_string(millions) + "M", inputs));
  }
  if (body_mvoxels > 0.0) {
    phantom::BodyParams params;
    params.spacing_mm = phantom::body_spacing_for_voxels(params, static_cast<int64_t>(body_mvoxels * 1e6));
    Result<phantom::Phantom> body = phantom::make_body(params);
    if (!body.ok()) {
      std::fprintf(stderr, "%s\n", body.status().to_string().c_str());
      return 1;
    }
    api::BuildInputs inputs;
    inputs.labels = body->labels;
    inputs.ct = body->ct;
    inputs.label_map = body->label_map;
    rows.push_back(run_case("body-" + std::to_string(static_cast<int>(body_mvoxels)) + "M", inputs));
  }
  std::cout << rows.dump(2) << "\n";
  return 0;
}
