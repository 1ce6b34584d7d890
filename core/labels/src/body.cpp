// Body mask (labels joined with a CT threshold, largest component, holes filled) and mesher classes.
#include "posewarp/labels/body.h"

#include <algorithm>
#include <cmath>
#include <unordered_map>
#include <vector>

#include "posewarp/common/parallel.h"

namespace posewarp::labels {
namespace {

// Marks the largest 6-connected component of mask != 0 with 1 and clears the rest.
void keep_largest_component(std::vector<uint8_t>& mask, const Index3& size) {
  const int64_t nx = size[0], ny = size[1], nz = size[2];
  std::vector<int32_t> component(mask.size(), -1);
  std::vector<int64_t> component_sizes;
  std::vector<int64_t> stack;
  for (int64_t seed = 0; seed < static_cast<int64_t>(mask.size()); ++seed) {
    if (!mask[seed] || component[seed] >= 0) continue;
    const int32_t id = static_cast<int32_t>(component_sizes.size());
    int64_t count = 0;
    stack.push_back(seed);
    component[seed] = id;
    while (!stack.empty()) {
      const int64_t v = stack.back();
      stack.pop_back();
      ++count;
      const int64_t i = v % nx, j = (v / nx) % ny, k = v / (nx * ny);
      const int64_t neighbours[6] = {i > 0 ? v - 1 : -1,           i + 1 < nx ? v + 1 : -1,
                                     j > 0 ? v - nx : -1,          j + 1 < ny ? v + nx : -1,
                                     k > 0 ? v - nx * ny : -1,     k + 1 < nz ? v + nx * ny : -1};
      for (const int64_t n : neighbours) {
        if (n >= 0 && mask[n] && component[n] < 0) {
          component[n] = id;
          stack.push_back(n);
        }
      }
    }
    component_sizes.push_back(count);
  }
  if (component_sizes.empty()) return;
  const int32_t largest = static_cast<int32_t>(
      std::max_element(component_sizes.begin(), component_sizes.end()) - component_sizes.begin());
  for (size_t v = 0; v < mask.size(); ++v) mask[v] = component[v] == largest ? 1 : 0;
}

// The grid axis whose direction is closest to LPS z (superior-inferior).
int axial_axis(const ImageGeometry& g) {
  int best = 2;
  double best_dot = -1.0;
  for (int axis = 0; axis < 3; ++axis) {
    const double dot = std::abs(g.direction[6 + axis]);
    if (dot > best_dot) best_dot = dot, best = axis;
  }
  return best;
}

// Fills background regions of each slice (normal to `axis`) that do not reach the slice border.
void fill_holes_per_slice(std::vector<uint8_t>& mask, const Index3& size, int axis) {
  const int u_axis = axis == 0 ? 1 : 0;
  const int v_axis = axis == 2 ? 1 : 2;
  const int64_t nu = size[u_axis], nv = size[v_axis];
  const int64_t stride[3] = {1, size[0], size[0] * size[1]};
  parallel_for(0, size[axis], 1, [&](int64_t s0, int64_t s1) {
    std::vector<uint8_t> outside(static_cast<size_t>(nu * nv));
    std::vector<int64_t> stack;
    for (int64_t s = s0; s < s1; ++s) {
      auto voxel = [&](int64_t u, int64_t v) { return s * stride[axis] + u * stride[u_axis] + v * stride[v_axis]; };
      std::fill(outside.begin(), outside.end(), 0);
      auto push = [&](int64_t u, int64_t v) {
        const int64_t cell = u + nu * v;
        if (!outside[cell] && !mask[voxel(u, v)]) {
          outside[cell] = 1;
          stack.push_back(cell);
        }
      };
      for (int64_t u = 0; u < nu; ++u) push(u, 0), push(u, nv - 1);
      for (int64_t v = 0; v < nv; ++v) push(0, v), push(nu - 1, v);
      while (!stack.empty()) {
        const int64_t cell = stack.back();
        stack.pop_back();
        const int64_t u = cell % nu, v = cell / nu;
        if (u > 0) push(u - 1, v);
        if (u + 1 < nu) push(u + 1, v);
        if (v > 0) push(u, v - 1);
        if (v + 1 < nv) push(u, v + 1);
      }
      for (int64_t v = 0; v < nv; ++v) {
        for (int64_t u = 0; u < nu; ++u) {
          if (!outside[u + nu * v]) mask[voxel(u, v)] = 1;
        }
      }
    }
  });
}

}  // namespace

Status validate(const BodyParams& params) {
  if (!std::isfinite(params.ct_threshold_hu)) return invalid_argument_error("body CT threshold must be finite");
  return ok_status();
}

Result<LabelVolume> body_mask(const LabelMap& map, const LabelVolume& labels, const IntensityVolume* ct,
                              const BodyParams& params) {
  POSEWARP_RETURN_IF_ERROR(validate(params));
  if (labels.empty()) return invalid_argument_error("the label volume is empty");
  const bool with_ct = ct != nullptr && params.use_ct;
  if (with_ct && !ct->geometry().same_grid(labels.geometry(), 1e-3)) {
    return invalid_argument_error("the CT (" + ct->geometry().describe() + ") and the labels (" +
                                  labels.geometry().describe() +
                                  ") are not on the same grid; resample one onto the other first");
  }
  const size_t n = static_cast<size_t>(labels.voxel_count());
  std::vector<uint8_t> mask(n, 0);
  if (with_ct) {
    for (size_t v = 0; v < n; ++v) mask[v] = ct->data()[v] > params.ct_threshold_hu ? 1 : 0;
    if (params.keep_largest_component) keep_largest_component(mask, labels.size());
  }
  // Labelled voxels are body whatever the CT says (lungs, airways).
  std::unordered_map<Label, bool> in_body;
  for (size_t v = 0; v < n; ++v) {
    const Label value = labels.data()[v];
    if (value == 0) continue;
    auto it = in_body.find(value);
    if (it == in_body.end()) it = in_body.emplace(value, map.role_of(value) != LabelRole::kBackground).first;
    if (it->second) mask[v] = 1;
  }
  if (params.fill_holes) fill_holes_per_slice(mask, labels.size(), axial_axis(labels.geometry()));
  LabelVolume body(labels.geometry(), 0);
  body.set_source_type(PixelType::kUInt8);
  std::copy(mask.begin(), mask.end(), body.data());
  return body;
}

LabelVolume segment_classes(const LabelMap& map, const LabelVolume& labels, const LabelVolume& body) {
  std::unordered_map<Label, Label> class_of;
  const std::vector<std::string> segments = map.bone_segments();
  for (size_t k = 0; k < segments.size(); ++k) {
    for (const Label value : map.labels_of_segment(segments[k])) class_of[value] = static_cast<Label>(2 + k);
  }
  LabelVolume classes(labels.geometry(), 0);
  classes.set_source_type(segments.size() + 2 <= 255 ? PixelType::kUInt8 : PixelType::kUInt16);
  const int64_t n = labels.voxel_count();
  for (int64_t v = 0; v < n; ++v) {
    const Label value = labels.data()[v];
    auto it = class_of.find(value);
    if (it != class_of.end()) {
      classes.data()[v] = it->second;  // bone wins even where the body mask missed it
    } else if (body.data()[v] != 0) {
      classes.data()[v] = 1;
    }
  }
  return classes;
}

}  // namespace posewarp::labels
