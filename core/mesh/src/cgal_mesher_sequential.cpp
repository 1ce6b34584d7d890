// CGAL Mesh_3, sequential: the same seed gives the same mesh every time.
#include "cgal_mesher_impl.h"

namespace posewarp::mesh::detail {

Result<TetMesh> run_cgal_sequential(const MesherInput& input, const MeshParams& params, StageProgress& progress,
                                    std::atomic<bool>& stop) {
  return run_cgal_mesh_3<CGAL::Sequential_tag>(input, params, progress, stop);
}

}  // namespace posewarp::mesh::detail
