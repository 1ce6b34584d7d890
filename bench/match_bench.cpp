// Posture matching measured: a rig posed by known poses (the engine, labels only), each matched back from the posed
// labels alone (api::match_posture). Per pose: each moved joint's angle error (the angle of the rotation between the
// true and the found turn), the largest error over the joints left at rest, the root's position and turn errors,
// the smallest Dice of the bones over 5 ml, and the match's time. With --target-rig the targets are posed from
// another rig of the same skeleton (e.g. `posewarp phantom body --skin-offset 15 --fat 25`: the same bones under
// other soft tissue, built on its own grid), so that the match meets soft tissue other than its own.
// Usage: posewarp_bench_match --rig RIG --pose POSE.json [--pose ...] [--grid input|grow (grow)] [--target-rig RIG]
//   e.g. the body phantom of the README: --rig body20/body.rig --pose multi.json
#include <Eigen/Geometry>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <string>
#include <vector>

#include "posewarp/api/files.h"
#include "posewarp/api/match.h"
#include "posewarp/api/pose_engine.h"
#include "posewarp/api/rig_file.h"
#include "posewarp/common/stopwatch.h"
#include "posewarp/pose/forward_kinematics.h"
#include "posewarp/pose/pose.h"

namespace {

using namespace posewarp;

// Each joint's turn in LPS under `pose` (identity where the pose does not name it).
std::vector<Eigen::Matrix3d> joint_turns(const Skeleton& skeleton, const Pose& pose) {
  std::vector<Eigen::Matrix3d> turns(skeleton.joints.size(), Eigen::Matrix3d::Identity());
  for (const JointRotation& r : pose.joints) {
    const int j = skeleton.joint_index(r.joint);
    if (j >= 0) turns[static_cast<size_t>(j)] = pose::joint_rotation_in_lps(skeleton.joints[static_cast<size_t>(j)], r);
  }
  return turns;
}

// Each segment's voxels in the rest labels (LPS mm), every `step`-th in scan order.
std::vector<std::vector<Eigen::Vector3d>> segment_points(const Skeleton& skeleton, const LabelVolume& labels,
                                                         int64_t step) {
  std::vector<int> segment_of(1 << 16, -1);
  for (size_t s = 0; s < skeleton.segments.size(); ++s) {
    for (Label l : skeleton.segments[s].labels) {
      if (l >= 0 && l < (1 << 16)) segment_of[static_cast<size_t>(l)] = static_cast<int>(s);
    }
  }
  std::vector<std::vector<Eigen::Vector3d>> points(skeleton.segments.size());
  const ImageGeometry& g = labels.geometry();
  for (int64_t at = 0; at < labels.voxel_count(); at += step) {
    const Label l = labels.data()[at];
    if (l < 0 || l >= (1 << 16) || segment_of[static_cast<size_t>(l)] < 0) continue;
    const Vec3 p =
        g.index_to_physical({static_cast<double>(at % g.size[0]), static_cast<double>((at / g.size[0]) % g.size[1]),
                             static_cast<double>(at / (g.size[0] * g.size[1]))});
    points[static_cast<size_t>(segment_of[static_cast<size_t>(l)])].emplace_back(p[0], p[1], p[2]);
  }
  return points;
}

double degrees_between(const Eigen::Matrix3d& a, const Eigen::Matrix3d& b) {
  return Eigen::AngleAxisd(a.transpose() * b).angle() * 180.0 / M_PI;
}

int run(const std::string& rig_path, const std::vector<std::string>& poses, api::GridPolicy grid,
        const std::string& target_rig_path) {
  const Stopwatch load;
  Result<api::Rig> rig = api::load_rig(rig_path);
  if (!rig.ok()) return std::fprintf(stderr, "posewarp_bench_match: %s\n", rig.status().to_string().c_str()), 1;
  const Skeleton skeleton = rig->skeleton;
  const LabelMap map = rig->label_map;
  const std::vector<std::vector<Eigen::Vector3d>> bone_points = segment_points(skeleton, rig->labels, 7);
  const double voxel_mm = std::max(
      {rig->labels.geometry().spacing[0], rig->labels.geometry().spacing[1], rig->labels.geometry().spacing[2]});
  // The targets' rig: this one, or another of the same skeleton.
  Result<api::Rig> target_rig = target_rig_path.empty() ? rig : api::load_rig(target_rig_path);
  if (!target_rig.ok()) {
    return std::fprintf(stderr, "posewarp_bench_match: %s\n", target_rig.status().to_string().c_str()), 1;
  }
  const Skeleton target_skeleton = target_rig->skeleton;
  if (!target_rig_path.empty()) {
    std::printf("targets posed from %s (%lld x %lld x %lld voxels)\n", target_rig_path.c_str(),
                static_cast<long long>(target_rig->labels.geometry().size[0]),
                static_cast<long long>(target_rig->labels.geometry().size[1]),
                static_cast<long long>(target_rig->labels.geometry().size[2]));
  }
  Result<api::PoseEngine> engine = api::PoseEngine::create(std::move(target_rig).value());
  if (!engine.ok()) return std::fprintf(stderr, "posewarp_bench_match: %s\n", engine.status().to_string().c_str()), 1;
  std::printf("rig %s: %zu joints, %lld x %lld x %lld voxels (opened in %.2f s)\n", rig_path.c_str(),
              skeleton.joints.size(), static_cast<long long>(rig->labels.geometry().size[0]),
              static_cast<long long>(rig->labels.geometry().size[1]),
              static_cast<long long>(rig->labels.geometry().size[2]), load.seconds());
  int failures = 0;
  for (const std::string& path : poses) {
    Result<Pose> truth = api::read_pose(path);
    if (!truth.ok()) return std::fprintf(stderr, "posewarp_bench_match: %s\n", truth.status().to_string().c_str()), 1;
    api::PoseRequest request;
    request.pose = *truth;
    request.grid = grid;
    request.want_labels = true;
    request.want_ct = false;
    Result<api::PoseResult> posed = engine->pose(request);
    if (!posed.ok() || !posed->labels) {
      return std::fprintf(stderr, "posewarp_bench_match: %s\n", posed.status().to_string().c_str()), 1;
    }
    Result<api::PostureMatch> match = api::match_posture(*rig, *posed->labels, map);
    if (!match.ok()) return std::fprintf(stderr, "posewarp_bench_match: %s\n", match.status().to_string().c_str()), 1;
    const std::vector<Eigen::Matrix3d> want = joint_turns(target_skeleton, *truth),
                                       got = joint_turns(skeleton, match->match.pose);
    std::printf("\n%s (%s grid): match %.2f s\n", path.c_str(), grid == api::GridPolicy::kGrow ? "grown" : "input",
                match->seconds);
    double worst_rest = 0;
    std::string worst_rest_joint;
    for (size_t j = 0; j < skeleton.joints.size(); ++j) {
      const double error = degrees_between(want[j], got[j]);
      const bool moved = degrees_between(want[j], Eigen::Matrix3d::Identity()) > 1e-6;
      if (moved) {
        std::printf("  %-24s turned %6.1f deg, found within %5.2f deg\n", skeleton.joints[j].name.c_str(),
                    degrees_between(want[j], Eigen::Matrix3d::Identity()), error);
      } else if (error > worst_rest) {
        worst_rest = error, worst_rest_joint = skeleton.joints[j].name;
      }
    }
    std::printf("  joints at rest: within %.2f deg (worst %s)\n", worst_rest, worst_rest_joint.c_str());
    const RigidTransform &a = truth->root, &b = match->match.pose.root;
    // The root's centroid goes to c + t (forward_kinematics).
    std::printf("  root: centroid placed within %.2f mm, turn within %.2f deg\n", (a.translation - b.translation).norm(),
                degrees_between(a.rotation, b.rotation));
    // Where each bone lands: its rest voxels (every 7th) placed by the true and by the found pose, the largest
    // distance between the two (the "bone positions within a voxel").
    Result<std::vector<RigidTransform>> placed_true = pose::forward_kinematics(target_skeleton, *truth);
    Result<std::vector<RigidTransform>> placed_found = pose::forward_kinematics(skeleton, match->match.pose);
    if (placed_true.ok() && placed_found.ok()) {
      double worst = 0;
      std::string worst_segment;
      for (size_t k = 0; k < bone_points.size(); ++k) {
        for (const Eigen::Vector3d& p : bone_points[k]) {
          const double d = ((*placed_true)[k].apply(p) - (*placed_found)[k].apply(p)).norm();
          if (d > worst) worst = d, worst_segment = skeleton.segments[k].name;
        }
      }
      std::printf("  bone positions: every voxel within %.2f mm of its true place (worst %s; voxels up to %.2f mm)\n",
                  worst, worst_segment.c_str(), voxel_mm);
    }
    double smallest = 1.0;
    std::string smallest_segment;
    int skipped = 0;
    for (const api::SegmentMatch& s : match->match.segments) {
      skipped += !s.matched;
      if (s.matched && s.volume_ml > 5.0 && s.dice < smallest) smallest = s.dice, smallest_segment = s.segment;
    }
    std::printf("  Dice of bones over 5 ml: at least %.3f (%s); %d bones skipped\n", smallest, smallest_segment.c_str(),
                skipped);
    failures += smallest < 0.9;
  }
  return failures > 0 ? 1 : 0;
}

}  // namespace

int main(int argc, char** argv) {
  std::string rig, target_rig;
  std::vector<std::string> poses;
  api::GridPolicy grid = api::GridPolicy::kGrow;
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--rig") && i + 1 < argc) {
      rig = argv[++i];
    } else if (!std::strcmp(argv[i], "--target-rig") && i + 1 < argc) {
      target_rig = argv[++i];
    } else if (!std::strcmp(argv[i], "--pose") && i + 1 < argc) {
      poses.push_back(argv[++i]);
    } else if (!std::strcmp(argv[i], "--grid") && i + 1 < argc) {
      grid = std::strcmp(argv[++i], "input") == 0 ? api::GridPolicy::kInput : api::GridPolicy::kGrow;
    } else {
      rig.clear();
      break;
    }
  }
  if (rig.empty() || poses.empty()) {
    std::fprintf(stderr,
                 "usage: %s --rig RIG --pose POSE.json [--pose ...] [--grid input|grow (grow)] [--target-rig RIG]\n",
                 argv[0]);
    return 2;
  }
  return run(rig, poses, grid, target_rig);
}
