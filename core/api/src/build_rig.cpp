// build_rig: body, skeleton, classes, mesh, weights and centres of rotation, timed stage by stage.
#include <nlohmann/json.hpp>

#include <cstring>
#include <new>

#include "posewarp/api/joint_range.h"
#include "posewarp/api/rig.h"

#include "posewarp/api/rig_file.h"
#include "posewarp/common/exception_wall.h"
#include "posewarp/common/parallel.h"
#include "posewarp/common/sha256.h"
#include "posewarp/common/stopwatch.h"
#include "posewarp/cor/rotation_centres.h"
#include "posewarp/fem/soft_tissue.h"
#include "posewarp/labels/body.h"
#include "posewarp/labels/label_map.h"
#include "posewarp/labels/volume_kind.h"
#include "posewarp/mapping/tet_locator.h"
#include "posewarp/mesh/mesher.h"
#include "posewarp/rig/skeleton.h"
#include "posewarp/rig/skin_contacts.h"
#include "posewarp/surface/surface_mesh.h"
#include "posewarp/weights/laplace_weights.h"

#ifndef POSEWARP_VERSION
#define POSEWARP_VERSION "unknown"
#endif

namespace posewarp::api {

std::string Rig::id() const {
  return Sha256()
      .update(labels_hash + "|" + ct_hash + "|" + labels::label_map_to_json(label_map) + "|" + params_json + "|" +
              POSEWARP_VERSION)
      .hex_digest();
}

int64_t Rig::footprint_bytes() const {
  auto bytes = [](const auto& matrix) { return static_cast<int64_t>(matrix.size() * sizeof(*matrix.data())); };
  int64_t total = labels.voxel_count() * static_cast<int64_t>(sizeof(Label)) + (ct ? ct->voxel_bytes() : 0);
  total += bytes(mesh.vertices) + bytes(mesh.tets) + bytes(mesh.tet_class);
  total += bytes(weights.segment) + bytes(weights.weight) + bytes(centres.centre) +
           static_cast<int64_t>(centres.rigid.size());
  for (const surface::SurfaceMesh& m : surfaces) total += bytes(m.vertices) + bytes(m.triangles);
  for (const mapping::Embedding& e : embeddings) total += bytes(e.tet) + bytes(e.barycentric);
  total += static_cast<int64_t>(rest_owner.bytes() + body_region.bytes() + skin_vertex.size() +
                                tet_region.size() * sizeof(int16_t));
  if (bone_substitute) {
    total +=
        static_cast<int64_t>((bone_substitute->voxel.size() + bone_substitute->substitute.size()) * sizeof(int32_t));
  }
  return total;
}

namespace {

// SHA-256 of a volume's grid and voxels: the same voxels on another grid are another input.
template <typename T>
std::string volume_sha256(const Volume<T>& volume) {
  const ImageGeometry& g = volume.geometry();
  Sha256 hash;
  hash.update(g.size.data(), sizeof(g.size)).update(g.spacing.data(), sizeof(g.spacing));
  hash.update(g.origin.data(), sizeof(g.origin)).update(g.direction.data(), sizeof(g.direction));
  hash.update(volume.data(), static_cast<size_t>(volume.voxel_count()) * sizeof(T));
  return hash.hex_digest();
}

// The build parameters with every other input that shapes the rig besides the volumes: the rig spec and the body
// mask. Canonical (nlohmann sorts keys), so the same inputs give the same rig id.
std::string canonical_params(const BuildInputs& inputs, const BuildParams& params) {
  nlohmann::json doc = nlohmann::json::parse(params_to_json(params));
  nlohmann::json spec;
  for (const auto& [name, labels] : inputs.spec.segments) spec["segments"].push_back({name, labels});
  spec["root"] = inputs.spec.root;
  if (inputs.spec.contact_distance_mm) spec["contact_distance_mm"] = *inputs.spec.contact_distance_mm;
  for (const rig::JointSpec& joint : inputs.spec.joints) {
    nlohmann::json j = {{"child", joint.child}, {"parent", joint.parent}, {"name", joint.name}};
    if (joint.centre_mm) j["centre_mm"] = {joint.centre_mm->x(), joint.centre_mm->y(), joint.centre_mm->z()};
    spec["joints"].push_back(j);
  }
  for (const auto& [a, b] : inputs.spec.remove_joints) spec["remove_joints"].push_back({a, b});
  doc["rig_spec"] = spec;
  doc["body_mask_sha256"] = inputs.body ? volume_sha256(*inputs.body) : "";
  return doc.dump();
}

// "the labels 'seg.nii.gz'", or just "the labels" when the caller gave no source.
std::string input_name(const std::string& kind, const std::string& source) {
  return source.empty() ? kind : kind + " '" + source + "'";
}

}  // namespace

std::string rig_id_of(const BuildInputs& inputs, const BuildParams& params) {
  Rig rig;
  rig.labels_hash = volume_sha256(inputs.labels);
  if (inputs.ct) rig.ct_hash = volume_sha256(*inputs.ct);
  rig.label_map = inputs.label_map;
  rig.params_json = canonical_params(inputs, params);
  return rig.id();
}

Status validate(const BuildParams& params) {
  POSEWARP_RETURN_IF_ERROR(rig::validate(params.skeleton));
  POSEWARP_RETURN_IF_ERROR(labels::validate(params.body));
  POSEWARP_RETURN_IF_ERROR(rig::validate(params.skin_contacts));
  POSEWARP_RETURN_IF_ERROR(mesh::validate(params.mesh));
  POSEWARP_RETURN_IF_ERROR(weights::validate(params.weights));
  POSEWARP_RETURN_IF_ERROR(cor::validate(params.cor));
  POSEWARP_RETURN_IF_ERROR(surface::validate(params.surfaces));
  return ok_status();
}

static Result<Rig> build_rig_unguarded(const BuildInputs& inputs, const BuildParams& params, const ProgressHooks& hooks) {
  POSEWARP_RETURN_IF_ERROR(validate(params));
  if (inputs.labels.empty()) return invalid_argument_error("the label volume is empty");
  const ImageGeometry& grid = inputs.labels.geometry();
  if (inputs.ct && !inputs.ct->geometry().same_grid(grid, 1e-3)) {
    return invalid_argument_error("the CT (" + inputs.ct->geometry().describe() + ") is not on the labels' grid (" +
                                  grid.describe() + "); resample it onto the segmentation first");
  }
  if (inputs.body && !inputs.body->geometry().same_grid(grid, 1e-3)) {
    return invalid_argument_error("the body mask is not on the labels' grid; resample it onto the segmentation first");
  }
  // What each volume is for, before any expensive work: a CT given as the labels (or labels as the CT) would mesh
  // garbage for half a minute.
  {
    const std::string labels_name = input_name("the labels", inputs.labels_source);
    const std::string ct_name = inputs.ct ? input_name("the CT", inputs.ct_source) : std::string();
    POSEWARP_RETURN_IF_ERROR(labels::check_labels_look_like_labels(inputs.labels, labels_name, ct_name));
    if (inputs.ct) {
      POSEWARP_RETURN_IF_ERROR(labels::check_ct_is_not_labels(*inputs.ct, inputs.label_map, ct_name, labels_name));
    }
  }
  Rig rig;
  rig.source_geometry = grid;
  rig.label_map = inputs.label_map;
  rig.params_json = canonical_params(inputs, params);
  rig.provenance.software_version = POSEWARP_VERSION;
  rig.provenance.labels_source = inputs.labels_source;
  rig.provenance.ct_source = inputs.ct_source;
  rig.labels_hash = volume_sha256(inputs.labels);
  if (inputs.ct) rig.ct_hash = volume_sha256(*inputs.ct);
  nlohmann::json stats;
  StageTimer clock(rig.provenance.stage_seconds);

  const Status built = guarded("while building the rig of " + grid.describe(),
                               "lower the mesher's voxel budget or use coarser mesh sizes", [&]() -> Status {
    POSEWARP_ASSIGN_OR_RETURN(rig.skeleton,
                              rig::build_skeleton(inputs.labels, inputs.label_map, inputs.spec, params.skeleton, hooks));
    clock.lap("skeleton");

    LabelVolume body;
    if (inputs.body) {
      body = *inputs.body;
      for (const rig::Segment& segment : rig.skeleton.segments) {
        int64_t outside = 0;
        for (int64_t v = 0; v < inputs.labels.voxel_count(); ++v) {
          if (body.data()[v] == 0 &&
              std::find(segment.labels.begin(), segment.labels.end(), inputs.labels.data()[v]) != segment.labels.end()) {
            ++outside;
          }
        }
        if (outside > 0) {
          return invalid_argument_error("the body mask leaves " + std::to_string(outside) + " voxels of bone segment '" +
                                        segment.name + "' outside the body; a body mask must contain the bones " +
                                        "(fix the mask, or leave it out to have posewarp compute one)");
        }
      }
    } else {
      POSEWARP_ASSIGN_OR_RETURN(body, labels::body_mask(inputs.label_map, inputs.labels,
                                                        inputs.ct ? &*inputs.ct : nullptr, params.body));
    }
    clock.lap("body");

    LabelVolume classes = rig::skeleton_classes(rig.skeleton, inputs.labels, body);
    std::vector<std::string> names;
    for (const rig::Segment& segment : rig.skeleton.segments) names.push_back(segment.name);
    std::optional<rig::BodyRegions> regions;
    if (params.skin_contacts.depth_mm > 0.0) {
      POSEWARP_ASSIGN_OR_RETURN(regions, rig::body_regions(rig.skeleton, inputs.labels, body));
      const rig::SkinContactCut cut = rig::cut_skin_contacts(classes, rig.skeleton, *regions, params.skin_contacts);
      nlohmann::json pairs = nlohmann::json::array();
      for (const auto& [a, b] : cut.segment_pairs) {
        pairs.push_back({names[static_cast<size_t>(a)], names[static_cast<size_t>(b)]});
      }
      stats["skin_contacts"] = {{"voxels_cut", cut.voxels}, {"segment_pairs", pairs}};
      clock.lap("contacts");
    }
    mesh::MeshHealth health;
    mesh::MeshParams mesh_params = params.mesh;
    if (mesh_params.joint_cell_size_mm > 0.0) {  // the joints that bend far: all but those declared plane (the spine's)
      for (const rig::Joint& joint : rig.skeleton.joints) {
        if (joint.kind != labels::JointKind::kPlane) {
          mesh_params.joint_centres_lps.push_back({joint.centre_mm.x(), joint.centre_mm.y(), joint.centre_mm.z()});
        }
      }
    }
    POSEWARP_ASSIGN_OR_RETURN(rig.mesh, mesh::make_cgal_mesher()->mesh(classes, static_cast<int>(names.size()),
                                                                       mesh_params, hooks, &health));
    for (const std::string& warning : health.warnings) rig.skeleton.notes.push_back("mesh: " + warning);
    const int64_t bridging = mesh::separate_bone_segments(rig.mesh);
    if (regions) {
      stats["skin_contacts"]["tets_torn"] = rig::tear_skin_contacts(rig.mesh, rig.skeleton, *regions, grid);
    }
    const int64_t gap_edges_split = params.mesh.split_bone_gaps ? mesh::split_bone_gaps(rig.mesh) : 0;
    POSEWARP_RETURN_IF_ERROR(mesh::check_mesh_health(rig.mesh, classes, names, &health));
    stats["mesh"] = {{"vertices", rig.mesh.vertex_count()},
                     {"tets", rig.mesh.tet_count()},
                     {"bone_tets_relabelled_soft", bridging},
                     {"bone_gap_edges_split", gap_edges_split},
                     {"downsample_factor", health.downsample_factor},
                     {"tets_per_class", health.tets_per_class},
                     {"max_bone_volume_error", health.max_bone_volume_error},
                     {"body_volume_error", health.body_volume_error},
                     {"body_components", health.body_components},
                     {"degenerate_tets", health.degenerate_tets},
                     {"min_tet_quality", health.min_tet_quality},
                     {"sequential_fallback", health.sequential_fallback},
                     {"estimated_vertices", health.estimated_vertices}};
    clock.lap("mesh");

    weights::WeightStats weight_stats;
    POSEWARP_ASSIGN_OR_RETURN(rig.weights, weights::laplace_weights(rig.mesh, params.weights, hooks, &weight_stats));
    if (regions) {
      const std::vector<int> vertex_region = rig::vertex_regions(rig.mesh, *regions, grid);
      stats["skin_contacts"]["vertices_reweighted"] =
          rig::keep_weights_within_regions(rig.weights, vertex_region, rig.skeleton);
    }
    stats["weights"] = {{"free_vertices", weight_stats.free_vertices},
                        {"fixed_vertices", weight_stats.fixed_vertices},
                        {"min_raw_weight", weight_stats.min_raw_weight},
                        {"max_raw_weight", weight_stats.max_raw_weight},
                        {"max_partition_error_raw", weight_stats.max_partition_error_raw},
                        {"max_partition_error", weight_stats.max_partition_error},
                        {"max_laplace_residual", weight_stats.max_laplace_residual},
                        {"islands_attached", weight_stats.islands_attached},
                        {"island_vertices", weight_stats.island_vertices},
                        {"solver", weight_stats.solver}};
    clock.lap("weights");

    cor::CorStats cor_stats;
    POSEWARP_ASSIGN_OR_RETURN(rig.centres, cor::rotation_centres(rig.mesh, rig.weights, params.cor, hooks, &cor_stats));
    stats["cor"] = {{"rigid_vertices", cor_stats.rigid_vertices},
                    {"centred_vertices", cor_stats.centred_vertices},
                    {"unsupported_vertices", cor_stats.unsupported_vertices},
                    {"clusters", cor_stats.clusters}};
    clock.lap("cor");
    // The joints' gaps cut once every skinning input is made: the copies take their vertex's weights and centre.
    stats["mesh"]["joint_gap_vertices_cut"] =
        params.mesh.slide_joint_gaps ? fem::cut_joint_gaps(rig.mesh, rig.weights, rig.centres) : 0;
    clock.lap("gaps");

    // Surfaces at rest: every bone label, the skin (the body mask's boundary) and optionally every tissue label.
    std::vector<std::pair<Label, std::string>> wanted;
    for (const rig::Segment& segment : rig.skeleton.segments) {
      for (const Label value : segment.labels) {
        const labels::LabelEntry* entry = inputs.label_map.find(value);
        wanted.emplace_back(value, entry ? entry->name : std::to_string(value));
      }
    }
    if (params.tissue_surfaces) {
      for (const labels::LabelEntry& entry : inputs.label_map.entries()) {
        if (entry.role == labels::LabelRole::kTissue) wanted.emplace_back(entry.value, entry.name);
      }
    }
    POSEWARP_ASSIGN_OR_RETURN(rig.surfaces,
                              surface::extract_label_surfaces(inputs.labels, wanted, params.surfaces, hooks));
    // The skin bounds the whole body: on a large grid, extract it from the body mask downsampled to about 4M
    // voxels (a majority vote per block); smoothing hides the coarser steps and it stays the main cost otherwise.
    const LabelVolume skin_grid = mesh::downsample_classes(body, mesh::downsample_factor_for(body.geometry(), 4'000'000));
    POSEWARP_ASSIGN_OR_RETURN(std::vector<surface::SurfaceMesh> skin,
                              surface::extract_label_surfaces(skin_grid, {{1, "skin"}}, params.surfaces, hooks));
    for (surface::SurfaceMesh& s : skin) s.label = 0, rig.surfaces.push_back(std::move(s));
    // One embedding of all surface vertices (one spatial hash), split back per surface.
    int64_t surface_vertices = 0;
    for (const surface::SurfaceMesh& s : rig.surfaces) surface_vertices += s.vertices.rows();
    Eigen::MatrixXd all_vertices(surface_vertices, 3);
    int64_t row = 0;
    for (const surface::SurfaceMesh& s : rig.surfaces) {
      all_vertices.middleRows(row, s.vertices.rows()) = s.vertices;
      row += s.vertices.rows();
    }
    POSEWARP_ASSIGN_OR_RETURN(const mapping::Embedding all, mapping::embed_points(rig.mesh, all_vertices, hooks));
    row = 0;
    for (const surface::SurfaceMesh& s : rig.surfaces) {
      const int64_t n = s.vertices.rows();
      mapping::Embedding e;
      e.tet = all.tet.segment(row, n);
      e.barycentric = all.barycentric.middleRows(row, n);
      e.inside.assign(all.inside.begin() + row, all.inside.begin() + row + n);
      e.outside_count = std::count(e.inside.begin(), e.inside.end(), uint8_t{0});
      rig.embeddings.push_back(std::move(e));
      row += n;
    }
    stats["surfaces"] = {{"count", rig.surfaces.size()}, {"vertices", surface_vertices}};
    clock.lap("surfaces");
    return ok_status();
  });
  if (!built.ok()) return built;
  rig.labels = inputs.labels;
  if (inputs.ct) rig.ct.emplace(*inputs.ct);
  // Each joint's range of motion on this study (`rig info`, GetRig): how far a pose may turn it before bones meet.
  POSEWARP_RETURN_IF_ERROR(StageProgress(hooks, "ranges").check_cancel());
  POSEWARP_ASSIGN_OR_RETURN(const std::vector<JointRange> ranges, joint_ranges(rig));
  for (size_t j = 0; j < ranges.size() && j < rig.skeleton.joints.size(); ++j) {
    rig.skeleton.joints[j].ranges = ranges[j].motions;
  }
  clock.lap("ranges");
  POSEWARP_RETURN_IF_ERROR(StageProgress(hooks, "tables").check_cancel());
  POSEWARP_RETURN_IF_ERROR(complete_rig(rig, hooks).status());  // the engine's tables and the skin vertices
  clock.lap("tables");
  rig.provenance.stats_json = stats.dump();
  return rig;
}

Result<Rig> build_rig(const BuildInputs& inputs, const BuildParams& params, const ProgressHooks& hooks) {
  return guarded("building the rig",
                 [&] { return in_arena(hooks.threads, [&] { return build_rig_unguarded(inputs, params, hooks); }); });
}

}  // namespace posewarp::api
