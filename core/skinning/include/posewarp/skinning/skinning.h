// Skinning of tet vertices: linear blend (LBS), dual quaternion (DQS, Kavan et al. 2008) and optimized centres of
// rotation (CoR, Le & Hodgins 2016), as used by Sujar et al. 2018 section 3.5.
#pragma once

#include <Eigen/Core>

#include <string_view>
#include <vector>

#include "posewarp/common/result.h"
#include "posewarp/common/tet_mesh.h"

namespace posewarp::skinning {

// kFem is CoR refined by the soft tissue's steady state (posewarp::fem), which needs the whole tet mesh: the engine
// runs it; skin() itself answers kFem with INVALID_ARGUMENT.
enum class Method { kLbs, kDqs, kCor, kFem };

std::string_view method_name(Method method);
// "lbs", "dqs", "cor" or "fem"; anything else is INVALID_ARGUMENT listing the four.
Result<Method> method_from_name(std::string_view name);

// Rest -> posed rigid transform per bone segment: p' = rotation[k] * p + translation[k] (LPS mm).
struct SegmentTransforms {
  std::vector<Eigen::Matrix3d> rotation;
  std::vector<Eigen::Vector3d> translation;
  size_t size() const { return rotation.size(); }
};

// v'_i = sum_j w_ij (R_j v_i + t_j). rest: #V x 3; result #V x 3.
Eigen::MatrixXd lbs(const Eigen::MatrixXd& rest, const SkinWeights& weights, const SegmentTransforms& transforms);

// Blends unit dual quaternions of the segments' full rest-to-posed transforms, each aligned to the hemisphere of
// the vertex's strongest influence, normalizes, applies (Kavan et al. 2008).
Eigen::MatrixXd dqs(const Eigen::MatrixXd& rest, const SkinWeights& weights, const SegmentTransforms& transforms);

// q = normalize(sum_j w_j q_j) (aligned), R = R(q), t = sum_j w_j T_j(c) - R c, v' = R v + t with c the vertex's
// centre of rotation; rigid vertices use LBS (one segment dominates them).
Eigen::MatrixXd cor(const Eigen::MatrixXd& rest, const SkinWeights& weights, const RotationCentres& centres,
                    const SegmentTransforms& transforms);

// Dispatches on `method`; checks that weights, centres and transforms fit the vertices (INVALID_ARGUMENT if not).
Result<Eigen::MatrixXd> skin(Method method, const Eigen::MatrixXd& rest, const SkinWeights& weights,
                             const RotationCentres& centres, const SegmentTransforms& transforms);

}  // namespace posewarp::skinning
