// Output grid policies: the input grid, the input grid grown to hold the posed body, or a given grid.
#include <Eigen/Dense>

#include <cmath>
#include <iomanip>
#include <sstream>

#include "posewarp/resample/tet_warp.h"

namespace posewarp::resample {

Result<ImageGeometry> output_geometry(GridPolicy policy, const ImageGeometry& source, const Eigen::MatrixXd& posed,
                                      const ImageGeometry* given, const ResampleParams& params) {
  POSEWARP_RETURN_IF_ERROR(validate(params));
  ImageGeometry out;
  switch (policy) {
    case GridPolicy::kInput: out = source; break;
    case GridPolicy::kGiven:
      if (given == nullptr) return invalid_argument_error("the 'given' output grid policy needs a grid");
      out = *given;
      break;
    case GridPolicy::kGrow: {
      out = source;
      double lo[3] = {0.0, 0.0, 0.0};
      double hi[3] = {static_cast<double>(source.size[0] - 1), static_cast<double>(source.size[1] - 1),
                      static_cast<double>(source.size[2] - 1)};
      const PhysicalToIndex to_index(source);
      for (int64_t v = 0; v < posed.rows(); ++v) {
        const Vec3 u = to_index({posed(v, 0), posed(v, 1), posed(v, 2)});
        for (int a = 0; a < 3; ++a) {
          if (!std::isfinite(u[a])) return invalid_argument_error("posed vertices are not finite");
          const double pad = params.grow_margin_mm / source.spacing[a];
          lo[a] = std::min(lo[a], std::floor(u[a] - pad));
          hi[a] = std::max(hi[a], std::ceil(u[a] + pad));
        }
      }
      for (int a = 0; a < 3; ++a) {
        const double extent = hi[a] - lo[a] + 1.0;
        if (!(extent <= 65536.0)) {
          // Printed as a double: a vertex 1e300 mm away makes an extent no integer type holds.
          std::ostringstream needed;
          needed << std::setprecision(6) << extent;
          return invalid_argument_error("growing the output grid to hold the posed body needs " + needed.str() +
                                        " voxels along axis " + std::to_string(a) +
                                        " (at most 65536); the pose moves the body absurdly far");
        }
        out.size[a] = static_cast<int64_t>(extent);
      }
      out.origin = source.index_to_physical({lo[0], lo[1], lo[2]});
      break;
    }
  }
  for (int a = 0; a < 3; ++a) {
    if (out.size[a] < 1 || out.size[a] > 65536) {
      return invalid_argument_error("the output grid is " + std::to_string(out.size[0]) + " x " +
                                    std::to_string(out.size[1]) + " x " + std::to_string(out.size[2]) +
                                    " voxels; each axis must hold 1..65536");
    }
  }
  POSEWARP_RETURN_IF_ERROR(out.validate().with_context("output grid"));
  if (out.voxel_count() > params.max_output_voxels) {
    return resource_exhausted_error("the output grid would hold " + std::to_string(out.voxel_count()) +
                                    " voxels, over the limit of " + std::to_string(params.max_output_voxels) +
                                    "; use a coarser or smaller grid");
  }
  return out;
}

}  // namespace posewarp::resample
