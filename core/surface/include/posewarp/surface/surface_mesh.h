// Triangle surfaces: per-label surfaces at rest (VTK discrete flying edges, smoothing, decimation) and mesh files
// (STL, OBJ, PLY, VTP).
#pragma once

#include <Eigen/Core>

#include <string>
#include <utility>
#include <vector>

#include "posewarp/common/progress.h"
#include "posewarp/common/result.h"
#include "posewarp/common/volume.h"

namespace posewarp::surface {

struct SurfaceMesh {
  std::string name;
  Label label = 0;             // the label it bounds (0 for a user's mesh)
  Eigen::MatrixXd vertices;    // #V x 3, LPS mm
  Eigen::MatrixXi triangles;   // #F x 3
};

struct SurfaceParams {
  int smoothing_iterations = 20;  // windowed-sinc smoothing passes, 0 = none
  double pass_band = 0.1;         // windowed-sinc pass band (smaller smooths more)
  double decimation = 0.5;        // fraction of triangles removed by quadric decimation, 0 = none
};

Status validate(const SurfaceParams& params);

// One surface per wanted label present in the volume, in physical LPS mm (spacing, origin and direction applied).
// `mask` labels: a non-zero entry of `wanted` matches that label value only.
Result<std::vector<SurfaceMesh>> extract_label_surfaces(const LabelVolume& labels,
                                                        const std::vector<std::pair<Label, std::string>>& wanted,
                                                        const SurfaceParams& params, const ProgressHooks& hooks);

// By extension: .stl, .obj, .ply, .vtp. Missing, empty or unreadable files are errors naming the file.
Result<SurfaceMesh> read_surface(const std::string& path);
// Written to a temporary file and renamed into place.
Status write_surface(const SurfaceMesh& mesh, const std::string& path);

}  // namespace posewarp::surface
