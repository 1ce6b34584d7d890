// A triangle surface in LPS millimetres: a bone's, the skin's or a user's mesh. Vocabulary shared by the stages that
// make, embed and deform surfaces and by the api that hands them out (posewarp::surface reads, writes and extracts
// them).
#pragma once

#include <Eigen/Core>

#include <string>

#include "posewarp/common/volume.h"

namespace posewarp {

struct SurfaceMesh {
  std::string name;           // the label's name, or a file's stem
  Label label = 0;            // the label it bounds (0 for a user's mesh or the skin)
  Eigen::MatrixXd vertices;   // #V x 3, LPS mm
  Eigen::MatrixXi triangles;  // #F x 3 vertex indices, counter-clockwise seen from outside (outward normals)
};

}  // namespace posewarp
