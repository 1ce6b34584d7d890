// Where the soft tissue around a bent joint loses its volume: posewarp_fem_probe RIG POSE.json [METHOD ...]
//
// Poses the rig's tet mesh (no volumes) with each method and splits the soft tets whose rest centroid lies within
// 50 mm of each joint the pose moves by how many of their corners are bone vertices (fixed by their bone's rigid
// motion in every method), and by how many different bones those corners belong to. Per class: rest volume, signed
// volume change (the report's figure), the share folded (det <= 0) and what the folded tets cost of the volume.
// steps:K:ITERATIONS reaches the pose in K solves of ITERATIONS each, every angle scaled by k / K, each step going on
// from the last (a load-stepped solve, measured against the one-step solve).
// pose:REFINE[:REPEATS[:ITERATIONS]] times the whole fem pose with --fem-refine REFINE (best of REPEATS, default 3)
// and --fem-iterations ITERATIONS.
// nonlinear:TET_WEIGHT:STAR_WEIGHT:ITERATIONS:WARM[:MARGIN:UNTANGLE:BARRIER:REGION_BELOW:REGION_RINGS:BARRIER_FROM:
// STAR_BELOW] is the projected-Newton reference (fem::solve_nonlinear) from WARM's vertices (cor, or fem to go on from
// the projective solve's result). A probe for developers: the figures say whether the loss is tissue a solve could
// move (free corners) or tissue pinned between two bones by the mesh.
#include <Eigen/Dense>

#include <algorithm>
#include <array>
#include <cstdlib>
#include <limits>
#include <map>
#include <optional>
#include <cstdio>
#include <set>
#include <string>
#include <vector>

#include "posewarp/api/pose_engine.h"
#include "posewarp/api/rig_file.h"
#include "posewarp/fem/soft_tissue.h"
#include "posewarp/pose/forward_kinematics.h"
#include "posewarp/skinning/tet_maps.h"
#include <chrono>
#include <sstream>

using namespace posewarp;

namespace {

struct ClassFigures {
  double rest = 0.0, posed = 0.0, folded = 0.0, folded_loss = 0.0;
  // A tet of this rest volume posed with this det F.
  void add(double rest_volume, double det) {
    rest += rest_volume;
    posed += rest_volume * det;
    if (det <= 0.0) {
      folded += rest_volume;
      folded_loss += rest_volume * (1.0 - det);
    }
  }
};

void print_row(const char* name, const ClassFigures& c, double total_rest) {
  if (c.rest <= 0.0) return;
  std::printf("  %-26s %8.1f ml %7.1f%% of it   change %+7.1f%%   folded %5.1f%%   folded cost %+6.1f%% of all\n", name,
              c.rest / 1000.0, 100.0 * c.rest / total_rest, 100.0 * (c.posed / c.rest - 1.0), 100.0 * c.folded / c.rest,
              -100.0 * c.folded_loss / total_rest);
}

// The segments' rigid transforms of a pose, as the skinning and the solve take them.
skinning::SegmentTransforms segments_of(const rig::Skeleton& skeleton, const pose::Pose& pose) {
  skinning::SegmentTransforms segments;
  const std::vector<pose::RigidTransform> transforms = pose::forward_kinematics(skeleton, pose).value();
  for (const pose::RigidTransform& t : transforms) {
    segments.rotation.push_back(t.rotation);
    segments.translation.push_back(t.translation);
  }
  return segments;
}

// Step k of 9 of a slider dragged from rest to `pose`: every angle scaled by k / 9.
pose::Pose slider_step(const pose::Pose& pose, int k) {
  pose::Pose step = pose;
  for (pose::JointRotation& r : step.joints) {
    if (r.angles_deg) *r.angles_deg *= k / 9.0;
  }
  return step;
}

}  // namespace

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(
        stderr,
        "usage: posewarp_fem_probe RIG POSE.json [METHOD ...]   (methods: cor dqs lbs fem, fem:..., corot:..., "
        "nonlinear:..., steps:... as the file's head says; default cor fem)\n");
    return 2;
  }
  std::vector<std::string> methods;
  for (int i = 3; i < argc; ++i) methods.emplace_back(argv[i]);
  if (methods.empty()) methods = {"cor", "fem"};
  auto rig = api::load_rig(argv[1]);
  if (!rig.ok()) {
    std::fprintf(stderr, "%s\n", rig.status().message().c_str());
    return 1;
  }
  auto pose = pose::read_pose(argv[2]);
  if (!pose.ok()) {
    std::fprintf(stderr, "%s\n", pose.status().message().c_str());
    return 1;
  }
  auto engine = api::PoseEngine::create(std::move(*rig));
  if (!engine.ok()) {
    std::fprintf(stderr, "%s\n", engine.status().message().c_str());
    return 1;
  }
  const TetMesh& mesh = engine->rig().mesh;
  const skinning::RestTetFrames frames = skinning::rest_tet_frames(mesh);
  const fem::Topology topology = fem::topology(mesh);
  // Which bone segments each vertex belongs to (a vertex of bone tets of two segments belongs to both).
  std::vector<std::set<int>> bones(static_cast<size_t>(mesh.vertex_count()));
  for (int64_t t = 0; t < mesh.tet_count(); ++t) {
    if (mesh.tet_class(t) < kFirstBoneClass) continue;
    for (int c = 0; c < 4; ++c) bones[static_cast<size_t>(mesh.tets(t, c))].insert(mesh.tet_class(t) - kFirstBoneClass);
  }
  // The bone segments a vertex's tets touch (a free vertex between two bones touches both).
  std::vector<std::set<int>> near_bones(static_cast<size_t>(mesh.vertex_count()));
  for (int64_t t = 0; t < mesh.tet_count(); ++t) {
    std::set<int> touched;
    for (int c = 0; c < 4; ++c)
      touched.insert(bones[static_cast<size_t>(mesh.tets(t, c))].begin(),
                     bones[static_cast<size_t>(mesh.tets(t, c))].end());
    for (int c = 0; c < 4; ++c) near_bones[static_cast<size_t>(mesh.tets(t, c))].insert(touched.begin(), touched.end());
  }
  for (const std::string& method_name : methods) {
    // fem:WEIGHT:ITERATIONS:WARM[:MARGIN:UNTANGLE:CONTACT:PIECES] solves here with those parameters from WARM's
    // vertices (cor, dqs or lbs).
    std::optional<fem::FemParams> custom;
    std::optional<fem::CorotationalParams> corotational;
    std::optional<fem::NonlinearParams> nonlinear;
    std::string warm_name = method_name;
    int load_steps = 1;
    if (method_name.rfind("steps:", 0) == 0) {  // steps:K:ITERATIONS, the pose reached in K solves going on from each other
      std::stringstream in(method_name.substr(6));
      std::string k, it;
      std::getline(in, k, ':');
      std::getline(in, it, ':');
      load_steps = std::stoi(k);
      warm_name = "cor";
      custom.emplace();
      custom->max_iterations = std::stoi(it);
    }
    if (method_name.rfind("corot:", 0) == 0) {  // corot:POISSON:ITERATIONS:WARM, the co-rotational reference
      std::stringstream in(method_name.substr(6));
      std::string nu, it;
      std::getline(in, nu, ':');
      std::getline(in, it, ':');
      std::getline(in, warm_name, ':');
      corotational.emplace();
      corotational->poisson_ratio = std::stod(nu);
      corotational->max_iterations = std::stoi(it);
    }
    // nonlinear:TET_WEIGHT:STAR_WEIGHT:ITERATIONS:WARM[:MARGIN:UNTANGLE:BARRIER:REGION_BELOW:REGION_RINGS:
    // BARRIER_FROM:STAR_BELOW], the projected-Newton reference
    if (method_name.rfind("nonlinear:", 0) == 0) {
      std::stringstream in(method_name.substr(10));
      std::string tet, star, it, margin, untangle;
      std::getline(in, tet, ':');
      std::getline(in, star, ':');
      std::getline(in, it, ':');
      std::getline(in, warm_name, ':');
      std::getline(in, margin, ':');
      nonlinear.emplace();
      nonlinear->tet_volume_weight = std::stod(tet);
      nonlinear->star_volume_weight = std::stod(star);
      nonlinear->max_iterations = std::stoi(it);
      if (!margin.empty()) nonlinear->margin_mm = std::stod(margin);
      std::getline(in, untangle, ':');
      nonlinear->untangle = !untangle.empty() && untangle != "0";
      std::string barrier, below, rings;
      std::getline(in, barrier, ':');
      if (!barrier.empty()) nonlinear->barrier_weight = std::stod(barrier);
      std::getline(in, below, ':');
      if (!below.empty()) nonlinear->region_below = std::stod(below);
      std::getline(in, rings, ':');
      if (!rings.empty()) nonlinear->region_rings = std::stoi(rings);
      std::string from;
      std::getline(in, from, ':');
      if (!from.empty()) nonlinear->barrier_from = std::stod(from);
      std::string star_below;
      std::getline(in, star_below, ':');
      if (!star_below.empty()) nonlinear->star_below = std::stod(star_below);
    }
    if (method_name.rfind("fem:", 0) == 0) {
      std::stringstream in(method_name.substr(4));
      std::string w, it;
      std::getline(in, w, ':');
      std::getline(in, it, ':');
      std::getline(in, warm_name, ':');
      std::string margin, untangle, contact;
      std::getline(in, margin, ':');
      std::getline(in, untangle, ':');
      std::getline(in, contact, ':');
      std::string pieces;  // the untangled pieces' volume weight (FemParams::untangle_volume_weight)
      std::getline(in, pieces, ':');
      custom.emplace();
      if (!pieces.empty()) custom->untangle_volume_weight = std::stod(pieces);
      if (!contact.empty()) custom->contact = contact != "0";
      if (!margin.empty()) custom->margin_mm = std::stod(margin);
      if (!untangle.empty()) custom->untangle = untangle != "0";
      custom->volume_weight = std::stod(w);
      custom->max_iterations = std::stoi(it);
    }
    // pose:REFINE[:REPEATS[:ITERATIONS]] is the whole fem pose as a user gets it (labels and CT warped, surfaces
    // deformed) with --fem-refine REFINE (and --fem-iterations ITERATIONS when given), REPEATS times (default 3, the
    // first also preparing what the engine keeps): its best wall time and its stages' best.
    int refine = -1, repeats = 1, projective_iterations = 0;
    if (method_name.rfind("pose:", 0) == 0) {
      std::stringstream in(method_name.substr(5));
      std::string n, r, it;
      std::getline(in, n, ':');
      std::getline(in, r, ':');
      std::getline(in, it, ':');
      if (!it.empty()) projective_iterations = std::stoi(it);
      refine = std::stoi(n);
      repeats = r.empty() ? 3 : std::max(1, std::stoi(r));
      warm_name = "fem";
    }
    auto method = api::method_from_name(warm_name);
    if (!method.ok()) {
      std::fprintf(stderr, "%s\n", method.status().message().c_str());
      return 1;
    }
    api::PoseRequest request;
    request.pose = *pose;
    request.method = *method;
    request.want_labels = request.want_ct = request.want_surfaces = refine >= 0;
    if (refine >= 0) request.fem.refine_iterations = refine;
    if (nonlinear) request.fem.refine_iterations = 0;  // WARM fem: the projective solve's own result
    request.fem.max_iterations = projective_iterations;
    Result<api::PoseResult> result = internal_error("no pose");
    double best = std::numeric_limits<double>::infinity();
    std::map<std::string, double> stage_best;
    for (int r = 0; r < repeats; ++r) {
      const auto start = std::chrono::steady_clock::now();
      result = engine->pose(request);
      if (!result.ok()) break;
      best = std::min(best, std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
      for (const auto& [stage, seconds] : result->report.stage_seconds) {
        const auto [at, first] = stage_best.try_emplace(stage, seconds);
        if (!first) at->second = std::min(at->second, seconds);
      }
    }
    if (!result.ok()) {
      std::fprintf(stderr, "%s\n", result.status().message().c_str());
      return 1;
    }
    if (refine >= 0) {
      std::printf("%s: whole pose best of %d %.0f ms; stages' best:", method_name.c_str(), repeats, 1000.0 * best);
      for (const auto& [stage, seconds] : stage_best) std::printf(" %s %.0f", stage.c_str(), 1000.0 * seconds);
      std::printf(" ms\n");
    }
    Eigen::MatrixXd posed = result->posed_vertices;
    if (custom || corotational || nonlinear) {
      const skinning::SegmentTransforms segments = segments_of(engine->rig().skeleton, *pose);
      fem::FemStats stats;
      const auto start = std::chrono::steady_clock::now();
      const fem::SolveInputs inputs{mesh, frames, topology, engine->rig().weights, segments, posed};
      Result<Eigen::MatrixXd> solved = posed;
      if (load_steps == 1) {
        solved = custom      ? fem::solve(inputs, *custom, {}, &stats)
                 : nonlinear ? fem::solve_nonlinear(inputs, *nonlinear, {}, &stats)
                             : fem::solve_corotational(inputs, *corotational, {}, &stats);
      } else {  // a load-stepped solve: each step's warm start carries the last step's correction (measured worse)
        fem::SolveCache cache;
        fem::FemParams step_params = *custom;
        for (int k = 1; k <= load_steps && solved.ok(); ++k) {
          pose::Pose step = *pose;
          for (pose::JointRotation& r : step.joints) {
            if (r.angles_deg) *r.angles_deg *= static_cast<double>(k) / load_steps;
          }
          const skinning::SegmentTransforms step_segments = segments_of(engine->rig().skeleton, step);
          const Eigen::MatrixXd warm = skinning::skin(skinning::Method::kCor, mesh.vertices, engine->rig().weights,
                                                      engine->rig().centres, step_segments).value();
          step_params.continue_from_last = k > 1;
          solved = fem::solve({mesh, frames, topology, engine->rig().weights, step_segments, warm, &cache}, step_params,
                              {}, &stats);
        }
      }
      if (!solved.ok()) {
        std::fprintf(stderr, "%s\n", solved.status().message().c_str());
        return 1;
      }
      posed = *solved;
      std::printf("%s: %lld free vertices, %lld tets, %d iterations, last step %.3f mm, %d restarts, factor %.2f s, iterations %.2f s, all %.2f s\n", method_name.c_str(), static_cast<long long>(stats.free_vertices), static_cast<long long>(stats.tets), stats.iterations,
                  stats.last_step_mm, stats.restarts, stats.factor_seconds, stats.iterate_seconds,
                  std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
      if ((custom && custom->untangle) || (nonlinear && nonlinear->untangle)) {
        std::printf(
            "  untangled: inverted tets with a free corner %lld -> %lld (%s), %lld vertices, %d iterations, %.2f s\n",
            static_cast<long long>(stats.inverted_before_untangle), static_cast<long long>(stats.inverted),
            stats.untangle_undone ? "undone" : "kept", static_cast<long long>(stats.untangle_vertices),
            stats.untangle_iterations, stats.untangle_seconds);
      }
      if (custom && custom->contact) {
        std::printf("  contact: %lld skin vertices pressed against the tissue facing them, look-ups %.2f s\n",
                    static_cast<long long>(stats.contacts), stats.contact_seconds);
      }
    }
    for (const pose::JointRotation& moved : pose->joints) {
      const rig::Joint* joint = nullptr;
      for (const rig::Joint& j : engine->rig().skeleton.joints) {
        if (j.name == moved.joint) joint = &j;
      }
      if (joint == nullptr) continue;
      constexpr double kRadius = 50.0;
      // [bone corners 0..4], and for 4: [5] one bone, [6] two or more bones.
      std::array<ClassFigures, 9> classes{};  // [7], [8]: 3 bone corners, the free corner near one bone / two or more
      std::array<ClassFigures, 4> sides{};  // tets with a free corner: [child side?][flexion side?]
      double total_rest = 0.0;
      ClassFigures wider;  // within 100 mm
      for (int64_t t = 0; t < mesh.tet_count(); ++t) {
        if (mesh.tet_class(t) != kSoftTissueClass) continue;
        Eigen::Vector3d centroid = Eigen::Vector3d::Zero();
        Eigen::Matrix3d rest_edges, posed_edges;
        for (int c = 0; c < 4; ++c) centroid += 0.25 * mesh.vertices.row(mesh.tets(t, c)).transpose();
        if ((centroid - joint->centre_mm).norm() > 100.0) continue;
        for (int c = 1; c < 4; ++c) {
          rest_edges.col(c - 1) = (mesh.vertices.row(mesh.tets(t, c)) - mesh.vertices.row(mesh.tets(t, 0))).transpose();
          posed_edges.col(c - 1) = (posed.row(mesh.tets(t, c)) - posed.row(mesh.tets(t, 0))).transpose();
        }
        const double rest_volume = rest_edges.determinant() / 6.0,
                     det = posed_edges.determinant() / rest_edges.determinant();
        wider.add(rest_volume, det);
        if ((centroid - joint->centre_mm).norm() > kRadius) continue;
        int bone_corners = 0;
        std::set<int> segments;
        for (int c = 0; c < 4; ++c) {
          const auto& b = bones[static_cast<size_t>(mesh.tets(t, c))];
          bone_corners += !b.empty();
          segments.insert(b.begin(), b.end());
        }
        ClassFigures* into[2] = {&classes[static_cast<size_t>(bone_corners)], nullptr};
        if (bone_corners == 4) into[1] = &classes[segments.size() > 1 ? 6 : 5];
        if (bone_corners == 3) {
          for (int c = 0; c < 4; ++c) {
            if (bones[static_cast<size_t>(mesh.tets(t, c))].empty()) {
              into[1] = &classes[near_bones[static_cast<size_t>(mesh.tets(t, c))].size() > 1 ? 8 : 7];
            }
          }
        }
        for (ClassFigures* c : into) {
          if (c != nullptr) c->add(rest_volume, det);
        }
        total_rest += rest_volume;
        if (bone_corners < 4) {
          // In the joint's frame: z along the child's long axis, and a flexion turns the child's far end toward -y.
          const Eigen::Vector3d local = joint->frame.transpose() * (centroid - joint->centre_mm);
          sides[static_cast<size_t>(2 * (local.z() > 0.0) + (local.y() < 0.0))].add(rest_volume, det);
        }
      }
      ClassFigures all;
      for (int k = 0; k <= 4; ++k) {
        all.rest += classes[static_cast<size_t>(k)].rest;
        all.posed += classes[static_cast<size_t>(k)].posed;
        all.folded += classes[static_cast<size_t>(k)].folded;
        all.folded_loss += classes[static_cast<size_t>(k)].folded_loss;
      }
      const std::vector<fem::Penetration> inside =
          fem::penetration(mesh, posed, topology.skin, joint->centre_mm, {kRadius, 100.0});
      std::printf(
          "%s %s, skin inside tissue / bone from elsewhere within 50 mm: %lld / %lld of %lld, within 100 mm: %lld / "
          "%lld of %lld\n",
          method_name.c_str(), joint->name.c_str(), static_cast<long long>(inside[0].inside_tissue),
          static_cast<long long>(inside[0].inside_bone), static_cast<long long>(inside[0].skin_vertices),
          static_cast<long long>(inside[1].inside_tissue), static_cast<long long>(inside[1].inside_bone),
          static_cast<long long>(inside[1].skin_vertices));
      std::printf("%s %s, soft tets within %.0f mm of its centre:\n", method_name.c_str(), joint->name.c_str(), kRadius);
      print_row("all", all, total_rest);
      print_row("all within 100 mm", wider, wider.rest);
      const char* names[9] = {"no bone corner",    "1 bone corner",           "2 bone corners",
                              "3 bone corners",    "4 bone corners (fixed)",  "  4, all on one bone",
                              "  4, on two bones", "  3, free near one bone", "  3, free near two"};
      for (size_t k = 0; k < classes.size(); ++k) print_row(names[k], classes[k], total_rest);
      const char* side_names[4] = {"free, parent, other side", "free, parent, flexion side", "free, child, other side",
                                   "free, child, flexion side"};
      for (size_t k = 0; k < sides.size(); ++k) print_row(side_names[k], sides[k], total_rest);
    }
  }
  // A slider dragged from rest to the pose in 9 steps (every angle scaled), fem previews: what each call waits for.
  // POSEWARP_PROBE_NO_SLIDER=1 leaves it out (ten seconds on a body) when only the methods' figures are wanted.
  if (const char* skip = std::getenv("POSEWARP_PROBE_NO_SLIDER"); skip && std::string(skip) == "1") return 0;
  std::printf("fem preview, the pose reached in 9 slider steps:");
  for (int k = 1; k <= 9; ++k) {
    const auto start = std::chrono::steady_clock::now();
    if (!engine->preview(slider_step(*pose, k), api::Method::kFem).ok()) return 1;
    std::printf(" %.0f", 1000.0 * std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
  }
  std::printf(" ms\n");
  // The same steps through the stages, timed apart: CoR skinning of the whole mesh, the solve (free vertices and
  // system, then the preview's iterations on the bent tissue going on from the last: 5, 4 or 3 per call, and the
  // preview's since 2026-11-29, at most 4 within 70 ms of solve), and where the slider's last call left the tissue
  // against the steady state (300 iterations from the warm start, as the preview solves: no margin, no untangling).
  fem::FemParams preview;
  preview.continue_from_last = true;
  preview.untangle = false;
  preview.margin_mm = 0.0;
  const skinning::SegmentTransforms last_segments = segments_of(engine->rig().skeleton, slider_step(*pose, 9));
  const Eigen::MatrixXd last_warm = skinning::skin(skinning::Method::kCor, mesh.vertices, engine->rig().weights,
                                                   engine->rig().centres, last_segments).value();
  fem::FemParams steady = preview;
  steady.max_iterations = 300;
  steady.continue_from_last = false;
  const Eigen::MatrixXd converged =
      fem::solve({mesh, frames, topology, engine->rig().weights, last_segments, last_warm}, steady, {}).value();
  const Eigen::VectorXd moved = (converged - last_warm).rowwise().norm();
  const double moved_count = std::max<double>(1.0, (moved.array() > 1e-9).count());
  for (const auto& [per_call, budget] : {std::pair{5, 0.0}, {4, 0.0}, {3, 0.0}, {4, 0.070}}) {
    fem::SolveCache cache;
    fem::FemParams params = preview;
    params.max_iterations = per_call;
    params.time_budget_seconds = budget;
    if (budget > 0.0)
      std::printf("  at most %d per call within %.0f ms of solve (the preview's):\n", per_call, 1000.0 * budget);
    for (int k = 1; k <= 9; ++k) {
      const skinning::SegmentTransforms segments = segments_of(engine->rig().skeleton, slider_step(*pose, k));
      const auto start = std::chrono::steady_clock::now();
      const Eigen::MatrixXd warm = skinning::skin(skinning::Method::kCor, mesh.vertices, engine->rig().weights,
                                                  engine->rig().centres, segments).value();
      const double skin_s = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
      fem::FemStats stats;
      const Eigen::MatrixXd got =
          fem::solve({mesh, frames, topology, engine->rig().weights, segments, warm, &cache}, params, {}, &stats)
              .value();
      std::printf(
          "  step %d: skin %.0f ms, free vertices and system %.0f ms (reused %d; %lld free, %lld tets), %d iterations "
          "%.0f ms\n",
          k, 1000.0 * skin_s, 1000.0 * stats.factor_seconds, stats.reused_system ? 1 : 0,
          static_cast<long long>(stats.free_vertices), static_cast<long long>(stats.tets), stats.iterations,
          1000.0 * stats.iterate_seconds);
      if (k == 9) {  // where the slider's last call left the tissue, against the steady state it goes to
        const Eigen::VectorXd off = (got - converged).rowwise().norm();
        std::printf(
            "  at most %d per call (the last call %d): after the slider's 9 calls the vertices are %.3f mm (mean of "
            "the moved), %.2f mm (max) "
            "from the steady state, which moves them %.3f mm (mean) from the warm start\n",
            per_call, stats.iterations, off.sum() / moved_count, off.maxCoeff(), moved.sum() / moved_count);
      }
    }
  }
  return 0;
}
