// JSON forms of the skeleton and the build parameters.
#include "rig_json.h"

#include "posewarp/common/json.h"
#include "posewarp/rig/anatomical_frame.h"

#include <nlohmann/json.hpp>

#include <cmath>

namespace posewarp::api {
namespace detail {
namespace {

using json = nlohmann::json;

json to_json3(const Eigen::Vector3d& v) { return json::array({v.x(), v.y(), v.z()}); }
Eigen::Vector3d vec(const json& j) { return {j.at(0).get<double>(), j.at(1).get<double>(), j.at(2).get<double>()}; }

}  // namespace

std::string skeleton_to_json(const rig::Skeleton& skeleton) {
  json doc;
  doc["root"] = skeleton.root;
  json segments = json::array();
  for (const rig::Segment& s : skeleton.segments) {
    segments.push_back({{"name", s.name},
                        {"labels", s.labels},
                        {"voxels", s.voxels},
                        {"centroid_mm", to_json3(s.centroid_mm)},
                        {"principal_axis", to_json3(s.principal_axis)},
                        {"elongation", s.elongation},
                        {"parent_joint", s.parent_joint}});
  }
  doc["segments"] = segments;
  json joints = json::array();
  for (const rig::Joint& j : skeleton.joints) {
    joints.push_back({{"name", j.name},
                      {"parent", j.parent},
                      {"child", j.child},
                      {"centre_mm", to_json3(j.centre_mm)},
                      {"frame", json::array({to_json3(j.frame.col(0)), to_json3(j.frame.col(1)), to_json3(j.frame.col(2))})},
                      {"method", j.method},
                      {"contact_area_mm2", j.contact_area_mm2},
                      {"sphere_radius_mm", j.sphere_radius_mm},
                      {"sphere_rms_mm", j.sphere_rms_mm},
                      {"internal_rotation_sign", j.internal_rotation_sign},
                      {"kind", labels::joint_kind_name(j.kind)},
                      {"flexion", labels::flexion_direction_name(j.flexion)},
                      {"side", rig::body_side_name(j.side)},
                      {"hinge_axis", to_json3(j.hinge_axis)},
                      {"declared", j.declared}});
    for (const rig::MotionRange& m : j.ranges) {
      joints.back()["ranges"].push_back({{"motion", m.motion},
                                         {"negative_deg", m.negative_deg},
                                         {"positive_deg", m.positive_deg},
                                         {"negative_stopped", m.negative_stopped},
                                         {"positive_stopped", m.positive_stopped}});
    }
  }
  doc["joints"] = joints;
  doc["missing_segments"] = skeleton.missing_segments;
  doc["notes"] = skeleton.notes;
  return doc.dump();
}

Result<rig::Skeleton> skeleton_from_json(const std::string& text) {
  const Result<json> parsed = parse_json<json>(text, "rig skeleton section");
  if (!parsed.ok()) return data_loss_error(parsed.status().message());
  try {
    const json& doc = *parsed;
    rig::Skeleton skeleton;
    skeleton.root = doc.at("root").get<int>();
    for (const json& s : doc.at("segments")) {
      rig::Segment segment;
      segment.name = s.at("name").get<std::string>();
      segment.labels = s.at("labels").get<std::vector<Label>>();
      segment.voxels = s.at("voxels").get<int64_t>();
      segment.centroid_mm = vec(s.at("centroid_mm"));
      segment.principal_axis = vec(s.at("principal_axis"));
      segment.elongation = s.value("elongation", 1.0);
      segment.parent_joint = s.at("parent_joint").get<int>();
      skeleton.segments.push_back(segment);
    }
    for (const json& j : doc.at("joints")) {
      rig::Joint joint;
      joint.name = j.at("name").get<std::string>();
      joint.parent = j.at("parent").get<int>();
      joint.child = j.at("child").get<int>();
      joint.centre_mm = vec(j.at("centre_mm"));
      for (int c = 0; c < 3; ++c) joint.frame.col(c) = vec(j.at("frame").at(static_cast<size_t>(c)));
      joint.method = j.at("method").get<std::string>();
      joint.contact_area_mm2 = j.at("contact_area_mm2").get<double>();
      joint.sphere_radius_mm = j.at("sphere_radius_mm").get<double>();
      joint.sphere_rms_mm = j.at("sphere_rms_mm").get<double>();
      // Rigs written before the anatomical frames lack these; their frames keep the old meaning.
      joint.internal_rotation_sign = j.value("internal_rotation_sign", 1);
      if (joint.internal_rotation_sign != 1 && joint.internal_rotation_sign != -1) {
        return data_loss_error("rig skeleton joint '" + joint.name + "' has an internal rotation sign other than +-1");
      }
      if (j.contains("kind")) {
        POSEWARP_ASSIGN_OR_RETURN(joint.kind, labels::joint_kind_from_name(j["kind"].get<std::string>()));
      }
      if (j.contains("flexion")) {
        POSEWARP_ASSIGN_OR_RETURN(joint.flexion, labels::flexion_direction_from_name(j["flexion"].get<std::string>()));
      }
      const std::string side = j.value("side", std::string("midline"));
      joint.side = side == "left" ? rig::BodySide::kLeft : side == "right" ? rig::BodySide::kRight : rig::BodySide::kMidline;
      if (j.contains("hinge_axis")) joint.hinge_axis = vec(j["hinge_axis"]);
      joint.declared = j.value("declared", false);
      if (j.contains("ranges")) {  // rigs built before ranges were measured have none
        for (const json& m : j.at("ranges")) {
          rig::MotionRange range;
          range.motion = m.at("motion").get<std::string>();
          range.negative_deg = m.at("negative_deg").get<double>();
          range.positive_deg = m.at("positive_deg").get<double>();
          range.negative_stopped = m.at("negative_stopped").get<bool>();
          range.positive_stopped = m.at("positive_stopped").get<bool>();
          if (!std::isfinite(range.negative_deg) || !std::isfinite(range.positive_deg)) {
            return data_loss_error("rig skeleton joint '" + joint.name + "' has a range that is not a number");
          }
          joint.ranges.push_back(range);
        }
      }
      skeleton.joints.push_back(joint);
    }
    skeleton.missing_segments = doc.at("missing_segments").get<std::vector<std::string>>();
    skeleton.notes = doc.at("notes").get<std::vector<std::string>>();
    const int n = static_cast<int>(skeleton.segments.size());
    if (skeleton.root < 0 || skeleton.root >= n) return data_loss_error("rig skeleton has an invalid root");
    for (const rig::Joint& joint : skeleton.joints) {
      if (joint.parent < 0 || joint.parent >= n || joint.child < 0 || joint.child >= n) {
        return data_loss_error("rig skeleton joint '" + joint.name + "' refers to a missing segment");
      }
    }
    for (const rig::Segment& segment : skeleton.segments) {
      if (segment.parent_joint < -1 || segment.parent_joint >= static_cast<int>(skeleton.joints.size())) {
        return data_loss_error("rig skeleton segment '" + segment.name + "' refers to a missing joint");
      }
      if (!segment.centroid_mm.allFinite() || !segment.principal_axis.allFinite()) {
        return data_loss_error("rig skeleton segment '" + segment.name + "' has a NaN or infinite centroid or axis");
      }
    }
    return skeleton;
  } catch (const json::exception& error) {
    return data_loss_error(std::string("rig skeleton section is malformed: ") + error.what());
  }
}

}  // namespace detail

std::string params_to_json(const BuildParams& p) {
  using json = nlohmann::json;
  json doc;
  doc["skeleton"] = {{"contact_distance_mm", p.skeleton.contact_distance_mm},
                     {"sphere_max_relative_rms", p.skeleton.sphere_max_relative_rms},
                     {"sphere_min_points", p.skeleton.sphere_min_points},
                     {"max_centre_offset_mm", p.skeleton.max_centre_offset_mm}};
  doc["skin_contacts"] = {{"depth_mm", p.skin_contacts.depth_mm}};
  doc["body"] = {{"use_ct", p.body.use_ct},
                 {"ct_threshold_hu", p.body.ct_threshold_hu},
                 {"keep_largest_component", p.body.keep_largest_component},
                 {"fill_holes", p.body.fill_holes}};
  doc["mesh"] = {{"facet_size_mm", p.mesh.facet_size_mm},
                 {"facet_distance_mm", p.mesh.facet_distance_mm},
                 {"facet_angle_deg", p.mesh.facet_angle_deg},
                 {"bone_cell_size_mm", p.mesh.bone_cell_size_mm},
                 {"soft_cell_size_mm", p.mesh.soft_cell_size_mm},
                 {"size_growth", p.mesh.size_growth},
                 {"cell_radius_edge_ratio", p.mesh.cell_radius_edge_ratio},
                 {"voxel_budget", p.mesh.voxel_budget},
                 {"parallel", p.mesh.parallel},
                 {"seed", p.mesh.seed},
                 {"exude", p.mesh.exude},
                 {"exude_time_limit_s", p.mesh.exude_time_limit_s},
                 {"parallel_watchdog_s", p.mesh.parallel_watchdog_s},
                 {"max_vertices", p.mesh.max_vertices}};
  if (p.mesh.joint_cell_size_mm > 0.0) {  // only when set: rigs built without it keep their ids
    doc["mesh"]["joint_cell_size_mm"] = p.mesh.joint_cell_size_mm;
    doc["mesh"]["joint_radius_mm"] = p.mesh.joint_radius_mm;
  }
  doc["mesh"]["split_bone_gaps"] = p.mesh.split_bone_gaps;  // a rig whose mesh has the gaps split has a new id
  doc["mesh"]["slide_joint_gaps"] = p.mesh.slide_joint_gaps;  // and one whose gaps are cut
  doc["weights"] = {{"max_influences", p.weights.max_influences},
                    {"prune_below", p.weights.prune_below},
                    {"islands", p.weights.islands == weights::IslandPolicy::kFail ? "fail" : "attach_nearest"},
                    {"prefer_cholmod", p.weights.prefer_cholmod}};
  doc["cor"] = {{"sigma", p.cor.sigma}, {"rigid_threshold", p.cor.rigid_threshold}, {"quantization", p.cor.quantization}};
  doc["surfaces"] = {{"smoothing_iterations", p.surfaces.smoothing_iterations},
                     {"pass_band", p.surfaces.pass_band},
                     {"decimation", p.surfaces.decimation},
                     {"tissues", p.tissue_surfaces}};
  return doc.dump();
}

}  // namespace posewarp::api
