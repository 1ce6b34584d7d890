// Joint ranges of motion by turning bone voxels (see joint_range.h).
#include "posewarp/api/joint_range.h"

#include <Eigen/Dense>

#include <atomic>
#include <cmath>

#include "posewarp/common/parallel.h"
#include "posewarp/pose/forward_kinematics.h"
#include "posewarp/resample/rigid_bones.h"

namespace posewarp::api {

Result<std::vector<JointRange>> joint_ranges(const Rig& rig, const RangeParams& params) {
  if (!(params.step_deg >= 0.5 && params.step_deg <= 90.0) || !(params.max_deg >= params.step_deg && params.max_deg <= 180.0) ||
      !(params.overlap_ml > 0.0) || params.max_points < 100) {
    return invalid_argument_error("joint range parameters out of range (step 0.5..90 degrees, up to 180 degrees, "
                                  "overlap above 0 ml, at least 100 points)");
  }
  const LabelVolume& labels = rig.labels;
  const ImageGeometry& g = labels.geometry();
  const rig::Skeleton& skeleton = rig.skeleton;
  std::vector<std::vector<Label>> segment_labels;
  for (const rig::Segment& s : skeleton.segments) segment_labels.push_back(s.labels);
  POSEWARP_ASSIGN_OR_RETURN(const resample::BoneVoxels bones, resample::bone_voxels(labels, segment_labels));
  // Index <-> physical: x = origin + M i with M = direction * diag(spacing).
  Eigen::Matrix3d m;
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c) m(r, c) = g.direction[static_cast<size_t>(3 * r + c)] * g.spacing[static_cast<size_t>(c)];
  const Eigen::Matrix3d m_inverse = m.inverse();
  const Eigen::Vector3d origin(g.origin[0], g.origin[1], g.origin[2]);
  const double voxel_ml = std::abs(m.determinant()) / 1000.0;

  std::vector<JointRange> ranges;
  for (size_t j = 0; j < skeleton.joints.size(); ++j) {
    const rig::Joint& joint = skeleton.joints[j];
    // The segments that move with this joint: its child and the child's descendants.
    std::vector<uint8_t> moving(skeleton.segments.size(), 0);
    for (size_t s = 0; s < skeleton.segments.size(); ++s) {
      for (int at = skeleton.segments[s].parent_joint; at >= 0;
           at = skeleton.segments[static_cast<size_t>(skeleton.joints[static_cast<size_t>(at)].parent)].parent_joint) {
        if (at == static_cast<int>(j)) {
          moving[s] = 1;
          break;
        }
      }
    }
    int64_t count = 0;
    for (const int16_t s : bones.bone_segment) count += moving[static_cast<size_t>(s)];
    const int stride = std::max(1, static_cast<int>(std::ceil(std::cbrt(static_cast<double>(count) / params.max_points))));
    std::vector<Eigen::Vector3d> points;  // index space
    for (int64_t k = 0; k < g.size[2]; k += stride)
      for (int64_t jj = 0; jj < g.size[1]; jj += stride)
        for (int64_t i = 0; i < g.size[0]; i += stride) {
          const int16_t s = bones.segment_of(g.offset(i, jj, k));
          if (s >= 0 && moving[static_cast<size_t>(s)]) points.emplace_back(double(i), double(jj), double(k));
        }
    const double point_ml = voxel_ml * stride * stride * stride;
    // ml of the moving bones inside a still bone with the joint turned by `rotation`.
    auto overlap_ml = [&](const Eigen::Matrix3d& rotation) {
      // In index space: i' = M^-1 (c + R (origin + M i - c) - origin) = A i + b.
      const Eigen::Matrix3d a = m_inverse * rotation * m;
      const Eigen::Vector3d b = m_inverse * (joint.centre_mm + rotation * (origin - joint.centre_mm) - origin);
      std::atomic<int64_t> hits{0};
      parallel_for(0, static_cast<int64_t>(points.size()), 4096, [&](int64_t p0, int64_t p1) {
        int64_t local = 0;
        for (int64_t p = p0; p < p1; ++p) {
          const Eigen::Vector3d q = a * points[static_cast<size_t>(p)] + b;
          const int64_t i = std::llround(q.x()), jj = std::llround(q.y()), k = std::llround(q.z());
          if (i < 0 || jj < 0 || k < 0 || i >= g.size[0] || jj >= g.size[1] || k >= g.size[2]) continue;
          const int16_t s = bones.segment_of(g.offset(i, jj, k));
          local += s >= 0 && !moving[static_cast<size_t>(s)];
        }
        hits += local;
      });
      return static_cast<double>(hits.load()) * point_ml;
    };
    JointRange range;
    range.joint = joint.name;
    const bool two_axes = joint.kind != labels::JointKind::kHinge;
    for (const std::string motion : {"flexion", "abduction"}) {
      if (motion == "abduction" && !two_axes) continue;
      MotionRange r;
      r.motion = motion;
      for (const int sign : {-1, 1}) {
        double reached = params.max_deg;
        bool stopped = false;
        for (double angle = params.step_deg; angle <= params.max_deg + 1e-9; angle += params.step_deg) {
          const double a = sign * angle;
          const pose::JointRotation turn = motion == "flexion" ? pose::anatomical_rotation(joint.name, a, 0.0)
                                                               : pose::anatomical_rotation(joint.name, 0.0, a);
          if (overlap_ml(pose::joint_rotation_in_lps(joint, turn)) > params.overlap_ml) {
            reached = angle - params.step_deg;
            stopped = true;
            break;
          }
        }
        (sign < 0 ? r.negative_deg : r.positive_deg) = reached;
        (sign < 0 ? r.negative_stopped : r.positive_stopped) = stopped;
      }
      range.motions.push_back(r);
    }
    ranges.push_back(std::move(range));
  }
  return ranges;
}

}  // namespace posewarp::api
