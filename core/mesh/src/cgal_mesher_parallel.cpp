// CGAL Mesh_3, TBB-parallel refinement (thread count from posewarp::set_thread_count).
// The vertex cap (MeshParams::max_vertices) needs the concurrent container's approximate size (about 3% slower).
#define CGAL_CONCURRENT_COMPACT_CONTAINER_APPROXIMATE_SIZE 1
#include "cgal_mesher_impl.h"

namespace posewarp::mesh::detail {

Result<TetMesh> run_cgal_parallel(const MesherInput& input, const MeshParams& params, StageProgress& progress,
                                  std::atomic<bool>& stop) {
#ifdef CGAL_LINKED_WITH_TBB
  return run_cgal_mesh_3<CGAL::Parallel_tag>(input, params, progress, stop);
#else
  return run_cgal_mesh_3<CGAL::Sequential_tag>(input, params, progress, stop);
#endif
}

}  // namespace posewarp::mesh::detail
