// Request checks: uploads, grids, meshes, poses, previews and builds, before any work.
#include "requests.h"

#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdio>
#include <set>

namespace posewarp::server {
namespace {

std::string number_text(double value) {
  char text[32];
  std::snprintf(text, sizeof text, "%g", value);
  return text;
}

Status check_json_size(const std::string& json, const std::string& field) {
  if (json.size() > kMaxRequestJsonBytes) {
    return invalid_argument_error(field + " holds " + std::to_string(json.size()) + " bytes; at most " +
                                  std::to_string(kMaxRequestJsonBytes) + " are read");
  }
  return ok_status();
}

// A typed pose's numbers must be finite (JSON has no NaN); `field` names the one that is not.
Status finite(std::initializer_list<double> values, const std::string& field) {
  for (const double v : values) {
    if (!std::isfinite(v)) return invalid_argument_error(field + " holds NaN or infinity; give finite numbers");
  }
  return ok_status();
}

Result<nlohmann::json> quaternion_json(const v1::Quaternion& q, const std::string& field) {
  POSEWARP_RETURN_IF_ERROR(finite({q.w(), q.x(), q.y(), q.z()}, field));
  return nlohmann::json{{"quaternion", {q.w(), q.x(), q.y(), q.z()}}};
}

Result<nlohmann::json> axis_angle_json(const v1::AxisAngle& a, const std::string& field) {
  if (a.axis_size() != 3) {
    return invalid_argument_error(field + ".axis holds " + std::to_string(a.axis_size()) + " values; give 3");
  }
  POSEWARP_RETURN_IF_ERROR(finite({a.axis(0), a.axis(1), a.axis(2), a.degrees()}, field));
  return nlohmann::json{{"axis_angle", {{"axis", {a.axis(0), a.axis(1), a.axis(2)}}, {"degrees", a.degrees()}}}};
}

// A typed pose as the pose JSON it stands for: the same checks and the same pose as that JSON (doubles written with
// 17 digits read back exactly). What JSON cannot say is refused here: NaN, a joint twice, a joint without rotation.
Result<std::string> typed_pose_json(const v1::Pose& pose) {
  if (pose.joints_size() > kMaxPoseJoints) {
    return invalid_argument_error("pose.joints holds " + std::to_string(pose.joints_size()) + " joints; at most " +
                                  std::to_string(kMaxPoseJoints));
  }
  nlohmann::json doc{{"format", "posewarp.pose"}, {"version", 1}, {"joints", nlohmann::json::object()}};
  if (!pose.name().empty()) doc["name"] = pose.name();
  if (pose.has_root()) {
    const v1::RootMotion& root = pose.root();
    nlohmann::json motion = nlohmann::json::object();
    if (root.translation_mm_size() != 0 && root.translation_mm_size() != 3) {
      return invalid_argument_error("pose.root.translation_mm holds " + std::to_string(root.translation_mm_size()) +
                                    " values; give 3 (LPS mm) or none");
    }
    if (root.translation_mm_size() == 3) {
      POSEWARP_RETURN_IF_ERROR(
          finite({root.translation_mm(0), root.translation_mm(1), root.translation_mm(2)}, "pose.root.translation_mm"));
      motion["translation_mm"] = {root.translation_mm(0), root.translation_mm(1), root.translation_mm(2)};
    }
    if (root.has_rotation()) {
      const v1::Rotation& r = root.rotation();
      if (r.has_quaternion()) {
        POSEWARP_ASSIGN_OR_RETURN(motion["rotation"], quaternion_json(r.quaternion(), "pose.root.rotation.quaternion"));
      } else if (r.has_axis_angle()) {
        POSEWARP_ASSIGN_OR_RETURN(motion["rotation"], axis_angle_json(r.axis_angle(), "pose.root.rotation.axis_angle"));
      } else {
        return invalid_argument_error("pose.root.rotation is set but empty; give quaternion or axis_angle");
      }
    }
    doc["root"] = std::move(motion);
  }
  std::set<std::string> seen;
  for (int i = 0; i < pose.joints_size(); ++i) {
    const v1::JointRotation& joint = pose.joints(i);
    const std::string field = "pose.joints[" + std::to_string(i) + "] (\"" + joint.joint().substr(0, 64) + "\")";
    if (joint.joint().empty()) return invalid_argument_error(field + " has no joint name; GetRig lists the joints");
    if (!seen.insert(joint.joint()).second) {
      return invalid_argument_error(field + " gives the joint a second time; give each joint one rotation");
    }
    nlohmann::json rotation;
    switch (joint.rotation_case()) {
      case v1::JointRotation::kAngles: {
        const v1::AnatomicalAngles& a = joint.angles();
        POSEWARP_RETURN_IF_ERROR(finite({a.flexion_deg(), a.abduction_deg(), a.rotation_deg()}, field + ".angles"));
        rotation = {{"angles_deg",
                     {{"flexion", a.flexion_deg()}, {"abduction", a.abduction_deg()}, {"rotation", a.rotation_deg()}}}};
        break;
      }
      case v1::JointRotation::kQuaternion: {
        POSEWARP_ASSIGN_OR_RETURN(rotation, quaternion_json(joint.quaternion(), field + ".quaternion"));
        break;
      }
      case v1::JointRotation::kAxisAngle: {
        POSEWARP_ASSIGN_OR_RETURN(rotation, axis_angle_json(joint.axis_angle(), field + ".axis_angle"));
        break;
      }
      case v1::JointRotation::ROTATION_NOT_SET:
        return invalid_argument_error(field + " gives no rotation; set angles, quaternion or axis_angle");
    }
    doc["joints"][joint.joint()] = std::move(rotation);
  }
  return doc.dump();
}

// The pose of a request: pose_json, or the typed pose (one of the two). `what` names the request in messages,
// `json_source` its pose_json.
Result<api::Pose> pose_of(const std::string& pose_json, const v1::Pose* typed, const std::string& what,
                          const std::string& json_source) {
  if (typed && !pose_json.empty()) {
    return invalid_argument_error(what + " gives both pose and pose_json; give the pose one way");
  }
  if (typed) {
    POSEWARP_ASSIGN_OR_RETURN(const std::string text, typed_pose_json(*typed));
    return api::pose_from_json(text, "(the typed pose of " + what + ")");
  }
  POSEWARP_RETURN_IF_ERROR(check_json_size(pose_json, "pose_json"));
  return api::pose_from_json(pose_json, json_source);
}

// An upload header's sha256 and size_bytes, the same for volumes and rigs.
Status check_file_claim(const std::string& sha256, uint64_t size_bytes, const RequestLimits& limits,
                        const std::string& what) {
  if (!api::is_hex_id(sha256)) {
    return invalid_argument_error("header.sha256 must be the " + what + "'s SHA-256 as 64 lowercase hex digits");
  }
  if (size_bytes == 0) {
    return invalid_argument_error("header.size_bytes is 0; give the size of the whole " + what + " in bytes");
  }
  if (size_bytes > static_cast<uint64_t>(limits.max_upload_bytes)) {
    return resource_exhausted_error("header.size_bytes is " + std::to_string(size_bytes) +
                                    "; this server takes files of at most " + std::to_string(limits.max_upload_bytes) +
                                    " bytes (its --max-upload-mb)");
  }
  return ok_status();
}

}  // namespace

const char* extension_of(v1::FileFormat format) {
  switch (format) {
    case v1::FILE_FORMAT_NIFTI_GZ: return ".nii.gz";
    case v1::FILE_FORMAT_NIFTI: return ".nii";
    case v1::FILE_FORMAT_NRRD: return ".nrrd";
    case v1::FILE_FORMAT_MHA: return ".mha";
    default: return nullptr;
  }
}

std::optional<PixelType> pixel_type_of(v1::PixelType type) {
  switch (type) {
    case v1::PIXEL_TYPE_UINT8: return PixelType::kUInt8;
    case v1::PIXEL_TYPE_INT8: return PixelType::kInt8;
    case v1::PIXEL_TYPE_UINT16: return PixelType::kUInt16;
    case v1::PIXEL_TYPE_INT16: return PixelType::kInt16;
    case v1::PIXEL_TYPE_UINT32: return PixelType::kUInt32;
    case v1::PIXEL_TYPE_INT32: return PixelType::kInt32;
    case v1::PIXEL_TYPE_FLOAT32: return PixelType::kFloat32;
    case v1::PIXEL_TYPE_FLOAT64: return PixelType::kFloat64;
    default: return std::nullopt;
  }
}

Result<v1::Method> method_from(v1::Method method, const std::string& field) {
  switch (method) {
    case v1::METHOD_UNSPECIFIED:
    case v1::METHOD_COR: return v1::METHOD_COR;
    case v1::METHOD_DQS:
    case v1::METHOD_LBS:
    case v1::METHOD_FEM: return method;
    default:
      return invalid_argument_error(
          field + " is " + std::to_string(static_cast<int>(method)) +
          ", not a method; use METHOD_COR (1, the default), METHOD_DQS (2), METHOD_LBS (3) or METHOD_FEM (4)");
  }
}

Result<ImageGeometry> grid_from(const v1::Grid& grid, const std::string& field) {
  if (grid.size_size() != 3 || grid.spacing_size() != 3 || grid.origin_size() != 3 || grid.direction_size() != 9) {
    return invalid_argument_error(field +
                                  " needs 3 sizes, 3 spacings, 3 origin coordinates and 9 direction entries "
                                  "(row-major, LPS mm); it has " +
                                  std::to_string(grid.size_size()) + ", " + std::to_string(grid.spacing_size()) + ", " +
                                  std::to_string(grid.origin_size()) + " and " + std::to_string(grid.direction_size()));
  }
  ImageGeometry g;
  for (int a = 0; a < 3; ++a) {
    const std::string axis = "[" + std::to_string(a) + "]";
    if (grid.size(a) < 1 || grid.size(a) > kMaxGridAxis) {
      return invalid_argument_error(field + ".size" + axis + " is " + std::to_string(grid.size(a)) +
                                    "; each axis holds 1 to " + std::to_string(kMaxGridAxis) + " voxels");
    }
    if (!(grid.spacing(a) >= kMinSpacingMm && grid.spacing(a) <= kMaxSpacingMm)) {
      return invalid_argument_error(field + ".spacing" + axis + " is " + number_text(grid.spacing(a)) +
                                    " mm; a spacing lies within " + number_text(kMinSpacingMm) + " to " +
                                    number_text(kMaxSpacingMm) + " mm");
    }
    if (!(std::abs(grid.origin(a)) <= kMaxOriginMm)) {
      return invalid_argument_error(field + ".origin" + axis + " is " + number_text(grid.origin(a)) +
                                    " mm; an origin lies within " + number_text(kMaxOriginMm) + " mm of zero");
    }
    g.size[static_cast<size_t>(a)] = grid.size(a);
    g.spacing[static_cast<size_t>(a)] = grid.spacing(a);
    g.origin[static_cast<size_t>(a)] = grid.origin(a);
  }
  for (int e = 0; e < 9; ++e) {
    if (!std::isfinite(grid.direction(e))) {
      return invalid_argument_error(field + ".direction[" + std::to_string(e) + "] is not a finite number");
    }
    g.direction[static_cast<size_t>(e)] = grid.direction(e);
  }
  Status valid = g.validate();
  if (!valid.ok()) return valid.with_context(field);
  return g;
}

Result<api::SurfaceMesh> surface_from(const v1::Surface& message) {
  const std::string name = message.name().empty() ? "mesh" : message.name().substr(0, 64);
  if (message.vertices_size() == 0 || message.vertices_size() % 3 != 0 || message.triangles_size() % 3 != 0) {
    return invalid_argument_error("meshes: mesh '" + name +
                                  "' needs 3 coordinates per vertex (vertices) and 3 vertex "
                                  "indices per triangle (triangles)");
  }
  api::SurfaceMesh mesh;
  mesh.name = name;
  mesh.label = message.label();
  const int vertices = message.vertices_size() / 3;
  mesh.vertices.resize(vertices, 3);
  for (int i = 0; i < message.vertices_size(); ++i) {
    if (!(std::abs(message.vertices(i)) <= kMaxOriginMm)) {
      return invalid_argument_error("meshes: mesh '" + name + "' has vertex coordinate " +
                                    number_text(message.vertices(i)) + "; coordinates are finite LPS mm within " +
                                    number_text(kMaxOriginMm) + " mm of zero");
    }
    mesh.vertices(i / 3, i % 3) = message.vertices(i);
  }
  mesh.triangles.resize(message.triangles_size() / 3, 3);
  for (int i = 0; i < message.triangles_size(); ++i) {
    if (message.triangles(i) < 0 || message.triangles(i) >= vertices) {
      return invalid_argument_error("meshes: mesh '" + name + "' has a triangle naming vertex " +
                                    std::to_string(message.triangles(i)) + " of " + std::to_string(vertices));
    }
    mesh.triangles(i / 3, i % 3) = message.triangles(i);
  }
  return mesh;
}

Result<UploadPlan> check_upload_header(const v1::UploadVolumeHeader& header, const RequestLimits& limits) {
  UploadPlan plan;
  plan.raw = header.format() == v1::FILE_FORMAT_RAW;
  const char* extension = plan.raw ? ".nii.gz" : extension_of(header.format());
  if (extension == nullptr) {
    return invalid_argument_error("header.format is " + std::to_string(static_cast<int>(header.format())) +
                                  "; an upload is FILE_FORMAT_NIFTI_GZ, NIFTI, NRRD, MHA (each with its voxels "
                                  "inline) or RAW");
  }
  plan.extension = extension;
  if (header.kind() != v1::VOLUME_KIND_LABELS && header.kind() != v1::VOLUME_KIND_INTENSITY) {
    return invalid_argument_error("header.kind is " + std::to_string(static_cast<int>(header.kind())) +
                                  "; an upload is VOLUME_KIND_LABELS or VOLUME_KIND_INTENSITY");
  }
  POSEWARP_RETURN_IF_ERROR(check_file_claim(header.sha256(), header.size_bytes(), limits, "file"));
  if (!plan.raw) {
    if (header.has_raw_grid() || header.raw_pixel_type() != v1::PIXEL_TYPE_UNSPECIFIED) {
      return invalid_argument_error(
          "header.raw_grid and header.raw_pixel_type belong to FILE_FORMAT_RAW uploads; a "
          "file carries its own geometry");
    }
    return plan;
  }
  POSEWARP_ASSIGN_OR_RETURN(plan.raw_grid, grid_from(header.raw_grid(), "header.raw_grid"));
  const std::optional<PixelType> type = pixel_type_of(header.raw_pixel_type());
  if (!type) {
    return invalid_argument_error("header.raw_pixel_type is " +
                                  std::to_string(static_cast<int>(header.raw_pixel_type())) +
                                  "; a raw upload names its samples' type (PIXEL_TYPE_UINT8 ... PIXEL_TYPE_FLOAT64)");
  }
  plan.raw_type = *type;
  const int64_t voxels = plan.raw_grid.voxel_count();
  if (voxels > limits.max_volume_voxels) {
    return resource_exhausted_error(
        "header.raw_grid holds " + std::to_string(voxels) + " voxels; this server takes volumes of at most " +
        std::to_string(limits.max_volume_voxels) + " voxels (its --max-volume-voxels): crop or downsample the volume");
  }
  const uint64_t expected = static_cast<uint64_t>(voxels) * static_cast<uint64_t>(pixel_type_bytes(plan.raw_type));
  if (header.size_bytes() != expected) {
    return invalid_argument_error("header.size_bytes is " + std::to_string(header.size_bytes()) + ", but raw_grid (" +
                                  plan.raw_grid.describe() + ") of " + std::string(pixel_type_name(plan.raw_type)) +
                                  " samples is " + std::to_string(expected) + " bytes");
  }
  return plan;
}

Status check_rig_upload_header(const v1::UploadRigHeader& header, const RequestLimits& limits) {
  POSEWARP_RETURN_IF_ERROR(check_file_claim(header.sha256(), header.size_bytes(), limits, "rig file"));
  if (header.name().size() > 256) return invalid_argument_error("header.name is longer than 256 characters");
  return ok_status();
}

Result<CheckedPose> check_pose_request(const v1::PoseRequest& request) {
  if (!api::is_hex_id(request.rig_id()))
    return invalid_argument_error("rig_id is 64 lowercase hex digits (from BuildRig)");
  CheckedPose checked;
  POSEWARP_ASSIGN_OR_RETURN(checked.method, method_from(request.method(), "method"));
  switch (request.grid()) {
    case v1::GRID_POLICY_UNSPECIFIED:
    case v1::GRID_POLICY_INPUT: checked.grid = v1::GRID_POLICY_INPUT; break;
    case v1::GRID_POLICY_GROW:
    case v1::GRID_POLICY_GIVEN: checked.grid = request.grid(); break;
    default:
      return invalid_argument_error("grid is " + std::to_string(static_cast<int>(request.grid())) +
                                    ", not a grid policy; use GRID_POLICY_INPUT (1, the default), GRID_POLICY_GROW (2) "
                                    "or GRID_POLICY_GIVEN (3) with given_grid");
  }
  if (checked.grid == v1::GRID_POLICY_GIVEN) {
    POSEWARP_ASSIGN_OR_RETURN(checked.given_grid, grid_from(request.given_grid(), "given_grid"));
  } else if (request.has_given_grid()) {
    return invalid_argument_error("given_grid is set, but grid is not GRID_POLICY_GIVEN; set both or neither");
  }
  switch (request.format()) {
    case v1::FILE_FORMAT_UNSPECIFIED:
    case v1::FILE_FORMAT_RAW:
    case v1::FILE_FORMAT_NIFTI_GZ:
    case v1::FILE_FORMAT_NIFTI:
    case v1::FILE_FORMAT_NRRD: break;
    default:
      return invalid_argument_error("format is " + std::to_string(static_cast<int>(request.format())) +
                                    "; a pose's volumes come as FILE_FORMAT_RAW samples or FILE_FORMAT_NIFTI_GZ, "
                                    "FILE_FORMAT_NIFTI or FILE_FORMAT_NRRD bytes (MHA is not offered)");
  }
  if (request.samples() != v1::SAMPLE_TYPE_STORED && request.samples() != v1::SAMPLE_TYPE_COMPUTED) {
    return invalid_argument_error("samples is " + std::to_string(static_cast<int>(request.samples())) +
                                  "; use SAMPLE_TYPE_STORED (0) or SAMPLE_TYPE_COMPUTED (1)");
  }
  if (request.chunk_bytes() != 0 &&
      (request.chunk_bytes() < kMinPoseChunkBytes || request.chunk_bytes() > kMaxPoseChunkBytes)) {
    return invalid_argument_error("chunk_bytes is " + std::to_string(request.chunk_bytes()) + "; give 0 (1 MiB) or " +
                                  std::to_string(kMinPoseChunkBytes) + " to " + std::to_string(kMaxPoseChunkBytes));
  }
  checked.chunk_bytes = request.chunk_bytes() == 0 ? kDefaultPoseChunkBytes : request.chunk_bytes();
  if (request.meshes_size() > 0 && !request.want_surfaces()) {
    return invalid_argument_error("meshes come back as posed surfaces: set want_surfaces");
  }
  if (request.meshes_size() > 256) {
    return invalid_argument_error("meshes holds " + std::to_string(request.meshes_size()) + " meshes; at most 256");
  }
  for (const v1::Surface& mesh : request.meshes()) {
    POSEWARP_ASSIGN_OR_RETURN(api::SurfaceMesh parsed, surface_from(mesh));
    checked.meshes.push_back(std::move(parsed));
  }
  Result<api::Pose> parsed =
      pose_of(request.pose_json(), request.has_pose() ? &request.pose() : nullptr, "the request", "pose_json");
  if (!parsed.ok()) return parsed.status();
  checked.pose = std::move(parsed).value();
  return checked;
}

Result<api::Pose> check_preview_request(const v1::PreviewRequest& request) {
  POSEWARP_RETURN_IF_ERROR(method_from(request.method(), "method").status());
  const std::string update = "preview update " + std::to_string(request.sequence());
  return pose_of(request.pose_json(), request.has_pose() ? &request.pose() : nullptr, update, "pose_json of " + update);
}

Status check_build_request(const v1::BuildRigRequest& request) {
  if (!api::is_hex_id(request.labels_volume_id())) {
    return invalid_argument_error("labels_volume_id is 64 lowercase hex digits (the id UploadVolume answered)");
  }
  if (!request.ct_volume_id().empty() && !api::is_hex_id(request.ct_volume_id())) {
    return invalid_argument_error("ct_volume_id is empty or 64 lowercase hex digits (the id UploadVolume answered)");
  }
  if (request.ct_volume_id() == request.labels_volume_id()) {
    return invalid_argument_error(
        "labels_volume_id and ct_volume_id name the same volume; the CT is the intensity "
        "volume on the labels' grid");
  }
  POSEWARP_RETURN_IF_ERROR(check_json_size(request.label_map_json(), "label_map_json"));
  POSEWARP_RETURN_IF_ERROR(check_json_size(request.rig_spec_json(), "rig_spec_json"));
  if (request.name().size() > 256) return invalid_argument_error("name is longer than 256 characters");
  return ok_status();
}

Status check_match_request(const v1::MatchPostureRequest& request) {
  if (!api::is_hex_id(request.rig_id()))
    return invalid_argument_error("rig_id is 64 lowercase hex digits (from BuildRig)");
  if (request.target_labels_volume_id().empty() == request.standard().empty()) {
    return invalid_argument_error(
        "give either target_labels_volume_id (the other scan's labels, uploaded) or standard (a standard posture's "
        "name)");
  }
  if (!request.target_labels_volume_id().empty() && !api::is_hex_id(request.target_labels_volume_id())) {
    return invalid_argument_error("target_labels_volume_id is 64 lowercase hex digits (the id UploadVolume answered)");
  }
  if (request.standard().size() > 64) return invalid_argument_error("standard is longer than 64 characters");
  if (!request.preset().empty() && !request.label_map_json().empty()) {
    return invalid_argument_error("give preset or label_map_json, not both");
  }
  if (request.preset().size() > 64) return invalid_argument_error("preset is longer than 64 characters");
  return check_json_size(request.label_map_json(), "label_map_json");
}

}  // namespace posewarp::server
