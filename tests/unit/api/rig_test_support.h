// A small bar rig shared by the api tests (built once per test binary).
#pragma once

#include "posewarp/api/rig.h"
#include "posewarp/phantom/phantom.h"

namespace posewarp::testing {

inline api::BuildParams small_bar_params() {
  api::BuildParams params;
  params.mesh.facet_size_mm = 4.0;
  params.mesh.facet_distance_mm = 1.0;
  params.mesh.bone_cell_size_mm = 4.0;
  params.mesh.soft_cell_size_mm = 8.0;
  params.mesh.parallel = false;
  return params;
}

inline api::BuildInputs bar_inputs() {
  phantom::BarParams bar;
  bar.length_mm = 160.0;
  bar.bone_count = 3;
  Result<phantom::Phantom> p = phantom::make_bar(bar);
  api::BuildInputs inputs;
  inputs.labels = p->labels;
  inputs.ct = p->ct;
  inputs.label_map = p->label_map;
  inputs.labels_source = "bar phantom";
  return inputs;
}

inline const api::Rig& shared_bar_rig() {
  static const api::Rig rig = [] {
    Result<api::Rig> built = api::build_rig(bar_inputs(), small_bar_params(), {});
    if (!built.ok()) throw std::runtime_error(built.status().to_string());
    return std::move(built).value();
  }();
  return rig;
}

// The same bar with its joints' gaps left whole (slide_joint_gaps off): meshed alike, the shared rig less the cut.
inline const api::Rig& shared_welded_bar_rig() {
  static const api::Rig rig = [] {
    api::BuildParams params = small_bar_params();
    params.mesh.slide_joint_gaps = false;
    Result<api::Rig> built = api::build_rig(bar_inputs(), params, {});
    if (!built.ok()) throw std::runtime_error(built.status().to_string());
    return std::move(built).value();
  }();
  return rig;
}

}  // namespace posewarp::testing
