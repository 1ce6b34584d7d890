// CGAL Mesh_3 on a labelled image, templated on the concurrency tag (one instantiation per translation unit,
// because each takes ~40 s to compile). GPL-3.0-or-later through CGAL's Mesh_3.
#pragma once

#include <CGAL/Exact_predicates_inexact_constructions_kernel.h>
#include <CGAL/Image_3.h>
#include <CGAL/Labeled_mesh_domain_3.h>
#include <CGAL/Mesh_complex_3_in_triangulation_3.h>
#include <CGAL/Mesh_criteria_3.h>
#include <CGAL/Mesh_triangulation_3.h>
#include <CGAL/Mesh_3/initialize_triangulation_from_labeled_image.h>
#include <CGAL/make_mesh_3.h>
#include <CGAL/refine_mesh_3.h>
#include <CGAL/exude_mesh_3.h>
#include <CGAL/Random.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>
#include <iostream>
#include <mutex>
#include <sstream>
#include <unordered_map>
#include <vector>

#include "cgal_mesher_common.h"

namespace posewarp::mesh::detail {

using Kernel = CGAL::Exact_predicates_inexact_constructions_kernel;
using Domain = CGAL::Labeled_mesh_domain_3<Kernel>;

// Cell size in mm at a point of the mesher grid: fine in and near bone, growing with the distance from it.
class CellSizeField {
 public:
  using FT = Kernel::FT;
  using Index = Domain::Index;

  CellSizeField(const MesherInput* input, const MeshParams* params) : input_(input), params_(params) {}

  FT operator()(const Kernel::Point_3& p, const int, const Index&) const {
    const double d = input_->bone_distance.at_grid_mm(p.x(), p.y(), p.z());
    return cell_size_at(*input_, *params_, p.x(), p.y(), p.z(), d);
  }

 private:
  const MesherInput* input_;
  const MeshParams* params_;
};

// The same complex seen as sequential: CGAL's exuder picks its code path from C3t3::Concurrency_tag, and its
// parallel path can spin forever (seen after 39 minutes in Slivers_exuder / flush_work_buffers with CGAL 5.5; its
// time limit is only checked when a task ends, and a cancelled TBB task group is reset by the next wait). Swapping
// a refined parallel complex into this view runs the sequential exuder, which honours its time limit; without the
// triangulation's lock data structure nothing is locked.
template <typename C3t3>
struct SequentialView : C3t3 {
  using Concurrency_tag = CGAL::Sequential_tag;
};

// Refinement stops (between CGAL's refinement steps) when `stop` is set: by the watchdog or by a cancel request.
template <typename Concurrency>
Result<TetMesh> run_cgal_mesh_3(const MesherInput& input, const MeshParams& params, StageProgress& progress,
                                std::atomic<bool>& stop) {
  using Tr = typename CGAL::Mesh_triangulation_3<Domain, CGAL::Default, Concurrency>::type;
  using C3t3 = CGAL::Mesh_complex_3_in_triangulation_3<Tr>;
  using Criteria = CGAL::Mesh_criteria_3<Tr>;

  const ImageGeometry& g = input.classes.geometry();
  // The image is in "grid mm": index * spacing, origin at 0; vertices are mapped to LPS afterwards.
  _image* raw = _createImage(static_cast<size_t>(g.size[0]), static_cast<size_t>(g.size[1]),
                             static_cast<size_t>(g.size[2]), 1, g.spacing[0], g.spacing[1], g.spacing[2], 1, WK_FIXED,
                             SGN_UNSIGNED);
  if (raw == nullptr) return resource_exhausted_error("could not allocate the mesher image (" + g.describe() + ")");
  auto* bytes = static_cast<unsigned char*>(raw->data);
  const Label* classes = input.classes.data();
  for (int64_t v = 0; v < input.classes.voxel_count(); ++v) bytes[v] = static_cast<unsigned char>(classes[v]);
  CGAL::Image_3 image(raw);

  CGAL::Random random(params.seed);
  namespace p = CGAL::parameters;
  Domain domain = Domain::create_labeled_image_mesh_domain(image, p::relative_error_bound = 1e-6, p::p_rng = &random);
  POSEWARP_RETURN_IF_ERROR(progress.check_cancel());
  progress.update(0.05);

  CellSizeField cell_size(&input, &params);
  Criteria criteria(p::facet_angle = params.facet_angle_deg, p::facet_size = params.facet_size_mm,
                    p::facet_distance = params.facet_distance_mm,
                    p::cell_radius_edge_ratio = params.cell_radius_edge_ratio, p::cell_size = cell_size);

  CGAL::get_default_random() = CGAL::Random(params.seed);
  // Seed every connected component of every label (CGAL's default initialization shoots random rays and can miss
  // small bones entirely), then refine.
  C3t3 c3t3;
  {
    // CGAL 5.5's initializer narrates to std::cout; posewarp's stdout belongs to its own reports. The swap is one
    // process-wide state, so builds running at once (a server) take turns here; the initializer is the quick part.
    static std::mutex cout_swap;
    const std::lock_guard<std::mutex> turn(cout_swap);
    std::ostringstream narration;
    struct Swap {  // restored even when the initializer throws
      std::streambuf* saved;
      ~Swap() { std::cout.rdbuf(saved); }
    } swap{std::cout.rdbuf(narration.rdbuf())};
    initialize_triangulation_from_labeled_image(c3t3, domain, image, criteria, static_cast<unsigned char>(0));
  }
  progress.update(0.1);
  CGAL::parameters::internal::Mesh_3_options options;
  options.pointer_to_stop_atomic_boolean = &stop;
  CGAL::Mesh_error_code error = CGAL::CGAL_MESH_3_NO_ERROR;
  options.pointer_to_error_code = &error;
  options.maximal_number_of_vertices = static_cast<std::size_t>(params.max_vertices);
  CGAL::refine_mesh_3(c3t3, domain, criteria, p::no_perturb(), p::no_odt(), p::no_lloyd(), p::no_exude(), options);
  POSEWARP_RETURN_IF_ERROR(progress.check_cancel());
  if (stop.load()) return deadline_exceeded_error("mesh refinement was stopped by the watchdog");
  if (error == CGAL::CGAL_MESH_3_MAXIMAL_NUMBER_OF_VERTICES_REACHED) {
    return resource_exhausted_error("the mesh reached " + std::to_string(params.max_vertices) +
                                    " vertices before meeting its size criteria; use larger mesh sizes (bone and soft "
                                    "cell sizes, facet size) or raise max_vertices");
  }
  progress.update(0.8);
  if (params.exude) {
    SequentialView<C3t3> sequential;
    sequential.swap(c3t3);
    CGAL::exude_mesh_3(sequential, p::time_limit = params.exude_time_limit_s, p::sliver_bound = 10);
    c3t3.swap(sequential);
  }
  POSEWARP_RETURN_IF_ERROR(progress.check_cancel());
  progress.update(0.9);

  // Collect the tets in the complex, their vertices renumbered in order of first appearance.
  const Tr& tr = c3t3.triangulation();
  std::unordered_map<typename Tr::Vertex_handle, int, CGAL::Handle_hash_function> vertex_index;
  std::vector<std::array<double, 3>> points;
  std::vector<std::array<int, 4>> tets;
  std::vector<int> tet_class;
  tets.reserve(static_cast<size_t>(c3t3.number_of_cells_in_complex()));
  for (auto cell = c3t3.cells_in_complex_begin(); cell != c3t3.cells_in_complex_end(); ++cell) {
    std::array<int, 4> tet{};
    for (int corner = 0; corner < 4; ++corner) {
      const auto vh = cell->vertex(corner);
      auto [it, inserted] = vertex_index.emplace(vh, static_cast<int>(points.size()));
      if (inserted) {
        const auto& wp = tr.point(vh);
        const Vec3 physical = g.index_to_physical({wp.x() / g.spacing[0], wp.y() / g.spacing[1], wp.z() / g.spacing[2]});
        points.push_back(physical);
      }
      tet[static_cast<size_t>(corner)] = it->second;
    }
    tets.push_back(tet);
    tet_class.push_back(static_cast<int>(c3t3.subdomain_index(cell)));
  }
  return assemble_mesh(points, tets, tet_class, input.segment_count);
}

}  // namespace posewarp::mesh::detail
