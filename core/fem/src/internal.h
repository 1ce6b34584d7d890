// What the fem stage's solvers share: the inputs' check, the tissue a pose bends, a tet's gradient rows and the
// signed SVD of a 3 x 3 deformation gradient; the assembled solvers' (co-rotational, nonlinear) packed tets and
// matrix patterns; the untangling and the contacts.
#pragma once

#include <Eigen/Core>
#include <Eigen/SparseCore>

#include <array>
#include <cstdint>
#include <functional>
#include <optional>
#include <unordered_map>
#include <utility>
#include <vector>

#include "posewarp/common/progress.h"
#include "posewarp/common/stopwatch.h"
#include "posewarp/fem/soft_tissue.h"

namespace posewarp::fem::internal {

// INVALID_ARGUMENT naming the parameter when an iteration limit, tolerance or margin is out of range.
Status validate_iterations(int max_iterations, double tolerance_mm, double margin_mm);

// INVALID_ARGUMENT when the inputs do not fit the mesh or each other.
Status check_inputs(const SolveInputs& in);

// The vertices a solve moves, ascending: no bone vertex, but every vertex whose influences move it to different
// places and the tissue within `margin_mm` of one along mesh edges (rest mm).
std::vector<int32_t> free_vertices(const SolveInputs& in, double margin_mm);

// Vertex c's gradient row in tet t: F = sum_c x_c g_c^T.
Eigen::Vector3d gradient(const skinning::RestTetFrames& frames, int64_t t, int c);

// F = U diag(sigma) V^T with U and V rotations; sigma's last entry is negative when F is inverted.
void signed_svd(const Eigen::Matrix3d& f, Eigen::Matrix3d& u, Eigen::Vector3d& sigma, Eigen::Matrix3d& v);

using Positions = Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>;  // one row per solve vertex, mm

using SparseMatrix = Eigen::SparseMatrix<double>;

// The assembled solvers' (co-rotational, nonlinear) tets: those touching a free vertex, by slot: their corners as solve
// vertices (the free ones first, in free order, then the fixed corners), gradient rows and rest volumes.
struct Elements {
  Eigen::Index free_count = 0;
  std::vector<int32_t> solve_vertices;                 // solve vertex -> mesh vertex
  std::vector<std::array<int32_t, 4>> corner;          // slot -> its corners' solve vertices
  std::vector<Eigen::Matrix<double, 3, 4>> gradients;  // slot -> its corners' gradient rows
  std::vector<double> volume;                          // slot -> rest volume
};

// Packs the tets that touch the free vertices.
Elements gather_elements(const SolveInputs& in, const std::vector<int32_t>& free_vertices);

// The matrix's pattern (3 x 3 blocks between free vertices sharing a tet), built once; each iteration writes its
// values through `where`: per tet, per free (a, b) pair, the 9 value slots of its (a, b) block.
struct BlockPattern {
  SparseMatrix matrix;
  std::vector<int64_t> where;        // per tet, per (a, b) with both free, 9 slots (row-major in the 3 x 3 block)
  std::vector<int64_t> where_start;  // slot -> its first entry in `where`
};

// The free-free blocks' pattern and where each tet's blocks go in its values.
BlockPattern block_pattern(const Elements& el);

// Per solve vertex (the free ones first, `free_count` of them): the segment of the bone a fixed corner is on, -1 for a
// free vertex or a fixed one off bone (PackedTets::bone_segment).
std::vector<int32_t> bone_segments(const SolveInputs& in, const std::vector<int32_t>& solve_vertices,
                                   size_t free_count);

// Where (row, col) is among a compressed column-major matrix's values; -1 when its pattern lacks it.
int64_t value_slot(const SparseMatrix& m, Eigen::Index row, Eigen::Index col);

// A solve's tets packed with their corners' solve vertices (the free ones, numbered first, then the fixed
// corners), gradient rows and rest volumes, and each free vertex's (tet, corner) pairs.
struct PackedTets {
  const std::vector<std::array<int32_t, 4>>& corners;
  const std::vector<Eigen::Matrix<double, 3, 4>>& gradients;
  const std::vector<double>& volume;
  const std::vector<int64_t>& vertex_start;                     // free count + 1
  const std::vector<std::pair<int32_t, int32_t>>& vertex_tets;  // (tet, corner)
  // Per solve vertex: the bone segment whose tets it is a corner of, -1 for a vertex of soft tets only.
  const std::vector<int32_t>& bone_segment;
};

// Turns back the inverted soft tets the solve left (fem::FemStats names the figures). The free vertices within
// `rings` edges of an inverted tet's free corner minimise a foldover-free hyperelastic energy with every other vertex
// held, after Garanzha et al. 2021 ("Foldover-free maps in 50 lines of code"): per tet, weighted by rest volume,
//   (1 - theta) |F|^2 / chi(D)^(2/3) + theta ((D - 1)^2 + (D^2 + 1) / chi(D)),   D = det F,
// with chi(D) = (D + sqrt(eps^2 + D^2)) / 2 a regularised det whose eps shrinks as the tets turn back (L-BFGS at each
// eps). The first term keeps shape; the second keeps volume, a barrier where D nears 0 and the square of the change
// elsewhere, so that tissue pressed on one side and stretched on the other keeps its mean volume (the paper's
// (D^2 + 1) / D alone is symmetric in log D and made bent tissue grow). Each connected piece of the region also keeps
// its volume as a whole: piece_volume_weight W_p (J_p - 1)^2, with W_p its tets' rest volume (a quarter per corner in
// the region) and J_p their posed volume over it. Its border is held, so what it can give back it gives through its
// free skin: where turning a fold back takes volume from the crease, the skin there bulges instead of sinking (a
// term per tet alone drew the skin in: a mesh of linear tets cannot bend keeping every tet's volume). Tets whose
// corners are all held stay as they are; a tet with three held corners keeps a floor under its regulariser, higher
// where its free corner lies in a joint's gap (beside two bones, PackedTets::bone_segment). The positions that folded
// the least tissue are kept; when none folded less than the solve's own, those stay. `cancel` is checked every round.
struct UntangleParams {
  // posewarp_fem_probe with the rings set by a build switch not kept, on scripts/body_check's rig (knee, elbow, hip
  // 90, and the bench's knee 90 with shoulder abduction 90, 50 iterations before): 2 rings left the same folded share
  // as 3 (within 0.1 point), the tissue's volume within 50 mm 0.4-1.9 points nearer rest, in 22-43% less time; 1 ring
  // left up to 0.5 point more folded.
  int rings = 2;
  double volume_share = 0.9;  // theta: keeping volume counts nine times keeping shape
  int max_iterations = 1000;
  // posewarp_fem_probe on two scripts/body_check rigs at knee, elbow, shoulder and hip 90, soft tissue within 50 mm
  // (volume change, rig 1 / rig 2, without the term -> with it): knee -3.8 / -4.2% -> -2.8 / -1.3%, elbow -0.2 /
  // -14.2% -> -1.3 / -7.4%, shoulder -8.3 / -7.7% -> -4.9 / -4.5%, hip -18.7 / -17.2% -> -16.9 / -14.4%, the folded
  // share the same within 0.2 point. One piece for the whole region at 1000 gave no more; a term per vertex star
  // instead (300 to 3000, rig 1) gave back as much at knee and shoulder but folded 0.5 to 4 points more.
  double piece_volume_weight = 0.0;  // FemParams::untangle_volume_weight (100)
};
// A free vertex kept on the outer side of a plane (a contact's face, as it was when the round began): the energy
// weight * (offset - (x - point) . normal)^2 where that is positive.
struct ContactPlane {
  int32_t vertex = 0;  // solve vertex, free
  Eigen::Vector3d point, normal;
  double offset = 0.0, weight = 0.0;
};
struct UntangleStats {
  int64_t inverted_before = 0, inverted_after = 0;  // tets with a free corner and det F <= 0
  bool undone = false;                              // no round folded less tissue: the solve's result stays
  int64_t vertices = 0;                             // the untangled region's free vertices
  int iterations = 0;
  double seconds = 0.0;
};
// `contact_planes`, when given, is asked at each round's start for the planes that keep skin out of the tissue
// facing it at the positions then (their energy is added to the tets'), so that turning a fold back does not push
// skin through skin.
using ContactLookUp = std::function<std::vector<ContactPlane>(const Positions&)>;
Result<UntangleStats> untangle(const PackedTets& tets, Eigen::Index free_count, Positions& x,
                               const UntangleParams& params, const ContactLookUp& contact_planes,
                               const std::function<Status()>& cancel);

// The untangling's figures into a solve's stats.
void record(const UntangleStats& untangled, FemStats& st);

// Cubic cells of `mm`: a point's cell, and the points a grid of them takes (CellGrid, DenseCells).
struct Cells {
  static constexpr int kMostPerAxis = 32;  // a box stretched over more cells per axis than this is left out
  double mm;
  Eigen::Array3i of(const Eigen::Vector3d& p) const { return (p.array() / mm).floor().cast<int>(); }
  // Finite and within the cells' 21-bit keys (a point beyond is no body's).
  bool hold(const Eigen::Vector3d& p) const { return p.allFinite() && (p.array().abs() / mm < double{1 << 20}).all(); }
  // The cells a box touches, (a, b) corner to corner; false for a box left out.
  bool of_box(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, Eigen::Array3i& a, Eigen::Array3i& b) const {
    if (!hold(lo) || !hold(hi)) return false;
    a = of(lo), b = of(hi);
    return !((b - a) > kMostPerAxis).any();
  }
};

// Items (points, or the boxes of tets and faces) on a uniform grid of cubic cells: which items a box may touch. An
// item inserted with a box is in every cell the box touches, so a query may visit it more than once.
class CellGrid {
 public:
  explicit CellGrid(double cell_mm) : cells_of_{cell_mm} {}
  void insert(int32_t item, const Eigen::Vector3d& lo, const Eigen::Vector3d& hi) {
    Eigen::Array3i a, b;
    if (!cells_of_.of_box(lo, hi, a, b)) return;
    for (int x = a.x(); x <= b.x(); ++x)
      for (int y = a.y(); y <= b.y(); ++y)
        for (int z = a.z(); z <= b.z(); ++z) cells_[key(Eigen::Array3i(x, y, z))].push_back(item);
  }
  // Calls visit(item) for each item in the cells a box touches.
  template <typename Visit>
  void in_box(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, const Visit& visit) const {
    Eigen::Array3i a, b;
    if (!cells_of_.of_box(lo, hi, a, b)) return;
    for (int x = a.x(); x <= b.x(); ++x)
      for (int y = a.y(); y <= b.y(); ++y)
        for (int z = a.z(); z <= b.z(); ++z) {
          const auto it = cells_.find(key(Eigen::Array3i(x, y, z)));
          if (it == cells_.end()) continue;
          for (const int32_t i : it->second) visit(i);
        }
  }

 private:
  static int64_t key(const Eigen::Array3i& c) {
    constexpr int64_t kMask = (int64_t{1} << 21) - 1;
    return ((int64_t{c.x()} & kMask) << 42) | ((int64_t{c.y()} & kMask) << 21) | (int64_t{c.z()} & kMask);
  }
  Cells cells_of_;
  std::unordered_map<int64_t, std::vector<int32_t>> cells_;
};

// Points in the cells a CellGrid of the same size keeps them in (the same boxes left out), held densely over the
// cells the points occupy: a box's cells are found by index instead of by hash. empty() when the points spread over
// too many cells for that (then CellGrid is the one to use).
class DenseCells {
 public:
  DenseCells(const std::vector<Eigen::Vector3d>& points, double cell_mm);
  bool empty() const { return start_.empty(); }
  // Calls visit(item) for each point in the cells the box touches: the points CellGrid::in_box gives.
  template <typename Visit>
  void in_box(const Eigen::Vector3d& lo, const Eigen::Vector3d& hi, const Visit& visit) const {
    Eigen::Array3i a, b;
    if (!cells_of_.of_box(lo, hi, a, b)) return;
    a = a.max(first_);
    b = b.min(first_ + size_ - 1);
    for (int x = a.x(); x <= b.x(); ++x)
      for (int y = a.y(); y <= b.y(); ++y)
        for (int z = a.z(); z <= b.z(); ++z) {
          const size_t c = index(Eigen::Array3i(x, y, z));
          for (int32_t k = start_[c]; k < start_[c + 1]; ++k) visit(items_[static_cast<size_t>(k)]);
        }
  }

 private:
  static constexpr int64_t kMostDenseCells = 1 << 22;  // 16 MB of starts at most
  size_t index(const Eigen::Array3i& c) const {
    const Eigen::Array3i d = c - first_;
    return static_cast<size_t>(d.x()) +
           static_cast<size_t>(size_.x()) *
               (static_cast<size_t>(d.y()) + static_cast<size_t>(size_.y()) * static_cast<size_t>(d.z()));
  }
  Cells cells_of_;
  Eigen::Array3i first_ = Eigen::Array3i::Zero(), size_ = Eigen::Array3i::Zero();
  std::vector<int32_t> start_, items_;
};

// The barycentric coordinates of p in the tet x[0..3], or nothing for a flat tet.
std::optional<Eigen::Vector4d> barycentric(const std::array<Eigen::Vector3d, 4>& x, const Eigen::Vector3d& p);

// Skin within this distance of a tet's corners at rest is the tet's own neighbourhood, not tissue from elsewhere.
constexpr double kElsewhereMm = 15.0;

// Skin pressed against the skin facing it, in the projective solve: collisions as a projection after the global step
// (Bouaziz et al. 2014 section 5 handle them as constraints of the local step; a projection keeps the factored matrix
// as it is). Every few iterations (`detect`) each free skin vertex inside a posed tet from elsewhere (none of whose
// corners lies within kElsewhereMm of it at rest) is paired with the nearest skin face from elsewhere; after each
// global step a paired vertex behind its face's plane is put back just outside it (`project`). The untangling keeps
// the pairs as planes with a penalty (`planes`).
class Contacts {
 public:
  // `solve_vertices`: the solve's mesh vertices, the free ones first; `contact`: the free skin vertices' solve
  // numbers with their tets' stiffness (L_ii, for the planes' weights). Tets and faces that could meet them are found
  // once, at the warm start.
  Contacts(const SolveInputs& in, const std::vector<int32_t>& solve_vertices, const std::vector<int32_t>& contact,
           const std::vector<double>& weight);
  // Looks up which skin vertices are inside tissue from elsewhere at positions x and pairs each with the nearest
  // skin face from elsewhere; returns how many were not paired before.
  int64_t detect(const Positions& x);
  void project(Positions& x) const;                            // each paired vertex behind its face put just outside it
  int64_t pressed(const Positions& x) const;  // paired vertices within kOutsideMm of their face's plane or behind it
  bool changed() const { return changed_; }   // the last look-up paired other vertices or faces than the one before
  std::vector<ContactPlane> planes(const Positions& x) const;  // each paired vertex's face as a plane, at x
  double seconds() const { return seconds_; }

 private:
  Eigen::Vector3d position(int32_t vertex, const Positions& x) const;
  // The signed distance of x from pair k's face (posed), and its unit normal.
  double face_distance(size_t k, const Positions& x, Eigen::Vector3d& normal) const;

  const SolveInputs& in_;
  std::vector<int32_t> local_;    // mesh vertex -> solve vertex, -1 outside the solve (held at the warm start)
  std::vector<int32_t> contact_;  // solve vertex per contact vertex
  std::vector<int32_t> vertex_;   // mesh vertex per contact vertex
  std::vector<double> weight_;    // per contact vertex: its tets' stiffness
  std::vector<int32_t> tets_;     // tets that may hold a contact vertex
  std::vector<int32_t> faces_;    // skin faces (topology's) a contact vertex may meet
  std::vector<int32_t> face_;     // per contact vertex: the face it is pushed against, or -1
  bool changed_ = false;
  double seconds_ = 0.0;
};

// The solvers' frame: the parameters and inputs checked, the stats (the caller's, or a local) cleared, the clock
// started and the vertices the solve moves found; none is the warm start itself (the rest pose, or only rigid
// motions), else `steady_state(in, params, free_vertices, progress, stats, clock)` solves, its progress reported as
// the stage `stage`.
template <typename Params, typename SteadyState>
Result<Eigen::MatrixXd> run_solve(const SolveInputs& in, const Params& params, const ProgressHooks& hooks,
                                  FemStats* stats, const SteadyState& steady_state, const char* stage = "fem") {
  POSEWARP_RETURN_IF_ERROR(validate(params));
  POSEWARP_RETURN_IF_ERROR(check_inputs(in));
  StageProgress progress(hooks, stage);
  FemStats local_stats;
  FemStats& st = stats ? *stats : local_stats;
  st = FemStats{};
  const Stopwatch start;
  std::vector<int32_t> free = free_vertices(in, params.margin_mm);
  st.free_vertices = static_cast<Eigen::Index>(free.size());
  if (free.empty()) return in.warm;
  return steady_state(in, params, std::move(free), progress, st, start);
}

}  // namespace posewarp::fem::internal
