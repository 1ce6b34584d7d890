// The rigs the service benchmarks pose (the real sample's, the mannequin and body phantoms', cached between runs
// since a 20M-voxel phantom's takes minutes to build) and their percentiles.
#pragma once

#include <algorithm>
#include <filesystem>
#include <stdexcept>
#include <string>
#include <vector>

#include "posewarp/api/files.h"
#include "posewarp/api/rig_file.h"
#include "posewarp/api/study.h"

namespace posewarp::bench {

// p-th percentile (0..100) of `values`.
inline double percentile(std::vector<double> values, double p) {
  if (values.empty()) return 0.0;
  std::sort(values.begin(), values.end());
  const size_t at =
      std::min(values.size() - 1, static_cast<size_t>(p / 100.0 * static_cast<double>(values.size() - 1) + 0.5));
  return values[at];
}

// The sample's rig (data/totalsegmentator_example, default parameters), as rig file bytes.
inline std::string sample_rig_bytes(const std::string& sample_dir) {
  api::BuildInputs sample;
  sample.labels = *api::read_label_volume(sample_dir + "/seg_total.nii.gz");
  sample.ct = *api::read_intensity_volume(sample_dir + "/ct.nii.gz");
  sample.label_map = *api::preset_by_name("totalsegmentator");
  Result<api::Rig> rig = api::build_rig(sample, {}, {});
  if (!rig.ok()) throw std::runtime_error(rig.status().to_string());
  return api::rig_to_bytes(*rig);
}

// A phantom's rig ("mannequin" or "body") at about `mvoxels` million voxels; with a cache directory, read from or
// kept in KIND-M.rig there.
inline std::string phantom_rig_bytes(const std::string& kind, double mvoxels, const std::filesystem::path& cache) {
  const std::filesystem::path cached =
      cache.empty() ? std::filesystem::path() : cache / (kind + "-" + std::to_string(mvoxels) + ".rig");
  if (!cached.empty() && std::filesystem::exists(cached)) {
    Result<std::string> bytes = api::read_text_input(cached.string(), "cached bench rig", int64_t{1} << 34);
    if (!bytes.ok()) throw std::runtime_error(bytes.status().to_string());
    return *bytes;
  }
  const auto voxels = static_cast<int64_t>(mvoxels * 1e6);
  if (kind != "mannequin" && kind != "body")
    throw std::runtime_error("unknown phantom '" + kind + "'; known: mannequin, body");
  Result<api::Phantom> p = [&] {
    if (kind == "body") {
      api::BodyParams params;
      params.spacing_mm = api::body_spacing_for_voxels(params, voxels);
      return api::make_body(params);
    }
    api::MannequinParams params;
    params.spacing_mm = api::mannequin_spacing_for_voxels(params, voxels);
    return api::make_mannequin(params);
  }();
  if (!p.ok()) throw std::runtime_error(p.status().to_string());
  api::BuildInputs inputs;
  inputs.labels = p->labels;
  inputs.ct = p->ct;
  inputs.label_map = p->label_map;
  Result<api::Rig> rig = api::build_rig(inputs, {}, {});
  if (!rig.ok()) throw std::runtime_error(rig.status().to_string());
  std::string bytes = api::rig_to_bytes(*rig);
  if (!cached.empty()) {
    std::filesystem::create_directories(cache);
    if (Status s = api::write_file_atomically(cached.string(), bytes, "bench rig"); !s.ok())
      throw std::runtime_error(s.to_string());
  }
  return bytes;
}

}  // namespace posewarp::bench
