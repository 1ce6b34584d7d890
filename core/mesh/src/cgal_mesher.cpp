// The CGAL mesher behind the Mesher interface: downsampling, distance map, dispatch, health checks.
#include <Eigen/Dense>

#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <condition_variable>
#include <mutex>
#include <new>
#include <thread>

#include "posewarp/common/exception_wall.h"
#include "cgal_mesher_common.h"

namespace posewarp::mesh {
namespace detail {

GridDistance::GridDistance(const LabelVolume& classes) : geometry_(classes.geometry()) {
  const Index3 n = geometry_.size;
  const auto& s = geometry_.spacing;
  constexpr float kFar = 1e30f;
  distance_.assign(static_cast<size_t>(classes.voxel_count()), kFar);
  for (int64_t v = 0; v < classes.voxel_count(); ++v) {
    if (classes.data()[v] >= kFirstBoneClass) distance_[static_cast<size_t>(v)] = 0.0f;
  }
  // Two-pass chamfer over the 26-neighbourhood with Euclidean step lengths (within ~8% of the true distance).
  struct Step {
    int di, dj, dk;
    float length;
  };
  std::vector<Step> forward;
  for (int dk = -1; dk <= 0; ++dk)
    for (int dj = -1; dj <= 1; ++dj)
      for (int di = -1; di <= 1; ++di) {
        if (dk == 0 && (dj > 0 || (dj == 0 && di >= 0))) continue;
        forward.push_back({di, dj, dk, static_cast<float>(std::sqrt(di * di * s[0] * s[0] + dj * dj * s[1] * s[1] +
                                                                    dk * dk * s[2] * s[2]))});
      }
  auto pass = [&](bool backward) {
    for (int64_t kk = 0; kk < n[2]; ++kk) {
      const int64_t k = backward ? n[2] - 1 - kk : kk;
      for (int64_t jj = 0; jj < n[1]; ++jj) {
        const int64_t j = backward ? n[1] - 1 - jj : jj;
        for (int64_t ii = 0; ii < n[0]; ++ii) {
          const int64_t i = backward ? n[0] - 1 - ii : ii;
          float& here = distance_[static_cast<size_t>(geometry_.offset(i, j, k))];
          if (here == 0.0f) continue;
          for (const Step& step : forward) {
            const int sign = backward ? -1 : 1;
            const int64_t x = i + sign * step.di, y = j + sign * step.dj, z = k + sign * step.dk;
            if (x < 0 || y < 0 || z < 0 || x >= n[0] || y >= n[1] || z >= n[2]) continue;
            here = std::min(here, distance_[static_cast<size_t>(geometry_.offset(x, y, z))] + step.length);
          }
        }
      }
    }
  };
  pass(false);
  pass(true);
}

namespace {

std::string format_mm(double value) {
  char text[32];
  std::snprintf(text, sizeof(text), "%g mm", value);
  return text;
}

}  // namespace

double cell_size_at(const MesherInput& input, const MeshParams& params, double x, double y, double z, double bone_mm) {
  double size = std::min(params.soft_cell_size_mm, params.bone_cell_size_mm + params.size_growth * bone_mm);
  if (params.joint_cell_size_mm > 0.0) {
    for (const std::array<double, 3>& c : input.joint_centres_grid) {
      const double d = std::sqrt((x - c[0]) * (x - c[0]) + (y - c[1]) * (y - c[1]) + (z - c[2]) * (z - c[2]));
      size = std::min(size, params.joint_cell_size_mm + params.size_growth * std::max(0.0, d - params.joint_radius_mm));
    }
  }
  return size;
}

int64_t estimated_vertex_count(const MesherInput& input, const MeshParams& params) {
  // About one vertex per 0.6 r^3 of volume at a circumradius bound r; 0.9 keeps the estimate low: it came to 0.8x
  // the real count on the body phantom (75k for 95k) and 0.5x on the bar (860 for 1743) at the default sizes.
  constexpr double kVolumePerVertex = 0.9;
  const ImageGeometry& g = input.classes.geometry();
  const double voxel_mm3 = g.spacing[0] * g.spacing[1] * g.spacing[2];
  double vertices = 0.0;
  for (int64_t v = 0; v < input.classes.voxel_count(); ++v) {
    if (input.classes.data()[v] == 0) continue;
    const int64_t i = v % g.size[0], j = (v / g.size[0]) % g.size[1], k = v / (g.size[0] * g.size[1]);
    const double size = cell_size_at(input, params, static_cast<double>(i) * g.spacing[0],
                                     static_cast<double>(j) * g.spacing[1], static_cast<double>(k) * g.spacing[2],
                                     input.bone_distance.at_voxel(v));
    vertices += voxel_mm3 / (kVolumePerVertex * size * size * size);
  }
  return static_cast<int64_t>(vertices);
}

double GridDistance::at_grid_mm(double x, double y, double z) const {
  const int64_t i = std::clamp<int64_t>(std::llround(x / geometry_.spacing[0]), 0, geometry_.size[0] - 1);
  const int64_t j = std::clamp<int64_t>(std::llround(y / geometry_.spacing[1]), 0, geometry_.size[1] - 1);
  const int64_t k = std::clamp<int64_t>(std::llround(z / geometry_.spacing[2]), 0, geometry_.size[2] - 1);
  return distance_[static_cast<size_t>(geometry_.offset(i, j, k))];
}

Result<TetMesh> assemble_mesh(const std::vector<std::array<double, 3>>& points, std::vector<std::array<int, 4>>& tets,
                              const std::vector<int>& tet_class, int segment_count) {
  TetMesh mesh;
  mesh.segment_count = segment_count;
  mesh.vertices.resize(static_cast<Eigen::Index>(points.size()), 3);
  for (size_t v = 0; v < points.size(); ++v) {
    for (int a = 0; a < 3; ++a) mesh.vertices(static_cast<Eigen::Index>(v), a) = points[v][static_cast<size_t>(a)];
  }
  mesh.tets.resize(static_cast<Eigen::Index>(tets.size()), 4);
  mesh.tet_class.resize(static_cast<Eigen::Index>(tets.size()));
  for (size_t t = 0; t < tets.size(); ++t) {
    std::array<int, 4>& tet = tets[t];
    const Eigen::Vector3d a = mesh.vertices.row(tet[0]);
    const Eigen::Vector3d e1 = mesh.vertices.row(tet[1]).transpose() - a;
    const Eigen::Vector3d e2 = mesh.vertices.row(tet[2]).transpose() - a;
    const Eigen::Vector3d e3 = mesh.vertices.row(tet[3]).transpose() - a;
    if (e1.dot(e2.cross(e3)) < 0.0) std::swap(tet[2], tet[3]);
    for (int c = 0; c < 4; ++c) mesh.tets(static_cast<Eigen::Index>(t), c) = tet[static_cast<size_t>(c)];
    mesh.tet_class(static_cast<Eigen::Index>(t)) = tet_class[t];
  }
  return mesh;
}

}  // namespace detail

namespace {

// Watches a refinement from its own thread: sets `stop` when `limit_s` has passed (0 = never) or the caller asks to
// cancel, and keeps the stage's progress moving on elapsed time, since CGAL reports none while it refines.
class Watchdog {
 public:
  Watchdog(std::atomic<bool>& stop, StageProgress& progress, double limit_s)
      : stop_(stop), progress_(progress), limit_s_(limit_s), thread_([this] { watch(); }) {}
  ~Watchdog() {
    {
      std::lock_guard<std::mutex> lock(mutex_);
      done_ = true;
    }
    wake_.notify_all();
    thread_.join();
  }
  Watchdog(const Watchdog&) = delete;
  Watchdog& operator=(const Watchdog&) = delete;

  bool fired() const { return fired_.load(); }

 private:
  void watch() {
    using Clock = std::chrono::steady_clock;
    const auto start = Clock::now();
    std::unique_lock<std::mutex> lock(mutex_);
    while (!wake_.wait_for(lock, std::chrono::milliseconds(50), [this] { return done_; })) {
      const double elapsed = std::chrono::duration<double>(Clock::now() - start).count();
      if (progress_.cancel_requested()) {
        stop_.store(true);
      } else if (limit_s_ > 0.0 && elapsed > limit_s_ && !stop_.load()) {
        fired_.store(true);
        stop_.store(true);
      }
      // An estimate on elapsed time (most bodies refine within half a minute), never reaching the end.
      progress_.update(0.1 + 0.65 * (1.0 - std::exp(-elapsed / 15.0)));
    }
  }

  std::atomic<bool>& stop_;
  StageProgress& progress_;
  const double limit_s_;
  std::atomic<bool> fired_{false};
  std::mutex mutex_;
  std::condition_variable wake_;
  bool done_ = false;
  std::thread thread_;  // last: starts once everything it reads is built
};

class CgalMesher final : public Mesher {
 public:
  std::string name() const override { return "cgal-mesh_3"; }

  Result<TetMesh> mesh(const LabelVolume& classes, int segment_count, const MeshParams& params,
                       const ProgressHooks& hooks, MeshHealth* health) override {
    POSEWARP_RETURN_IF_ERROR(validate(params));
    if (classes.empty()) return invalid_argument_error("the class volume to mesh is empty");
    if (segment_count < 1 || kFirstBoneClass + segment_count > 255) {
      return invalid_argument_error("the mesher takes 1..253 bone segments (got " + std::to_string(segment_count) + ")");
    }
    StageProgress progress(hooks, "mesh");
    return guarded("while meshing " + classes.geometry().describe(), "lower the voxel budget or use coarser mesh sizes",
                   [&]() -> Result<TetMesh> {
      const Index3 factor = downsample_factor_for(classes.geometry(), params.voxel_budget);
      if (health) health->downsample_factor = factor;
      detail::MesherInput input{downsample_classes(classes, factor), segment_count, detail::GridDistance(LabelVolume())};
      input.bone_distance = detail::GridDistance(input.classes);
      if (params.joint_cell_size_mm > 0.0) {
        const ImageGeometry& grid = input.classes.geometry();
        for (const std::array<double, 3>& c : params.joint_centres_lps) {
          const Vec3 index = grid.physical_to_index({c[0], c[1], c[2]});
          input.joint_centres_grid.push_back(
              {index[0] * grid.spacing[0], index[1] * grid.spacing[1], index[2] * grid.spacing[2]});
        }
      }
      POSEWARP_RETURN_IF_ERROR(progress.check_cancel());
      const int64_t estimate = detail::estimated_vertex_count(input, params);
      if (health) health->estimated_vertices = estimate;
      if (estimate > params.max_vertices) {
        return resource_exhausted_error(
            "these mesh sizes (bone cells " + detail::format_mm(params.bone_cell_size_mm) + ", soft cells " +
            detail::format_mm(params.soft_cell_size_mm) + ") would make at least " + std::to_string(estimate) +
            " vertices for this body, over max_vertices (" + std::to_string(params.max_vertices) +
            "); use larger bone_cell_size_mm / soft_cell_size_mm (the defaults are 6 and 14 mm)");
      }
      std::atomic<bool> stop{false};
      Result<TetMesh> mesh = internal_error("the mesher did not run");
      bool fell_back = false;
      if (params.parallel) {
        Watchdog watchdog(stop, progress, params.parallel_watchdog_s);
        mesh = detail::run_cgal_parallel(input, params, progress, stop);
        fell_back = !mesh.ok() && watchdog.fired() && !progress.cancel_requested();
      }
      if (!params.parallel || fell_back) {
        if (fell_back && health) {
          health->sequential_fallback = true;
          health->warnings.push_back("the parallel mesher did not finish within " +
                                     std::to_string(static_cast<int>(params.parallel_watchdog_s)) +
                                     " s (parallel_watchdog_s); the body was meshed again sequentially");
        }
        stop.store(false);
        Watchdog cancel_only(stop, progress, 0.0);
        mesh = detail::run_cgal_sequential(input, params, progress, stop);
      }
      if (mesh.ok()) progress.finish();
      return mesh;
    });
  }
};

}  // namespace

std::unique_ptr<Mesher> make_cgal_mesher() { return std::make_unique<CgalMesher>(); }

}  // namespace posewarp::mesh
