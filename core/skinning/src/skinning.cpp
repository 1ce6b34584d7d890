// LBS, DQS and CoR skinning over tet vertices, parallel over vertex chunks.
#include "posewarp/skinning/skinning.h"

#include <Eigen/Geometry>

#include <array>
#include <cmath>

#include "posewarp/common/parallel.h"

namespace posewarp::skinning {
namespace {

constexpr int64_t kGrain = 8192;

// Row-major 3x4 [R | t] per segment, as flat doubles for the inner loops.
std::vector<std::array<double, 12>> affine_rows(const SegmentTransforms& transforms) {
  std::vector<std::array<double, 12>> rows(transforms.size());
  for (size_t s = 0; s < transforms.size(); ++s) {
    for (int r = 0; r < 3; ++r) {
      for (int c = 0; c < 3; ++c) rows[s][static_cast<size_t>(4 * r + c)] = transforms.rotation[s](r, c);
      rows[s][static_cast<size_t>(4 * r + 3)] = transforms.translation[s](r);
    }
  }
  return rows;
}

// Unit dual quaternion (real w,x,y,z; dual w,x,y,z) of each segment's rigid transform.
struct DualQuaternion {
  std::array<double, 4> real;
  std::array<double, 4> dual;
};

std::vector<DualQuaternion> dual_quaternions(const SegmentTransforms& transforms) {
  std::vector<DualQuaternion> dq(transforms.size());
  for (size_t s = 0; s < transforms.size(); ++s) {
    Eigen::Quaterniond q(transforms.rotation[s]);
    q.normalize();
    const Eigen::Vector3d& t = transforms.translation[s];
    // dual = 0.5 * (0, t) * q
    const double w = q.w(), x = q.x(), y = q.y(), z = q.z();
    dq[s].real = {w, x, y, z};
    dq[s].dual = {-0.5 * (t.x() * x + t.y() * y + t.z() * z), 0.5 * (t.x() * w + t.y() * z - t.z() * y),
                  0.5 * (-t.x() * z + t.y() * w + t.z() * x), 0.5 * (t.x() * y - t.y() * x + t.z() * w)};
  }
  return dq;
}

// Rotation matrix (row-major) of a unit quaternion.
inline void rotation_of(const double q[4], double r[9]) {
  const double w = q[0], x = q[1], y = q[2], z = q[3];
  r[0] = 1 - 2 * (y * y + z * z);
  r[1] = 2 * (x * y - w * z);
  r[2] = 2 * (x * z + w * y);
  r[3] = 2 * (x * y + w * z);
  r[4] = 1 - 2 * (x * x + z * z);
  r[5] = 2 * (y * z - w * x);
  r[6] = 2 * (x * z - w * y);
  r[7] = 2 * (y * z + w * x);
  r[8] = 1 - 2 * (x * x + y * y);
}

// Blends the real (and optionally dual) parts of the influences of vertex v, aligned to the first influence's
// hemisphere. Returns the norm of the blended real part.
inline double blend(const SkinWeights& weights, const std::vector<DualQuaternion>& dq, int64_t v, double real[4],
                    double* dual) {
  const int32_t* segment = weights.segment.data() + v * weights.influences;
  const float* weight = weights.weight.data() + v * weights.influences;
  real[0] = real[1] = real[2] = real[3] = 0.0;
  if (dual) dual[0] = dual[1] = dual[2] = dual[3] = 0.0;
  const double* pivot = dq[static_cast<size_t>(segment[0] < 0 ? 0 : segment[0])].real.data();
  for (int i = 0; i < weights.influences; ++i) {
    const int32_t s = segment[i];
    if (s < 0) break;
    const DualQuaternion& q = dq[static_cast<size_t>(s)];
    const double dot = q.real[0] * pivot[0] + q.real[1] * pivot[1] + q.real[2] * pivot[2] + q.real[3] * pivot[3];
    const double w = dot < 0.0 ? -static_cast<double>(weight[i]) : static_cast<double>(weight[i]);
    for (int c = 0; c < 4; ++c) real[c] += w * q.real[static_cast<size_t>(c)];
    if (dual) {
      for (int c = 0; c < 4; ++c) dual[c] += w * q.dual[static_cast<size_t>(c)];
    }
  }
  return std::sqrt(real[0] * real[0] + real[1] * real[1] + real[2] * real[2] + real[3] * real[3]);
}

inline void lbs_vertex(const SkinWeights& weights, const std::vector<std::array<double, 12>>& m, int64_t v,
                       const double p[3], double out[3]) {
  const int32_t* segment = weights.segment.data() + v * weights.influences;
  const float* weight = weights.weight.data() + v * weights.influences;
  double x = 0.0, y = 0.0, z = 0.0, total = 0.0;
  for (int i = 0; i < weights.influences; ++i) {
    const int32_t s = segment[i];
    if (s < 0) break;
    const double w = weight[i];
    total += w;
    const double* a = m[static_cast<size_t>(s)].data();
    x += w * (a[0] * p[0] + a[1] * p[1] + a[2] * p[2] + a[3]);
    y += w * (a[4] * p[0] + a[5] * p[1] + a[6] * p[2] + a[7]);
    z += w * (a[8] * p[0] + a[9] * p[1] + a[10] * p[2] + a[11]);
  }
  // Weights are stored as float: renormalize in double so the rest pose is reproduced to rounding.
  const double inv = total > 0.0 ? 1.0 / total : 1.0;
  out[0] = x * inv;
  out[1] = y * inv;
  out[2] = z * inv;
}

}  // namespace

std::string_view method_name(Method method) {
  switch (method) {
    case Method::kLbs: return "lbs";
    case Method::kDqs: return "dqs";
    case Method::kCor: return "cor";
  }
  return "cor";
}

Result<Method> method_from_name(std::string_view name) {
  if (name == "lbs") return Method::kLbs;
  if (name == "dqs") return Method::kDqs;
  if (name == "cor") return Method::kCor;
  return invalid_argument_error("unknown skinning method '" + std::string(name) + "'; use lbs, dqs or cor");
}

Eigen::MatrixXd lbs(const Eigen::MatrixXd& rest, const SkinWeights& weights, const SegmentTransforms& transforms) {
  const auto m = affine_rows(transforms);
  const int64_t n = rest.rows();
  Eigen::MatrixXd posed(n, 3);
  parallel_for(0, n, kGrain, [&](int64_t begin, int64_t end) {
    for (int64_t v = begin; v < end; ++v) {
      const double p[3] = {rest(v, 0), rest(v, 1), rest(v, 2)};
      double out[3];
      lbs_vertex(weights, m, v, p, out);
      posed(v, 0) = out[0];
      posed(v, 1) = out[1];
      posed(v, 2) = out[2];
    }
  });
  return posed;
}

Eigen::MatrixXd dqs(const Eigen::MatrixXd& rest, const SkinWeights& weights, const SegmentTransforms& transforms) {
  const auto dq = dual_quaternions(transforms);
  const int64_t n = rest.rows();
  Eigen::MatrixXd posed(n, 3);
  parallel_for(0, n, kGrain, [&](int64_t begin, int64_t end) {
    for (int64_t v = begin; v < end; ++v) {
      double real[4], dual[4];
      const double norm = blend(weights, dq, v, real, dual);
      const double inv = 1.0 / norm;
      for (int c = 0; c < 4; ++c) real[c] *= inv, dual[c] *= inv;
      double r[9];
      rotation_of(real, r);
      // t = 2 * (dual * conj(real)).vec
      const double w0 = real[0], x0 = real[1], y0 = real[2], z0 = real[3];
      const double we = dual[0], xe = dual[1], ye = dual[2], ze = dual[3];
      const double tx = 2.0 * (-we * x0 + xe * w0 - ye * z0 + ze * y0);
      const double ty = 2.0 * (-we * y0 + xe * z0 + ye * w0 - ze * x0);
      const double tz = 2.0 * (-we * z0 - xe * y0 + ye * x0 + ze * w0);
      const double p[3] = {rest(v, 0), rest(v, 1), rest(v, 2)};
      posed(v, 0) = r[0] * p[0] + r[1] * p[1] + r[2] * p[2] + tx;
      posed(v, 1) = r[3] * p[0] + r[4] * p[1] + r[5] * p[2] + ty;
      posed(v, 2) = r[6] * p[0] + r[7] * p[1] + r[8] * p[2] + tz;
    }
  });
  return posed;
}

Eigen::MatrixXd cor(const Eigen::MatrixXd& rest, const SkinWeights& weights, const RotationCentres& centres,
                    const SegmentTransforms& transforms) {
  const auto dq = dual_quaternions(transforms);
  const auto m = affine_rows(transforms);
  const int64_t n = rest.rows();
  Eigen::MatrixXd posed(n, 3);
  parallel_for(0, n, kGrain, [&](int64_t begin, int64_t end) {
    for (int64_t v = begin; v < end; ++v) {
      const double p[3] = {rest(v, 0), rest(v, 1), rest(v, 2)};
      if (centres.rigid[static_cast<size_t>(v)]) {
        double out[3];
        lbs_vertex(weights, m, v, p, out);
        posed(v, 0) = out[0];
        posed(v, 1) = out[1];
        posed(v, 2) = out[2];
        continue;
      }
      double real[4];
      const double norm = blend(weights, dq, v, real, nullptr);
      for (double& c : real) c /= norm;
      double r[9];
      rotation_of(real, r);
      const double c[3] = {centres.centre(v, 0), centres.centre(v, 1), centres.centre(v, 2)};
      double blended_c[3];
      lbs_vertex(weights, m, v, c, blended_c);  // sum_j w_j T_j(c)
      const double rc[3] = {r[0] * c[0] + r[1] * c[1] + r[2] * c[2], r[3] * c[0] + r[4] * c[1] + r[5] * c[2],
                            r[6] * c[0] + r[7] * c[1] + r[8] * c[2]};
      posed(v, 0) = r[0] * p[0] + r[1] * p[1] + r[2] * p[2] + blended_c[0] - rc[0];
      posed(v, 1) = r[3] * p[0] + r[4] * p[1] + r[5] * p[2] + blended_c[1] - rc[1];
      posed(v, 2) = r[6] * p[0] + r[7] * p[1] + r[8] * p[2] + blended_c[2] - rc[2];
    }
  });
  return posed;
}

Result<Eigen::MatrixXd> skin(Method method, const Eigen::MatrixXd& rest, const SkinWeights& weights,
                             const RotationCentres& centres, const SegmentTransforms& transforms) {
  if (rest.cols() != 3) return invalid_argument_error("rest vertices must be #V x 3");
  if (weights.vertex_count() != rest.rows()) {
    return invalid_argument_error("the weights cover " + std::to_string(weights.vertex_count()) + " vertices, the mesh has " +
                                  std::to_string(rest.rows()));
  }
  if (transforms.rotation.size() != transforms.translation.size() ||
      static_cast<int>(transforms.size()) < weights.segment_count) {
    return invalid_argument_error("need one transform per bone segment (" + std::to_string(weights.segment_count) +
                                  "), got " + std::to_string(transforms.size()));
  }
  if (method == Method::kCor &&
      (centres.centre.rows() != rest.rows() || static_cast<int64_t>(centres.rigid.size()) != rest.rows())) {
    return invalid_argument_error("CoR skinning needs a centre of rotation for every vertex; rebuild the rig");
  }
  switch (method) {
    case Method::kLbs: return lbs(rest, weights, transforms);
    case Method::kDqs: return dqs(rest, weights, transforms);
    case Method::kCor: return cor(rest, weights, centres, transforms);
  }
  return internal_error("unhandled skinning method");
}

}  // namespace posewarp::skinning
