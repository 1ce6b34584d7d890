// The api's own small types: how a request names its method, its output grid and its CT interpolation, and the
// limits on what it may allocate. The engine turns them into its stages' settings; a client names no stage.
#pragma once

#include <cstdint>
#include <string_view>

#include "posewarp/common/result.h"

namespace posewarp::api {

// How the tet mesh follows the skeleton (Sujar et al. 2018 section 3.5; fem: the paper's section 5).
//   kCor: optimized centres of rotation (Le & Hodgins 2016), the default
//   kDqs: dual quaternions (Kavan et al. 2008)
//   kLbs: linear blend
//   kFem: CoR, then the soft tissue's volume-preserving steady state with the bones fixed
enum class Method { kCor, kDqs, kLbs, kFem };

// "cor", "dqs", "lbs" or "fem".
std::string_view method_name(Method method);
// The inverse of method_name; anything else is INVALID_ARGUMENT listing the four.
Result<Method> method_from_name(std::string_view name);

// The output grid: the input grid, the input grid grown to hold the posed body, or a grid the request gives.
enum class GridPolicy { kInput, kGrow, kGiven };

// How the CT is sampled at a voxel's source position (labels are always taken from the nearest voxel).
enum class Interpolation { kLinear, kNearest };

// What a pose may allocate for its output, checked before anything large is allocated.
struct OutputLimits {
  int64_t max_voxels = int64_t{1} << 29;  // of the output grid
  int64_t max_bytes = 0;                  // owner map, labels, CT and fields; 0: half the machine's memory
};

}  // namespace posewarp::api
