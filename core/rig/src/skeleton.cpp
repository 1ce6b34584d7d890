// Automatic skeleton: segments from the label map, contact graph weighted by contact area, maximum spanning tree
// from a root, joint centres (contact centroid or sphere fit) and frames, names from the presets.
#include <Eigen/Dense>

#include <algorithm>
#include <cmath>
#include <limits>
#include <map>
#include <queue>
#include <set>
#include <unordered_map>

#include "posewarp/rig/skeleton.h"

#include "joint_placement.h"
#include "posewarp/common/disjoint_sets.h"
#include "posewarp/common/tet_mesh.h"
#include "posewarp/rig/anatomical_frame.h"

namespace posewarp::rig {

Status validate(const SkeletonParams& params) {
  if (params.contact_distance_mm < 0.0 || !std::isfinite(params.contact_distance_mm) ||
      params.contact_distance_mm > kMaxContactDistanceMm) {
    return invalid_argument_error("contact_distance_mm must be 0 (automatic) or up to " +
                                  std::to_string(static_cast<int>(kMaxContactDistanceMm)) +
                                  " mm (joint spaces are a few mm; the contact search grows with its cube)");
  }
  if (!(params.sphere_max_relative_rms > 0.0)) return invalid_argument_error("sphere_max_relative_rms must be positive");
  if (params.sphere_min_points < 4) return invalid_argument_error("sphere_min_points must be at least 4");
  return ok_status();
}

namespace {

using detail::Contact;
using detail::Contacts;
using detail::physical;

// Step 1's answer: the skeleton's segments (and those missing), and each bone label's segment (-1: none).
struct Segments {
  Skeleton skeleton;
  std::unordered_map<Label, int> segment_of_label;
};

// 1. Segments: the map's bone segments, regrouped by the spec, keeping those present in the volume. At least two.
Result<Segments> find_segments(const LabelVolume& labels, const labels::LabelMap& map, const RigSpec& spec) {
  std::vector<std::pair<std::string, std::vector<Label>>> candidates;
  std::set<Label> regrouped;
  for (const auto& [name, values] : spec.segments) regrouped.insert(values.begin(), values.end());
  for (const std::string& name : map.bone_segments()) {
    std::vector<Label> values;
    for (const Label v : map.labels_of_segment(name)) {
      if (!regrouped.count(v)) values.push_back(v);
    }
    if (!values.empty()) candidates.emplace_back(name, values);
  }
  for (const auto& entry : spec.segments) {
    auto same = std::find_if(candidates.begin(), candidates.end(), [&](const auto& c) { return c.first == entry.first; });
    if (same != candidates.end()) {
      same->second.insert(same->second.end(), entry.second.begin(), entry.second.end());
    } else {
      candidates.push_back(entry);
    }
  }
  std::unordered_map<Label, int> candidate_of;
  for (size_t c = 0; c < candidates.size(); ++c) {
    for (const Label v : candidates[c].second) candidate_of[v] = static_cast<int>(c);
  }
  std::vector<int64_t> candidate_voxels(candidates.size(), 0);
  std::map<Label, int64_t> label_voxels;
  for (const Label v : labels.voxels()) {
    auto it = candidate_of.find(v);
    if (it != candidate_of.end()) {
      ++candidate_voxels[static_cast<size_t>(it->second)];
      ++label_voxels[v];
    }
  }
  for (const auto& [name, values] : spec.segments) {
    for (const Label v : values) {
      if (!label_voxels.count(v)) {
        return invalid_argument_error("the rig spec puts label " + std::to_string(v) + " into segment '" + name +
                                      "', but the label volume holds no voxel of it; remove it from the spec");
      }
    }
  }
  Segments found;
  Skeleton& skeleton = found.skeleton;
  std::vector<int> segment_of_candidate(candidates.size(), -1);
  for (size_t c = 0; c < candidates.size(); ++c) {
    if (candidate_voxels[c] == 0) {
      skeleton.missing_segments.push_back(candidates[c].first);
      continue;
    }
    segment_of_candidate[c] = static_cast<int>(skeleton.segments.size());
    Segment segment;
    segment.name = candidates[c].first;
    for (const Label v : candidates[c].second) {
      if (label_voxels.count(v)) segment.labels.push_back(v);
    }
    skeleton.segments.push_back(segment);
  }
  for (const auto& [label, c] : candidate_of) found.segment_of_label[label] = segment_of_candidate[static_cast<size_t>(c)];
  if (skeleton.segments.empty()) {
    int bone_labels = 0;
    for (const auto& entry : map.entries()) bone_labels += entry.role == labels::LabelRole::kBone;
    return failed_precondition_error(
        "no bone labels found: the label map '" + map.name() + "' names " + std::to_string(bone_labels) +
        " bone labels and the volume holds none of them. Check that the segmentation labels bones and that the "
        "label map (a preset, or a map of your own) matches it");
  }
  if (skeleton.segments.size() == 1) {
    return failed_precondition_error("only one bone segment ('" + skeleton.segments[0].name +
                                     "') is present; a rig needs at least two segments joined by a joint. Label "
                                     "more bones, or split the bone into segments with a rig spec");
  }
  return found;
}

// 2. Segment index per voxel, each segment's voxel count, centroid and principal axis, and its surface voxels.
void measure_segments(const LabelVolume& labels, const std::unordered_map<Label, int>& segment_of_label,
                      Skeleton& skeleton, std::vector<int16_t>& segment_at, std::vector<std::vector<Index3>>& surface) {
  const ImageGeometry& g = labels.geometry();
  const int n = static_cast<int>(skeleton.segments.size());
  segment_at.assign(static_cast<size_t>(labels.voxel_count()), -1);
  for (int64_t v = 0; v < labels.voxel_count(); ++v) {
    auto it = segment_of_label.find(labels.data()[v]);
    if (it != segment_of_label.end()) segment_at[static_cast<size_t>(v)] = static_cast<int16_t>(it->second);
  }
  std::vector<Eigen::Matrix3d> second_moment(static_cast<size_t>(n), Eigen::Matrix3d::Zero());
  surface.assign(static_cast<size_t>(n), {});
  for (int64_t k = 0; k < g.size[2]; ++k) {
    for (int64_t j = 0; j < g.size[1]; ++j) {
      for (int64_t i = 0; i < g.size[0]; ++i) {
        const int s = segment_at[static_cast<size_t>(g.offset(i, j, k))];
        if (s < 0) continue;
        Segment& segment = skeleton.segments[static_cast<size_t>(s)];
        const Eigen::Vector3d p = physical(g, i, j, k);
        ++segment.voxels;
        segment.centroid_mm += p;
        second_moment[static_cast<size_t>(s)] += p * p.transpose();
        bool on_surface = false;
        const int64_t neighbours[6][3] = {{i - 1, j, k}, {i + 1, j, k}, {i, j - 1, k},
                                          {i, j + 1, k}, {i, j, k - 1}, {i, j, k + 1}};
        for (const auto& q : neighbours) {
          if (!labels.contains(q[0], q[1], q[2]) || segment_at[static_cast<size_t>(g.offset(q[0], q[1], q[2]))] != s) {
            on_surface = true;
            break;
          }
        }
        if (on_surface) surface[static_cast<size_t>(s)].push_back({i, j, k});
      }
    }
  }
  for (int s = 0; s < n; ++s) {
    Segment& segment = skeleton.segments[static_cast<size_t>(s)];
    const double count = static_cast<double>(segment.voxels);
    segment.centroid_mm /= count;
    const Eigen::Matrix3d covariance =
        second_moment[static_cast<size_t>(s)] / count - segment.centroid_mm * segment.centroid_mm.transpose();
    Eigen::SelfAdjointEigenSolver<Eigen::Matrix3d> eigen(covariance);
    segment.principal_axis = eigen.eigenvectors().col(2).normalized();
    const Eigen::Vector3d spread = eigen.eigenvalues().cwiseMax(1e-12);
    segment.elongation = std::sqrt(spread(2) / spread(1));
  }
}

// 3. Contacts: surface voxels of a within the contact distance (mm) of a voxel of b.
Result<Contacts> find_contacts(const LabelVolume& labels, const std::vector<int16_t>& segment_at,
                               const std::vector<std::vector<Index3>>& surface, double contact_mm,
                               StageProgress& progress) {
  const ImageGeometry& g = labels.geometry();
  const int n = static_cast<int>(surface.size());
  const int64_t reach[3] = {static_cast<int64_t>(std::floor(contact_mm / g.spacing[0])),
                            static_cast<int64_t>(std::floor(contact_mm / g.spacing[1])),
                            static_cast<int64_t>(std::floor(contact_mm / g.spacing[2]))};
  Contacts contacts;
  std::vector<std::pair<int, double>> near;  // segment, squared distance to its nearest voxel
  for (int s = 0; s < n; ++s) {
    for (const Index3& v : surface[static_cast<size_t>(s)]) {
      near.clear();
      for (int64_t dk = -reach[2]; dk <= reach[2]; ++dk) {
        for (int64_t dj = -reach[1]; dj <= reach[1]; ++dj) {
          for (int64_t di = -reach[0]; di <= reach[0]; ++di) {
            const double d2 = std::pow(di * g.spacing[0], 2) + std::pow(dj * g.spacing[1], 2) + std::pow(dk * g.spacing[2], 2);
            if (d2 > contact_mm * contact_mm) continue;
            const int64_t x = v[0] + di, y = v[1] + dj, z = v[2] + dk;
            if (!labels.contains(x, y, z)) continue;
            const int other = segment_at[static_cast<size_t>(g.offset(x, y, z))];
            if (other < 0 || other == s) continue;
            auto known = std::find_if(near.begin(), near.end(), [&](const auto& e) { return e.first == other; });
            if (known == near.end()) {
              near.emplace_back(other, d2);
            } else {
              known->second = std::min(known->second, d2);
            }
          }
        }
      }
      const Eigen::Vector3d p = physical(g, v[0], v[1], v[2]);
      for (const auto& [other, d2] : near) {
        Contact& contact = contacts[{s, other}];
        ++contact.count;
        contact.sum += p;
        contact.voxels.push_back(v);
        contact.distance_mm.push_back(static_cast<float>(std::sqrt(d2)));
      }
    }
    progress.update(0.2 + 0.6 * (s + 1) / n);
    POSEWARP_RETURN_IF_ERROR(progress.check_cancel());
  }
  return contacts;
}

// 4. Root: the spec's, else the map's, else the most central large segment (noted).
Result<int> choose_root(const labels::LabelMap& map, const RigSpec& spec, Skeleton& skeleton) {
  int root = -1;
  const std::string wanted_root = !spec.root.empty() ? spec.root : map.root_segment();
  if (!wanted_root.empty()) root = skeleton.segment_index(wanted_root);
  if (!spec.root.empty() && root < 0) {
    return invalid_argument_error("the rig spec's root '" + spec.root + "' is not a bone segment present in the volume");
  }
  if (root >= 0) return root;
  Eigen::Vector3d body_centre = Eigen::Vector3d::Zero();
  double total = 0.0;
  for (const Segment& segment : skeleton.segments) {
    body_centre += segment.centroid_mm * static_cast<double>(segment.voxels);
    total += static_cast<double>(segment.voxels);
  }
  body_centre /= total;
  double extent = 1.0;
  for (const Segment& segment : skeleton.segments) extent = std::max(extent, (segment.centroid_mm - body_centre).norm());
  double best = -1.0;
  for (int s = 0; s < static_cast<int>(skeleton.segments.size()); ++s) {
    const Segment& segment = skeleton.segments[static_cast<size_t>(s)];
    const double score = static_cast<double>(segment.voxels) * std::exp(-4.0 * (segment.centroid_mm - body_centre).norm() / extent);
    if (score > best) best = score, root = s;
  }
  skeleton.notes.push_back("root chosen as the most central large segment: " + skeleton.segments[static_cast<size_t>(root)].name);
  return root;
}

// Step 5's answer: the tree's edges per segment (neighbour, contact area) and the spec's forced parents.
struct Tree {
  std::vector<std::vector<std::pair<int, double>>> adjacency;
  std::map<int, int> forced_parent;  // child -> parent
};

// A candidate joint of the spanning tree.
struct Edge {
  int a, b;
  double area;
  int priority;   // 2 rig spec, 1 declared by the label map, 0 contact only
  int order = 0;  // declaration order among the map's joints
};

// The candidate joints, best first: the spec's, then the label map's declared joints in its order whenever both
// segments are present (they give the anatomical tree, thorax -> clavicle -> scapula -> humerus, where the largest
// contact would not), then the contacts by area; the spec's removals kept out.
Result<std::vector<Edge>> candidate_edges(const ImageGeometry& g, const labels::LabelMap& map, const RigSpec& spec,
                                          const Skeleton& skeleton, const Contacts& contacts, Tree& tree) {
  auto segment_named = [&](const std::string& name, const char* what) -> Result<int> {
    const int s = skeleton.segment_index(name);
    if (s < 0) {
      return invalid_argument_error(std::string("the rig spec's ") + what + " '" + name +
                                    "' is not a bone segment present in the volume");
    }
    return s;
  };
  std::set<std::pair<int, int>> removed;
  for (const auto& [a, b] : spec.remove_joints) {
    POSEWARP_ASSIGN_OR_RETURN(const int sa, segment_named(a, "removed joint segment"));
    POSEWARP_ASSIGN_OR_RETURN(const int sb, segment_named(b, "removed joint segment"));
    removed.insert({std::min(sa, sb), std::max(sa, sb)});
  }
  const double face_area = (g.spacing[0] * g.spacing[1] + g.spacing[1] * g.spacing[2] + g.spacing[0] * g.spacing[2]) / 3.0;
  auto area_of = [&](int x, int y) {
    const auto one = contacts.find({x, y});
    const auto other = contacts.find({y, x});
    const double count = 0.5 * ((one == contacts.end() ? 0.0 : static_cast<double>(one->second.count)) +
                                (other == contacts.end() ? 0.0 : static_cast<double>(other->second.count)));
    return count * face_area;
  };
  std::vector<Edge> edges;
  for (const auto& [pair, contact] : contacts) {
    if (pair.first > pair.second) continue;
    if (removed.count(pair)) continue;
    edges.push_back({pair.first, pair.second, area_of(pair.first, pair.second), 0});
  }
  for (const JointSpec& joint : spec.joints) {
    POSEWARP_ASSIGN_OR_RETURN(const int child, segment_named(joint.child, "joint child"));
    if (joint.parent.empty()) continue;
    POSEWARP_ASSIGN_OR_RETURN(const int parent, segment_named(joint.parent, "joint parent"));
    if (parent == child) return invalid_argument_error("the rig spec joins segment '" + joint.child + "' to itself");
    tree.forced_parent[child] = parent;
    edges.push_back({parent, child, area_of(parent, child), 2});
  }
  int declared_order = 0;
  for (const labels::JointName& declared : map.joint_names()) {
    const int a = skeleton.segment_index(declared.segment_a), b = skeleton.segment_index(declared.segment_b);
    if (a < 0 || b < 0 || removed.count({std::min(a, b), std::max(a, b)})) continue;
    edges.push_back({a, b, area_of(a, b), 1, declared_order++});
  }
  std::stable_sort(edges.begin(), edges.end(), [](const Edge& x, const Edge& y) {
    if (x.priority != y.priority) return x.priority > y.priority;
    if (x.priority == 1) return x.order < y.order;
    return x.area > y.area;
  });
  return edges;
}

// 5. Maximum spanning tree over contact area, the spec's joints forced in and its removals kept out; segments that
// touch nothing are attached to the nearest connected segment (by centroids), and noted.
Result<Tree> spanning_tree(const ImageGeometry& g, const labels::LabelMap& map, const RigSpec& spec, int root,
                           const Contacts& contacts, Skeleton& skeleton) {
  const int n = static_cast<int>(skeleton.segments.size());
  Tree tree;
  POSEWARP_ASSIGN_OR_RETURN(const std::vector<Edge> edges, candidate_edges(g, map, spec, skeleton, contacts, tree));
  DisjointSets sets(n);
  tree.adjacency.resize(static_cast<size_t>(n));
  for (const Edge& e : edges) {
    if (!sets.unite(e.a, e.b)) {
      // A declared joint that closes a loop is an alternative (scapulothoracic when the clavicle is there).
      if (e.priority == 2) {
        return invalid_argument_error("the rig spec's joints between '" + skeleton.segments[static_cast<size_t>(e.a)].name +
                                      "' and '" + skeleton.segments[static_cast<size_t>(e.b)].name +
                                      "' close a loop; a skeleton is a tree");
      }
      continue;
    }
    tree.adjacency[static_cast<size_t>(e.a)].emplace_back(e.b, e.area);
    tree.adjacency[static_cast<size_t>(e.b)].emplace_back(e.a, e.area);
  }
  for (;;) {
    std::vector<int> attached;
    std::vector<int> detached;
    for (int s = 0; s < n; ++s) (sets.find(s) == sets.find(root) ? attached : detached).push_back(s);
    if (detached.empty()) break;
    double best = std::numeric_limits<double>::infinity();
    int best_a = -1, best_d = -1;
    for (const int d : detached) {
      for (const int a : attached) {
        const double dist = (skeleton.segments[static_cast<size_t>(d)].centroid_mm - skeleton.segments[static_cast<size_t>(a)].centroid_mm).norm();
        if (dist < best) best = dist, best_a = a, best_d = d;
      }
    }
    sets.unite(best_a, best_d);
    tree.adjacency[static_cast<size_t>(best_a)].emplace_back(best_d, 0.0);
    tree.adjacency[static_cast<size_t>(best_d)].emplace_back(best_a, 0.0);
    skeleton.notes.push_back("segment '" + skeleton.segments[static_cast<size_t>(best_d)].name +
                             "' touches no other bone; attached to the nearest, '" +
                             skeleton.segments[static_cast<size_t>(best_a)].name + "' (check it, or add a joint in a rig spec)");
  }
  return tree;
}

// 6. Orient from the root (breadth first, so parents come before children) and place the joints; note what the spec
// asked for and did not get, and make the joints' names unique.
void place_joints(const detail::JointPlacement& placement, const RigSpec& spec, const Tree& tree) {
  Skeleton& skeleton = placement.skeleton;
  const int root = skeleton.root;
  std::vector<int> parent_of(skeleton.segments.size(), -2);
  parent_of[static_cast<size_t>(root)] = -1;
  std::queue<int> queue;
  queue.push(root);
  while (!queue.empty()) {
    const int s = queue.front();
    queue.pop();
    std::vector<std::pair<int, double>> next = tree.adjacency[static_cast<size_t>(s)];
    std::sort(next.begin(), next.end());
    for (const auto& [c, area] : next) {
      if (parent_of[static_cast<size_t>(c)] != -2) continue;
      parent_of[static_cast<size_t>(c)] = s;
      queue.push(c);
      Joint joint = detail::place_joint(placement, s, c, area);
      skeleton.segments[static_cast<size_t>(c)].parent_joint = static_cast<int>(skeleton.joints.size());
      skeleton.joints.push_back(joint);
    }
  }
  for (const auto& [child, parent] : tree.forced_parent) {
    if (parent_of[static_cast<size_t>(child)] != parent) {
      skeleton.notes.push_back("the rig spec asked for '" + skeleton.segments[static_cast<size_t>(parent)].name +
                               "' as parent of '" + skeleton.segments[static_cast<size_t>(child)].name +
                               "', but the root's position made it the child; the joint is kept with roles swapped");
    }
  }
  for (const JointSpec& js : spec.joints) {
    if (js.child == skeleton.segments[static_cast<size_t>(root)].name && (js.centre_mm || !js.name.empty())) {
      skeleton.notes.push_back("the rig spec names a joint for the root segment '" + js.child + "', which has none");
    }
  }
  std::set<std::string> names;
  for (Joint& joint : skeleton.joints) {
    if (!names.insert(joint.name).second) {
      joint.name += "__" + skeleton.segments[static_cast<size_t>(joint.child)].name;
      names.insert(joint.name);
    }
  }
}

}  // namespace

Result<Skeleton> build_skeleton(const LabelVolume& labels, const labels::LabelMap& map, const RigSpec& spec,
                                const SkeletonParams& params, const ProgressHooks& hooks) {
  POSEWARP_RETURN_IF_ERROR(validate(params));
  if (labels.empty()) return invalid_argument_error("the label volume is empty");
  StageProgress progress(hooks, "skeleton");
  const ImageGeometry& g = labels.geometry();
  POSEWARP_ASSIGN_OR_RETURN(Segments segments, find_segments(labels, map, spec));
  Skeleton& skeleton = segments.skeleton;
  std::vector<int16_t> segment_at;
  std::vector<std::vector<Index3>> surface;
  measure_segments(labels, segments.segment_of_label, skeleton, segment_at, surface);
  POSEWARP_RETURN_IF_ERROR(progress.check_cancel());
  progress.update(0.2);
  const double max_spacing = std::max({g.spacing[0], g.spacing[1], g.spacing[2]});
  const double contact_mm = spec.contact_distance_mm.value_or(
      params.contact_distance_mm > 0.0 ? params.contact_distance_mm : std::min(3.5 * max_spacing, kMaxContactDistanceMm));
  POSEWARP_ASSIGN_OR_RETURN(const Contacts contacts, find_contacts(labels, segment_at, surface, contact_mm, progress));
  POSEWARP_ASSIGN_OR_RETURN(skeleton.root, choose_root(map, spec, skeleton));
  POSEWARP_ASSIGN_OR_RETURN(const Tree tree, spanning_tree(g, map, spec, skeleton.root, contacts, skeleton));
  const double max_offset =
      params.max_centre_offset_mm > 0.0 ? params.max_centre_offset_mm : std::max(10.0, 2.0 * max_spacing);
  place_joints({g, map, spec, params, skeleton, segment_at, surface, contacts, max_spacing, max_offset}, spec, tree);
  progress.finish();
  return std::move(segments.skeleton);
}

LabelVolume skeleton_classes(const Skeleton& skeleton, const LabelVolume& labels, const LabelVolume& body) {
  std::unordered_map<Label, Label> class_of;
  for (size_t k = 0; k < skeleton.segments.size(); ++k) {
    for (const Label v : skeleton.segments[k].labels) class_of[v] = static_cast<Label>(kFirstBoneClass + k);
  }
  LabelVolume classes(labels.geometry(), 0);
  classes.set_source_type(PixelType::kUInt8);
  for (int64_t v = 0; v < labels.voxel_count(); ++v) {
    auto it = class_of.find(labels.data()[v]);
    if (it != class_of.end()) {
      classes.data()[v] = it->second;
    } else if (body.data()[v] != 0) {
      classes.data()[v] = kSoftTissueClass;
    }
  }
  // Bones that touch (joint spaces thinner than a voxel) would share mesh vertices, and a shared vertex cannot
  // follow both bones: open a soft layer where two segments meet, one voxel on each side.
  const ImageGeometry& g = labels.geometry();
  std::vector<int64_t> contact;
  for (int64_t k = 0; k < g.size[2]; ++k) {
    for (int64_t j = 0; j < g.size[1]; ++j) {
      for (int64_t i = 0; i < g.size[0]; ++i) {
        const Label c = classes.at(i, j, k);
        if (c < kFirstBoneClass) continue;
        bool touches = false;
        for (int64_t dk = -1; dk <= 1 && !touches; ++dk) {
          for (int64_t dj = -1; dj <= 1 && !touches; ++dj) {
            for (int64_t di = -1; di <= 1 && !touches; ++di) {
              if (!classes.contains(i + di, j + dj, k + dk)) continue;
              const Label other = classes.at(i + di, j + dj, k + dk);
              touches = other >= kFirstBoneClass && other != c;
            }
          }
        }
        if (touches) contact.push_back(g.offset(i, j, k));
      }
    }
  }
  for (const int64_t v : contact) classes.data()[v] = kSoftTissueClass;
  return classes;
}

}  // namespace posewarp::rig
