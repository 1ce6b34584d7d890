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

// Hemisphere signs: sign[a * S + b] = +1 or -1 as segment b's rotation quaternion lies on the hemisphere of a's.
// A vertex blends every influence on the hemisphere of its first (strongest) one; the table saves a dot product
// per influence per vertex.
std::vector<double> hemisphere_signs(const std::vector<DualQuaternion>& dq) {
  const size_t n = dq.size();
  std::vector<double> sign(n * n);
  for (size_t a = 0; a < n; ++a) {
    for (size_t b = 0; b < n; ++b) {
      double dot = 0.0;
      for (size_t c = 0; c < 4; ++c) dot += dq[a].real[c] * dq[b].real[c];
      sign[a * n + b] = dot < 0.0 ? -1.0 : 1.0;
    }
  }
  return sign;
}

// Blends the real (and optionally dual) parts of the influences of vertex v, aligned to the first influence's
// hemisphere. Returns the squared norm of the blended real part.
inline double blend(const SkinWeights& weights, const std::vector<DualQuaternion>& dq, const std::vector<double>& sign,
                    int64_t v, double real[4], double* dual) {
  const int32_t* segment = weights.segment.data() + v * weights.influences;
  const float* weight = weights.weight.data() + v * weights.influences;
  real[0] = real[1] = real[2] = real[3] = 0.0;
  if (dual) dual[0] = dual[1] = dual[2] = dual[3] = 0.0;
  const double* pivot_sign = sign.data() + static_cast<size_t>(segment[0] < 0 ? 0 : segment[0]) * dq.size();
  for (int i = 0; i < weights.influences; ++i) {
    const int32_t s = segment[i];
    if (s < 0) break;
    const DualQuaternion& q = dq[static_cast<size_t>(s)];
    const double w = pivot_sign[s] * static_cast<double>(weight[i]);
    for (int c = 0; c < 4; ++c) real[c] += w * q.real[static_cast<size_t>(c)];
    if (dual) {
      for (int c = 0; c < 4; ++c) dual[c] += w * q.dual[static_cast<size_t>(c)];
    }
  }
  return real[0] * real[0] + real[1] * real[1] + real[2] * real[2] + real[3] * real[3];
}

// Rotates u by the (not necessarily unit) quaternion q = (w, r) with squared norm n2 and adds the result to out:
// q u q* / n2 = u + (2 / n2) (w (r x u) + r x (r x u)) (Kavan et al. 2008), no square root.
inline void add_rotated(const double q[4], double scale, const double u[3], double out[3]) {
  const double w = q[0], x = q[1], y = q[2], z = q[3];
  const double a0 = y * u[2] - z * u[1] + w * u[0];  // r x u + w u
  const double a1 = z * u[0] - x * u[2] + w * u[1];
  const double a2 = x * u[1] - y * u[0] + w * u[2];
  out[0] += u[0] + scale * (y * a2 - z * a1);       // u + scale * r x (r x u + w u)
  out[1] += u[1] + scale * (z * a0 - x * a2);
  out[2] += u[2] + scale * (x * a1 - y * a0);
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
    case Method::kFem: return "fem";
  }
  return "cor";
}

Result<Method> method_from_name(std::string_view name) {
  if (name == "lbs") return Method::kLbs;
  if (name == "dqs") return Method::kDqs;
  if (name == "cor") return Method::kCor;
  if (name == "fem") return Method::kFem;
  return invalid_argument_error("unknown method '" + std::string(name) + "'; use lbs, dqs, cor or fem");
}

namespace {

// Every rest vertex through `vertex(v, p, out)` (p its rest position, out its posed one), in parallel: #V x 3.
template <typename Vertex>
Eigen::MatrixXd pose_each_vertex(const Eigen::MatrixXd& rest, const Vertex& vertex) {
  const int64_t n = rest.rows();
  Eigen::MatrixXd posed(n, 3);
  parallel_for(0, n, kGrain, [&](int64_t begin, int64_t end) {
    for (int64_t v = begin; v < end; ++v) {
      const double p[3] = {rest(v, 0), rest(v, 1), rest(v, 2)};
      double out[3];
      vertex(v, p, out);
      posed(v, 0) = out[0];
      posed(v, 1) = out[1];
      posed(v, 2) = out[2];
    }
  });
  return posed;
}

}  // namespace

Eigen::MatrixXd lbs(const Eigen::MatrixXd& rest, const SkinWeights& weights, const SegmentTransforms& transforms) {
  const auto m = affine_rows(transforms);
  return pose_each_vertex(rest, [&](int64_t v, const double p[3], double out[3]) {
    lbs_vertex(weights, m, v, p, out);
  });
}

Eigen::MatrixXd dqs(const Eigen::MatrixXd& rest, const SkinWeights& weights, const SegmentTransforms& transforms) {
  const auto dq = dual_quaternions(transforms);
  const auto sign = hemisphere_signs(dq);
  return pose_each_vertex(rest, [&](int64_t v, const double p[3], double out[3]) {
    double b0[4], be[4];
    const double scale = 2.0 / blend(weights, dq, sign, v, b0, be);
    // v' = v + scale (r x (r x v + w v + d) + w d - d_w r) with b0 = (w, r), be = (d_w, d): the rotation and
    // translation of the normalized blend in one (Kavan et al. 2008, section 3.3).
    const double w = b0[0], x = b0[1], y = b0[2], z = b0[3];
    const double a0 = y * p[2] - z * p[1] + w * p[0] + be[1];
    const double a1 = z * p[0] - x * p[2] + w * p[1] + be[2];
    const double a2 = x * p[1] - y * p[0] + w * p[2] + be[3];
    out[0] = p[0] + scale * (y * a2 - z * a1 + w * be[1] - be[0] * x);
    out[1] = p[1] + scale * (z * a0 - x * a2 + w * be[2] - be[0] * y);
    out[2] = p[2] + scale * (x * a1 - y * a0 + w * be[3] - be[0] * z);
  });
}

Eigen::MatrixXd cor(const Eigen::MatrixXd& rest, const SkinWeights& weights, const RotationCentres& centres,
                    const SegmentTransforms& transforms) {
  const auto dq = dual_quaternions(transforms);
  const auto sign = hemisphere_signs(dq);
  const auto m = affine_rows(transforms);
  return pose_each_vertex(rest, [&](int64_t v, const double p[3], double out[3]) {
    if (centres.rigid[static_cast<size_t>(v)]) {
      lbs_vertex(weights, m, v, p, out);
      return;
    }
    // v' = R (v - c) + sum_j w_j T_j(c): the blended rotation about the vertex's centre, which moves as LBS.
    // One pass over the influences blends both.
    const double c[3] = {centres.centre(v, 0), centres.centre(v, 1), centres.centre(v, 2)};
    const int32_t* segment = weights.segment.data() + v * weights.influences;
    const float* weight = weights.weight.data() + v * weights.influences;
    const double* pivot_sign = sign.data() + static_cast<size_t>(segment[0] < 0 ? 0 : segment[0]) * dq.size();
    double real[4] = {0.0, 0.0, 0.0, 0.0}, moved[3] = {0.0, 0.0, 0.0}, total = 0.0;
    for (int i = 0; i < weights.influences; ++i) {
      const int32_t sg = segment[i];
      if (sg < 0) break;
      const double w = weight[i];
      const double* q = dq[static_cast<size_t>(sg)].real.data();
      const double ws = pivot_sign[sg] * w;
      for (int k = 0; k < 4; ++k) real[k] += ws * q[k];
      const double* a = m[static_cast<size_t>(sg)].data();
      total += w;
      moved[0] += w * (a[0] * c[0] + a[1] * c[1] + a[2] * c[2] + a[3]);
      moved[1] += w * (a[4] * c[0] + a[5] * c[1] + a[6] * c[2] + a[7]);
      moved[2] += w * (a[8] * c[0] + a[9] * c[1] + a[10] * c[2] + a[11]);
    }
    const double inv = total > 0.0 ? 1.0 / total : 1.0;
    for (int k = 0; k < 3; ++k) out[k] = moved[k] * inv;
    const double scale = 2.0 / (real[0] * real[0] + real[1] * real[1] + real[2] * real[2] + real[3] * real[3]);
    const double u[3] = {p[0] - c[0], p[1] - c[1], p[2] - c[2]};
    add_rotated(real, scale, u, out);
  });
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
    case Method::kFem:
      return invalid_argument_error("the fem method solves the whole tet mesh: pose through the engine (skinning "
                                    "gives its CoR warm start)");
  }
  return internal_error("unhandled skinning method");
}

}  // namespace posewarp::skinning
