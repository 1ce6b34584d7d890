// proto <-> core conversions.
#include "convert.h"

#include <cmath>
#include <cstring>

#include "posewarp/api/joint_range.h"
#include "posewarp/api/rig_info.h"

namespace posewarp::server {

void put_grid(const ImageGeometry& g, v1::Grid* grid) {
  for (size_t a = 0; a < 3; ++a) {
    grid->add_size(g.size[a]);
    grid->add_spacing(g.spacing[a]);
    grid->add_origin(g.origin[a]);
  }
  for (size_t e = 0; e < 9; ++e) grid->add_direction(g.direction[e]);
}

api::Method method_of(v1::Method method) {
  switch (method) {
    case v1::METHOD_DQS: return api::Method::kDqs;
    case v1::METHOD_LBS: return api::Method::kLbs;
    case v1::METHOD_FEM: return api::Method::kFem;
    default: return api::Method::kCor;  // METHOD_COR and METHOD_UNSPECIFIED (method_from refused the rest)
  }
}

v1::PixelType wire_pixel_type(PixelType type) {
  switch (type) {
    case PixelType::kUInt8: return v1::PIXEL_TYPE_UINT8;
    case PixelType::kInt8: return v1::PIXEL_TYPE_INT8;
    case PixelType::kUInt16: return v1::PIXEL_TYPE_UINT16;
    case PixelType::kInt16: return v1::PIXEL_TYPE_INT16;
    case PixelType::kUInt32: return v1::PIXEL_TYPE_UINT32;
    case PixelType::kInt32: return v1::PIXEL_TYPE_INT32;
    case PixelType::kFloat32: return v1::PIXEL_TYPE_FLOAT32;
    case PixelType::kFloat64: return v1::PIXEL_TYPE_FLOAT64;
    default: return v1::PIXEL_TYPE_UNSPECIFIED;
  }
}

void put_rig_row(const RigRecord& record, v1::Rig* message) {
  message->set_id(record.id);
  message->set_name(record.name);
  message->set_size_bytes(record.size_bytes);
  message->set_created(record.created);
  message->set_last_used(record.last_used);
  message->set_labels_volume_id(record.labels_volume_id);
  message->set_ct_volume_id(record.ct_volume_id);
}

void put_skeleton(const api::Rig& rig, v1::Skeleton* skeleton) {
  const api::SkeletonInfo info = api::describe_skeleton(rig);
  for (const api::SegmentInfo& s : info.segments) skeleton->add_segments(s.name);
  for (const api::JointInfo& j : info.joints) {
    v1::Joint* joint = skeleton->add_joints();
    joint->set_name(j.name);
    joint->set_parent(j.parent);
    joint->set_child(j.child);
    for (int a = 0; a < 3; ++a) joint->add_centre_mm(j.centre_mm[a]);
    joint->set_kind(j.kind);
    joint->set_method(j.method);
    joint->set_placed_because(j.placed_because);
    for (int a = 0; a < 3; ++a) {
      joint->add_flexion_axis(j.frame(a, 0));
      joint->add_abduction_axis(j.frame(a, 1));
      joint->add_rotation_axis(j.frame(a, 2));
    }
    for (const api::MotionRange& m : j.ranges) {
      v1::MotionRange* range = joint->add_ranges();
      range->set_motion(m.motion);
      range->set_negative_deg(m.negative_deg);
      range->set_positive_deg(m.positive_deg);
      range->set_negative_stopped(m.negative_stopped);
      range->set_positive_stopped(m.positive_stopped);
    }
  }
}

void put_rig(const RigRecord& record, const api::Rig& rig, v1::Rig* message) {
  put_rig_row(record, message);
  put_grid(rig.source_geometry, message->mutable_grid());
  v1::Skeleton skeleton;
  put_skeleton(rig, &skeleton);
  *message->mutable_joints() = skeleton.joints();
  *message->mutable_segments() = skeleton.segments();
  message->set_tet_vertices(rig.mesh.vertex_count());
  message->set_tets(rig.mesh.tet_count());
  message->set_software_version(rig.provenance.software_version);
  for (const auto& [stage, seconds] : rig.provenance.stage_seconds) {
    v1::StageTime* time = message->add_stage_seconds();
    time->set_stage(stage);
    time->set_seconds(seconds);
  }
  message->set_params_json(rig.params_json);
  message->set_has_ct(rig.ct.has_value());
}

void put_surface(const SurfaceMesh& mesh, bool with_vertices, v1::Surface* message) {
  message->set_name(mesh.name);
  message->set_label(mesh.label);
  if (with_vertices) {
    message->mutable_vertices()->Reserve(static_cast<int>(mesh.vertices.size()));
    for (Eigen::Index v = 0; v < mesh.vertices.rows(); ++v) {
      for (int a = 0; a < 3; ++a) message->add_vertices(mesh.vertices(v, a));
    }
  }
  message->mutable_triangles()->Reserve(static_cast<int>(mesh.triangles.size()));
  for (Eigen::Index t = 0; t < mesh.triangles.rows(); ++t) {
    for (int a = 0; a < 3; ++a) message->add_triangles(mesh.triangles(t, a));
  }
}

void put_report(const QualityReport& report, v1::QualityReport* message) {
  message->set_json(api::report_to_json(report));
  message->set_inverted_tets(report.mesh.inverted_tets);
  message->set_bone_rigidity_error_mm(report.bone_rigidity_error_mm);
  message->set_volume_change(report.mesh.body_volume_change);
  for (const Label l : report.labels.appeared) message->add_new_labels(l);
  for (const Label l : report.labels.vanished) message->add_lost_labels(l);
  for (const std::string& w : report.warnings) message->add_warnings(w);
}

std::string state_name(v1::Operation::State state) { return v1::Operation::State_Name(state); }

bool is_final(v1::Operation::State state) {
  return state == v1::Operation::SUCCEEDED || state == v1::Operation::FAILED || state == v1::Operation::CANCELLED;
}

v1::Operation operation_from(const OperationRecord& record) {
  v1::Operation operation;
  operation.set_id(record.id);
  v1::Operation::State state = v1::Operation::STATE_UNSPECIFIED;
  v1::Operation::State_Parse(record.state, &state);
  operation.set_state(state);
  operation.set_rig_id(record.rig_id);
  operation.set_error_code(record.error_code);
  operation.set_error_message(record.error_message);
  operation.set_elapsed_s(record.elapsed_s);
  operation.set_name(record.name);
  operation.set_created(record.created);
  return operation;
}

OperationRecord record_from(const v1::Operation& operation, const v1::BuildRigRequest& request) {
  OperationRecord record;
  record.id = operation.id();
  record.state = state_name(operation.state());
  record.name = request.name();
  record.labels_volume_id = request.labels_volume_id();
  record.ct_volume_id = request.ct_volume_id();
  record.rig_id = operation.rig_id();
  record.error_code = operation.error_code();
  record.error_message = operation.error_message();
  record.elapsed_s = operation.elapsed_s();
  record.created = operation.created();
  return record;
}

namespace {

template <typename Out>
Status fill_from_raw(std::string_view bytes, PixelType type, Volume<Out>& volume) {
  const int64_t count = volume.voxel_count();
  if (static_cast<uint64_t>(bytes.size()) != static_cast<uint64_t>(count) * static_cast<uint64_t>(pixel_type_bytes(type))) {
    return invalid_argument_error("the raw upload has " + std::to_string(bytes.size()) + " bytes; its grid (" +
                                  volume.geometry().describe() + ") of " + std::string(pixel_type_name(type)) +
                                  " samples needs " + std::to_string(count * pixel_type_bytes(type)));
  }
  if (!read_samples(bytes.data(), count, type, volume.data())) {
    return invalid_argument_error("raw samples of 64-bit integers are not taken; send int32 or float");
  }
  volume.set_source_type(type);
  return ok_status();
}

}  // namespace

Result<LabelVolume> labels_from_raw(std::string_view bytes, PixelType type, const ImageGeometry& grid) {
  if (is_floating(type) || type == PixelType::kUInt32) {
    return invalid_argument_error("raw labels are uint8, int8, uint16, int16 or int32 samples, not " +
                                  std::string(pixel_type_name(type)));
  }
  LabelVolume volume(grid);
  POSEWARP_RETURN_IF_ERROR(fill_from_raw(bytes, type, volume));
  return volume;
}

Result<IntensityVolume> intensity_from_raw(std::string_view bytes, PixelType type, const ImageGeometry& grid) {
  IntensityVolume volume(grid);
  POSEWARP_RETURN_IF_ERROR(fill_from_raw(bytes, type, volume));
  for (int64_t i = 0; i < volume.voxel_count(); ++i) {
    if (!std::isfinite(volume.data()[i])) {
      return invalid_argument_error("the raw intensities hold a NaN or infinity at voxel " + std::to_string(i) +
                                    "; replace it with a finite value before uploading");
    }
  }
  return volume;
}

namespace {

void put_quaternion(const Eigen::Quaterniond& q, v1::Quaternion* message) {
  message->set_w(q.w());
  message->set_x(q.x());
  message->set_y(q.y());
  message->set_z(q.z());
}

void put_angles(const Eigen::Vector3d& degrees, v1::AnatomicalAngles* message) {
  message->set_flexion_deg(degrees.x());
  message->set_abduction_deg(degrees.y());
  message->set_rotation_deg(degrees.z());
}

}  // namespace

void put_pose(const api::Pose& pose, v1::Pose* message) {
  message->set_name(pose.name);
  v1::RootMotion* root = message->mutable_root();
  for (int a = 0; a < 3; ++a) root->add_translation_mm(pose.root.translation[a]);
  put_quaternion(Eigen::Quaterniond(pose.root.rotation).normalized(), root->mutable_rotation()->mutable_quaternion());
  for (const JointRotation& j : pose.joints) {
    v1::JointRotation* joint = message->add_joints();
    joint->set_joint(j.joint);
    if (j.angles_deg) {
      put_angles(*j.angles_deg, joint->mutable_angles());
    } else {
      put_quaternion(j.rotation, joint->mutable_quaternion());
    }
  }
}

void put_segment_match(const api::SegmentMatch& match, v1::SegmentMatch* message) {
  message->set_segment(match.segment);
  message->set_joint(match.joint);
  message->set_matched(match.matched);
  message->set_skipped(match.skipped);
  message->set_volume_ml(match.volume_ml);
  if (match.matched && !match.joint.empty()) put_angles(match.angles_deg, message->mutable_angles());
  message->set_mean_distance_mm(match.mean_distance_mm);
  message->set_max_distance_mm(match.max_distance_mm);
  message->set_dice(match.dice);
  message->set_iterations(match.iterations);
  message->set_beyond_range(match.beyond_range);
  message->set_held_at_range(match.held_at_range);
}

}  // namespace posewarp::server
