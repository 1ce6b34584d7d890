// Remote commands over the generated gRPC client.
#include "remote.h"

#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/grpcpp.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <future>
#include <memory>
#include <thread>

#include "cli_support.h"
#include "posewarp/api/files.h"
#include "posewarp/api/rig_file.h"
#include "posewarp/api/support.h"
#include "posewarp_client/connection.h"
#include "posewarp_client/pose_answer.h"
#include "posewarp/v1/posewarp.grpc.pb.h"

#include <nlohmann/json.hpp>

namespace posewarp::cli {
namespace {

namespace fs = std::filesystem;

// A failed call as the local commands report it: the server's code is the core's, so the exit code table holds.
Status status_of(const client::CallError& error) {
  return Status(static_cast<StatusCode>(error.code), error.message);
}
Status status_of(const grpc::Status& status, const std::string& server) {
  return status_of(client::error_of(status, server));
}
int report_rpc(const grpc::Status& status, const std::string& server) {
  return report(status_of(status, server));
}

// The client library's connection (token, TLS, each call's metadata), shared by a command's calls.
using Remote = std::shared_ptr<const client::Connection>;

// The connection for a command's --server options: a call the server refuses as unavailable is tried again as
// RetryPolicy says, each wait said on stderr.
Result<Remote> connect(const Connection& c) {
  const RetryPolicy policy{c.retries};
  client::Retries retries{c.retries, [policy](int n) { return policy.wait(n); },
                          [server = c.server](const grpc::Status& failed, std::chrono::milliseconds wait) {
                            say("posewarp-server at " + server + " is unavailable (" + failed.error_message() +
                                "); trying again within " + std::to_string(wait.count() / 1000.0).substr(0, 3) +
                                " s");
                          }};
  client::CallError error;
  std::unique_ptr<client::Connection> opened =
      client::Connection::open({c.server, c.token_file, c.tls_ca}, &error, std::move(retries));
  if (!opened) return status_of(error);
  return Remote(std::move(opened));
}

// A rig id where --server wants one (a rig path there is the usual slip).
Status check_rig_id(const std::string& rig_id) {
  if (api::is_hex_id(rig_id)) return ok_status();
  return invalid_argument_error(
      "with --server the rig is a rig id (64 hex digits, from `posewarp rig build "
      "--server` or `posewarp rig list --server`), not '" +
      rig_id + "'");
}

v1::FileFormat format_of(const std::string& path) {
  auto ends = [&path](const char* suffix) {
    const std::string s(suffix);
    return path.size() >= s.size() && path.compare(path.size() - s.size(), s.size(), s) == 0;
  };
  if (ends(".nii.gz")) return v1::FILE_FORMAT_NIFTI_GZ;
  if (ends(".nii")) return v1::FILE_FORMAT_NIFTI;
  if (ends(".nrrd")) return v1::FILE_FORMAT_NRRD;
  if (ends(".mha")) return v1::FILE_FORMAT_MHA;
  return v1::FILE_FORMAT_UNSPECIFIED;
}

Result<std::string> upload(const Remote& stub, const RemoteVolumeFile& file, v1::VolumeKind kind) {
  const std::string& server = stub->server();
  const v1::FileFormat format = format_of(file.name);
  if (format == v1::FILE_FORMAT_UNSPECIFIED) {
    return invalid_argument_error("'" + file.name +
                                  "': the server takes .nii.gz, .nii, .nrrd or .mha files (convert "
                                  "others with `posewarp convert`)");
  }
  const std::string& bytes = file.bytes;
  v1::Volume volume;
  const grpc::Status status = stub->with_retries([&] {
    const auto context = stub->context();
    auto writer = stub->stub().UploadVolume(context.get(), &volume);
    v1::UploadVolumeRequest part;
    part.mutable_header()->set_kind(kind);
    part.mutable_header()->set_format(format);
    part.mutable_header()->set_size_bytes(bytes.size());
    part.mutable_header()->set_sha256(api::sha256_hex(bytes));
    // A server that holds the file already answers after the header; the chunks' writes then fail and stop.
    bool open = writer->Write(part);
    for (size_t offset = 0; open && offset < bytes.size(); offset += size_t{1} << 20) {
      v1::UploadVolumeRequest chunk;
      chunk.set_chunk(bytes.substr(offset, size_t{1} << 20));
      open = writer->Write(chunk);
    }
    writer->WritesDone();
    return writer->Finish();
  });
  if (!status.ok()) {
    if (status.error_code() == grpc::StatusCode::UNAVAILABLE) return status_of(status, server);
    return Status(static_cast<StatusCode>(status.error_code()), "'" + file.name + "': " + status.error_message());
  }
  if (volume.already_stored()) {
    say(file.name + " is on the server already (volume " + volume.id().substr(0, 12) + ")");
    return volume.id();
  }
  say("uploaded " + file.name + " as volume " + volume.id().substr(0, 12));
  return volume.id();
}

ImageGeometry grid_of(const v1::Grid& grid) {
  ImageGeometry g;
  for (int a = 0; a < 3 && a < grid.size_size(); ++a) {
    g.size[static_cast<size_t>(a)] = grid.size(a);
    g.spacing[static_cast<size_t>(a)] = grid.spacing(a);
    g.origin[static_cast<size_t>(a)] = grid.origin(a);
  }
  for (int e = 0; e < 9 && e < grid.direction_size(); ++e) g.direction[static_cast<size_t>(e)] = grid.direction(e);
  return g;
}

PixelType pixel_type_named(const std::string& name, PixelType fallback) {
  for (int t = 0; t <= static_cast<int>(PixelType::kFloat64); ++t) {
    if (pixel_type_name(static_cast<PixelType>(t)) == name) return static_cast<PixelType>(t);
  }
  return fallback;
}

// The raw samples of a pose answer as a volume on `grid`, to be written in the study's own voxel type.
template <typename T>
Result<Volume<T>> volume_from_samples(const std::string& bytes, v1::PixelType sample_type, const ImageGeometry& grid,
                                      const std::string& study_type) {
  const PixelType fallback = std::is_same_v<T, float> ? PixelType::kFloat32 : PixelType::kInt32;
  std::string name = v1::PixelType_Name(sample_type).substr(std::string_view("PIXEL_TYPE_").size());  // "UINT8"
  std::transform(name.begin(), name.end(), name.begin(), [](unsigned char c) { return std::tolower(c); });
  const PixelType type = pixel_type_named(name, fallback);
  Volume<T> volume(grid);
  if (bytes.size() != static_cast<size_t>(volume.voxel_count()) * static_cast<size_t>(pixel_type_bytes(type)) ||
      !read_samples(bytes.data(), volume.voxel_count(), type, volume.data())) {
    return data_loss_error("the server's samples do not fill the output grid; run the pose again");
  }
  volume.set_source_type(pixel_type_named(study_type, type));
  return volume;
}

}  // namespace

Result<std::string> build_rig_remote(const Connection& connection, const RemoteRigInputs& inputs,
                                     const std::function<void(const std::string&, double)>& on_stage) {
  POSEWARP_ASSIGN_OR_RETURN(const Remote stub, connect(connection));
  const std::string& server = connection.server;
  v1::BuildRigRequest request;
  POSEWARP_ASSIGN_OR_RETURN(*request.mutable_labels_volume_id(), upload(stub, inputs.labels, v1::VOLUME_KIND_LABELS));
  if (inputs.ct) {
    POSEWARP_ASSIGN_OR_RETURN(*request.mutable_ct_volume_id(), upload(stub, *inputs.ct, v1::VOLUME_KIND_INTENSITY));
  }
  request.set_label_map_json(inputs.label_map_json);
  request.set_preset(inputs.preset);
  request.set_rig_spec_json(inputs.rig_spec_json);
  request.set_name(inputs.name.empty() ? inputs.labels.name : inputs.name);
  v1::Operation operation;
  if (grpc::Status s = stub->unary(&v1::Posewarp::Stub::BuildRig, request, &operation); !s.ok()) {
    return status_of(s, server);  // a build request is idempotent: the same inputs share one operation
  }
  // The operation's stream until it ends; a stream cut by a restarting server is watched again.
  const grpc::Status watched = stub->with_retries([&] {
    const auto context = stub->context();
    v1::GetOperationRequest watch;
    watch.set_operation_id(operation.id());
    auto reader = stub->stub().WatchOperation(context.get(), watch);
    v1::Operation state;
    while (reader->Read(&state)) {
      operation = state;
      if (on_stage && !state.stage().empty()) on_stage(state.stage(), state.stage_fraction());
    }
    return reader->Finish();
  });
  if (!watched.ok()) return status_of(watched, server);
  if (operation.state() != v1::Operation::SUCCEEDED) {
    return Status(static_cast<StatusCode>(operation.error_code() == 0 ? 2 : operation.error_code()),
                  "the build failed on the server: " + operation.error_message());
  }
  say("rig " + operation.rig_id() + " built on " + server + " in " + std::to_string(operation.elapsed_s()) + " s");
  return operation.rig_id();
}

int run_build_remote(const RemoteBuild& o) {
  RemoteRigInputs inputs;
  inputs.labels.name = o.labels_path;
  Result<std::string> bytes = api::read_text_input(o.labels_path, "volume", int64_t{8} << 30);
  if (!bytes.ok()) return report(bytes.status());
  inputs.labels.bytes = std::move(bytes).value();
  if (!o.ct_path.empty()) {
    bytes = api::read_text_input(o.ct_path, "volume", int64_t{8} << 30);
    if (!bytes.ok()) return report(bytes.status());
    inputs.ct = RemoteVolumeFile{o.ct_path, std::move(bytes).value()};
  }
  if (!o.label_map_path.empty()) {
    bytes = api::read_text_input(o.label_map_path, "label map");
    if (!bytes.ok()) return report(bytes.status());
    inputs.label_map_json = std::move(bytes).value();
  }
  inputs.preset = o.preset;
  if (!o.spec_path.empty()) {
    bytes = api::read_text_input(o.spec_path, "rig spec");
    if (!bytes.ok()) return report(bytes.status());
    inputs.rig_spec_json = std::move(bytes).value();
  }
  inputs.name = o.name.empty() ? fs::path(o.labels_path).filename().string() : o.name;
  // Progress as the local build shows it, from the operation's stream.
  const ProgressHooks bar = progress_bar();
  Result<std::string> rig_id = build_rig_remote(o.connection, inputs, [&bar](const std::string& stage, double f) {
    if (bar.on_progress) bar.on_progress(stage, f);
  });
  if (!rig_id.ok()) return report(rig_id.status());
  std::printf("%s\n", rig_id->c_str());
  return 0;
}

Result<RemoteMatch> match_remote(const Connection& connection, const RemoteMatchRequest& r) {
  POSEWARP_RETURN_IF_ERROR(check_rig_id(r.rig_id));
  POSEWARP_ASSIGN_OR_RETURN(const Remote stub, connect(connection));
  v1::MatchPostureRequest request;
  request.set_rig_id(r.rig_id);
  if (r.target) {
    POSEWARP_ASSIGN_OR_RETURN(*request.mutable_target_labels_volume_id(),
                              upload(stub, *r.target, v1::VOLUME_KIND_LABELS));
  }
  request.set_standard(r.standard);
  request.set_preset(r.preset);
  request.set_label_map_json(r.label_map_json);
  request.set_free_hinges(r.free_hinges);
  request.set_beyond_range(r.beyond_range);
  v1::MatchPostureResponse answer;
  if (grpc::Status s = stub->unary(&v1::Posewarp::Stub::MatchPosture, request, &answer); !s.ok()) {
    return status_of(s, connection.server);
  }
  RemoteMatch out;
  POSEWARP_ASSIGN_OR_RETURN(out.match.match.pose, api::pose_from_json(answer.pose_json(), "the server's answer"));
  for (const v1::SegmentMatch& m : answer.segments()) {
    api::SegmentMatch s;
    s.segment = m.segment();
    s.joint = m.joint();
    s.matched = m.matched();
    s.skipped = m.skipped();
    s.volume_ml = m.volume_ml();
    s.angles_deg = {m.angles().flexion_deg(), m.angles().abduction_deg(), m.angles().rotation_deg()};
    s.mean_distance_mm = m.mean_distance_mm();
    s.max_distance_mm = m.max_distance_mm();
    s.dice = m.dice();
    s.iterations = m.iterations();
    s.beyond_range = m.beyond_range();
    s.held_at_range = m.held_at_range();
    out.match.match.segments.push_back(std::move(s));
  }
  out.match.unnamed_labels.assign(answer.unnamed_labels().begin(), answer.unnamed_labels().end());
  out.match.seconds = answer.seconds();
  out.report_json = answer.report_json();
  if (answer.has_target_grid()) out.target_grid = grid_of(answer.target_grid());
  return out;
}

int run_list_remote(const Connection& connection) {
  Result<Remote> remote = connect(connection);
  if (!remote.ok()) return report(remote.status());
  std::vector<v1::Rig> rigs;
  if (const client::CallError e = (*remote)->list_rigs(&rigs); e.failed()) {
    return report(status_of(e));
  }
  for (const v1::Rig& rig : rigs) {
    std::printf("%s  %-24s %10.1f MB  %s\n", rig.id().c_str(), rig.name().c_str(),
                static_cast<double>(rig.size_bytes()) / 1e6, rig.created().c_str());
  }
  return 0;
}

struct RemotePoser::State {
  Remote remote;
  std::string rig_id;
};

RemotePoser::RemotePoser(std::unique_ptr<State> state) : state_(std::move(state)) {}
RemotePoser::RemotePoser(RemotePoser&&) noexcept = default;
RemotePoser& RemotePoser::operator=(RemotePoser&&) noexcept = default;
RemotePoser::~RemotePoser() = default;

Result<RemotePoser> RemotePoser::open(const Connection& connection, const std::string& rig_id) {
  POSEWARP_RETURN_IF_ERROR(check_rig_id(rig_id));
  POSEWARP_ASSIGN_OR_RETURN(Remote remote, connect(connection));
  return RemotePoser(std::make_unique<State>(State{std::move(remote), rig_id}));
}

namespace {

void put_grid(const ImageGeometry& g, v1::Grid* grid) {
  for (int a = 0; a < 3; ++a) {
    grid->add_size(g.size[static_cast<size_t>(a)]);
    grid->add_spacing(g.spacing[static_cast<size_t>(a)]);
    grid->add_origin(g.origin[static_cast<size_t>(a)]);
  }
  for (int e = 0; e < 9; ++e) grid->add_direction(g.direction[static_cast<size_t>(e)]);
}

void set_quaternion(const Eigen::Quaterniond& q, v1::Quaternion* out) {
  out->set_w(q.w());
  out->set_x(q.x());
  out->set_y(q.y());
  out->set_z(q.z());
}

// The pose, typed: the same numbers its JSON (api::pose_to_json) would carry, so the server poses it the same.
void put_pose(const Pose& pose, v1::Pose* out) {
  out->set_name(pose.name);
  if (pose.root.rotation != Eigen::Matrix3d::Identity() || !pose.root.translation.isZero(0.0)) {
    v1::RootMotion* root = out->mutable_root();
    for (int a = 0; a < 3; ++a) root->add_translation_mm(pose.root.translation[a]);
    set_quaternion(Eigen::Quaterniond(pose.root.rotation), root->mutable_rotation()->mutable_quaternion());
  }
  for (const JointRotation& joint : pose.joints) {
    v1::JointRotation* typed = out->add_joints();
    typed->set_joint(joint.joint);
    if (joint.angles_deg) {
      typed->mutable_angles()->set_flexion_deg(joint.angles_deg->x());
      typed->mutable_angles()->set_abduction_deg(joint.angles_deg->y());
      typed->mutable_angles()->set_rotation_deg(joint.angles_deg->z());
    } else {
      set_quaternion(joint.rotation, typed->mutable_quaternion());
    }
  }
}

v1::PoseRequest proto_request(const api::PoseRequest& r, const std::string& rig_id) {
  v1::PoseRequest request;
  request.set_rig_id(rig_id);
  put_pose(r.pose, request.mutable_pose());
  request.set_method(r.method == api::Method::kDqs   ? v1::METHOD_DQS
                     : r.method == api::Method::kLbs ? v1::METHOD_LBS
                     : r.method == api::Method::kFem ? v1::METHOD_FEM
                                                          : v1::METHOD_COR);
  if (r.grid == api::GridPolicy::kGrow) request.set_grid(v1::GRID_POLICY_GROW);
  if (r.grid == api::GridPolicy::kGiven && r.given_grid) {
    request.set_grid(v1::GRID_POLICY_GIVEN);
    put_grid(*r.given_grid, request.mutable_given_grid());
  }
  if (r.method == api::Method::kFem &&
      (r.fem.max_iterations > 0 || r.fem.volume_weight > 0.0 || r.fem.contact ||
       r.fem.refine_iterations != api::FemOptions{}.refine_iterations)) {
    request.mutable_fem()->set_max_iterations(static_cast<uint32_t>(std::max(0, r.fem.max_iterations)));
    request.mutable_fem()->set_volume_weight(r.fem.volume_weight);
    request.mutable_fem()->set_contact(r.fem.contact);
    request.mutable_fem()->set_refine_iterations(static_cast<uint32_t>(std::max(0, r.fem.refine_iterations)));
  }
  request.set_nearest_ct(r.ct_interpolation == api::Interpolation::kNearest);
  request.set_want_labels(r.want_labels);
  request.set_want_ct(r.want_ct);
  request.set_want_surfaces(r.want_surfaces);
  request.set_want_fields(r.want_fields);
  request.set_max_output_bytes(static_cast<uint64_t>(std::max<int64_t>(0, r.limits.max_bytes)));
  request.set_samples(v1::SAMPLE_TYPE_STORED);            // what the files hold, in the fewest bytes
  request.set_label_encoding(v1::LABEL_ENCODING_RUNS);  // labels in runs: a fraction of their samples' bytes
  for (const SurfaceMesh& mesh : r.extra_surfaces) {
    v1::Surface* m = request.add_meshes();
    m->set_name(mesh.name);
    m->set_label(mesh.label);
    for (Eigen::Index v = 0; v < mesh.vertices.rows(); ++v) {
      for (int a = 0; a < 3; ++a) m->add_vertices(mesh.vertices(v, a));
    }
    for (Eigen::Index t = 0; t < mesh.triangles.rows(); ++t) {
      for (int a = 0; a < 3; ++a) m->add_triangles(mesh.triangles(t, a));
    }
  }
  return request;
}

std::vector<float> floats_of(const std::string& bytes) {
  std::vector<float> values(bytes.size() / sizeof(float));
  std::memcpy(values.data(), bytes.data(), values.size() * sizeof(float));
  return values;
}

}  // namespace

Result<RemotePoseResult> RemotePoser::pose(const api::PoseRequest& core) const {
  const v1::PoseRequest request = proto_request(core, state_->rig_id);
  client::PoseAnswer wire;
  if (const client::CallError e = client::pose(*state_->remote, request, &wire); e.failed()) {
    return status_of(e);
  }
  RemotePoseResult answer;
  for (const v1::Surface& s : wire.surfaces) {
    SurfaceMesh mesh;
    mesh.name = s.name();
    mesh.label = s.label();
    mesh.vertices.resize(s.vertices_size() / 3, 3);
    for (int i = 0; i < s.vertices_size(); ++i) mesh.vertices(i / 3, i % 3) = s.vertices(i);
    mesh.triangles.resize(s.triangles_size() / 3, 3);
    for (int i = 0; i < s.triangles_size(); ++i) mesh.triangles(i / 3, i % 3) = s.triangles(i);
    answer.result.surfaces.push_back(std::move(mesh));
  }
  answer.report_json = wire.report.json();
  answer.warnings.assign(wire.report.warnings().begin(), wire.report.warnings().end());
  const v1::PoseHeader& header = wire.header;
  const std::string &labels = wire.labels, &ct = wire.ct, &inverse = wire.inverse_field, &forward = wire.forward_field;
  const ImageGeometry grid = grid_of(header.grid());
  answer.result.output_grid = grid;
  if (core.want_labels) {
    POSEWARP_ASSIGN_OR_RETURN(answer.result.labels, volume_from_samples<Label>(labels, header.label_sample_type(), grid,
                                                                               header.label_pixel_type()));
  }
  if (core.want_ct && !ct.empty()) {
    POSEWARP_ASSIGN_OR_RETURN(answer.result.ct,
                              volume_from_samples<float>(ct, header.ct_sample_type(), grid, header.ct_pixel_type()));
  }
  answer.result.inverse_field = floats_of(inverse);
  answer.result.forward_field = floats_of(forward);
  answer.source_grid = grid_of(header.source_grid());
  return answer;
}

namespace {

// A rig file from the server, whole and checked against its SHA-256.
Result<std::string> download_rig(const Remote& remote, const std::string& rig_id) {
  v1::GetRigRequest request;
  request.set_rig_id(rig_id);
  std::string bytes, sha;
  uint64_t size = 0;
  const grpc::Status status = remote->with_retries([&] {
    bytes.clear();
    const auto context = remote->context(rig_id);
    auto reader = remote->stub().DownloadRig(context.get(), request);
    v1::RigChunk chunk;
    while (reader->Read(&chunk)) {
      if (chunk.offset() == 0) {
        sha = chunk.sha256();
        size = chunk.size_bytes();
        bytes.reserve(size);
      }
      bytes += chunk.data();
    }
    return reader->Finish();
  });
  if (!status.ok()) return status_of(status, remote->server());
  if (bytes.size() != size || api::sha256_hex(bytes) != sha) {
    return data_loss_error("the rig arrived incomplete or altered (size or SHA-256 differ); try again");
  }
  return bytes;
}

}  // namespace

Result<api::Rig> RemotePoser::rig() const {
  POSEWARP_ASSIGN_OR_RETURN(const std::string bytes, download_rig(state_->remote, state_->rig_id));
  return api::rig_from_bytes(bytes, "rig " + state_->rig_id);
}

namespace {

// A joint of GetRig as the local `rig info --json` writes it: its range as [negative, positive] degrees, and whether
// bone stopped each way.
nlohmann::json joint_json(const v1::Joint& j) {
  nlohmann::json joint{{"name", j.name()},
                       {"parent", j.parent()},
                       {"child", j.child()},
                       {"kind", j.kind()},
                       {"centre_mm", j.centre_mm()},
                       {"method", j.method()},
                       {"placed_because", j.placed_because()}};
  for (const v1::MotionRange& m : j.ranges()) {
    joint["range_deg"][m.motion()] = {0.0 - m.negative_deg(), m.positive_deg()};
    joint["range_stopped_by_bone"][m.motion()] = {m.negative_stopped(), m.positive_stopped()};
  }
  return joint;
}

}  // namespace

int run_info_remote(const Connection& connection, const std::string& rig_id, bool as_json) {
  if (Status s = check_rig_id(rig_id); !s.ok()) return report(s);
  Result<Remote> remote = connect(connection);
  if (!remote.ok()) return report(remote.status());
  v1::GetRigRequest request;
  request.set_rig_id(rig_id);
  v1::Rig rig;
  if (grpc::Status s = (*remote)->unary(&v1::Posewarp::Stub::GetRig, request, &rig, rig_id); !s.ok()) {
    return report_rpc(s, connection.server);
  }
  if (as_json) {
    nlohmann::json out = {{"id", rig.id()},
                          {"name", rig.name()},
                          {"size_bytes", rig.size_bytes()},
                          {"created", rig.created()},
                          {"last_used", rig.last_used()},
                          {"tet_vertices", rig.tet_vertices()},
                          {"tets", rig.tets()},
                          {"has_ct", rig.has_ct()},
                          {"software_version", rig.software_version()},
                          {"segments", rig.segments()}};
    for (const v1::Joint& j : rig.joints()) out["joints"].push_back(joint_json(j));
    for (const v1::StageTime& t : rig.stage_seconds()) out["stage_seconds"][t.stage()] = t.seconds();
    std::printf("%s\n", out.dump(2).c_str());
    return 0;
  }
  std::printf("rig %s  %s\n", rig.id().c_str(), rig.name().c_str());
  std::printf("  %lld tet vertices, %lld tets, %.1f MB, CT %s, created %s, last used %s\n",
              static_cast<long long>(rig.tet_vertices()), static_cast<long long>(rig.tets()),
              static_cast<double>(rig.size_bytes()) / 1e6, rig.has_ct() ? "kept" : "none", rig.created().c_str(),
              rig.last_used().c_str());
  std::printf("  %d segments, %d joints:\n", rig.segments_size(), rig.joints_size());
  for (const v1::Joint& j : rig.joints()) {
    std::printf("    %-24s %-6s %s -> %s at (%.1f, %.1f, %.1f) mm\n", j.name().c_str(), j.kind().c_str(),
                j.parent().c_str(), j.child().c_str(), j.centre_mm(0), j.centre_mm(1), j.centre_mm(2));
    if (!j.placed_because().empty()) std::printf("      placed: %s\n", j.placed_because().c_str());
    if (const std::string line = joint_range_line(joint_json(j)); !line.empty()) std::printf("%s\n", line.c_str());
  }
  for (const v1::StageTime& t : rig.stage_seconds()) std::printf("  %-10s %8.2f s\n", t.stage().c_str(), t.seconds());
  return 0;
}

int run_delete_remote(const Connection& connection, const std::string& rig_id) {
  if (Status s = check_rig_id(rig_id); !s.ok()) return report(s);
  Result<Remote> remote = connect(connection);
  if (!remote.ok()) return report(remote.status());
  v1::GetRigRequest request;
  request.set_rig_id(rig_id);
  v1::DeleteRigResponse deleted;
  if (grpc::Status s = (*remote)->unary(&v1::Posewarp::Stub::DeleteRig, request, &deleted, rig_id); !s.ok()) {
    return report_rpc(s, connection.server);
  }
  say("deleted rig " + rig_id + " on " + connection.server);
  return 0;
}

int run_export_remote(const Connection& connection, const std::string& rig_id, const std::string& rig_out) {
  if (Status s = check_rig_id(rig_id); !s.ok()) return report(s);
  if (Status s = check_output_files({rig_out}); !s.ok()) return report(s);
  Result<Remote> remote = connect(connection);
  if (!remote.ok()) return report(remote.status());
  Result<std::string> bytes = download_rig(*remote, rig_id);
  if (!bytes.ok()) return report(bytes.status());
  if (Status s = api::write_file_atomically(rig_out, *bytes, "rig file"); !s.ok()) return report(s);
  say("wrote " + rig_out + " (" + std::to_string(bytes->size() >> 20) + " MB)");
  return 0;
}

int run_health_remote(const Connection& connection, double timeout_s) {
  Result<Remote> remote = connect(connection);
  if (!remote.ok()) return report(remote.status());
  // grpc.health.v1 through the generic stub: the request (service "", the whole server) is empty; the answer's
  // field 1 is the serving status (1 = SERVING).
  grpc::GenericStub stub((*remote)->channel());
  const auto context = (*remote)->context();
  context->set_deadline(std::chrono::system_clock::now() +
                        std::chrono::milliseconds(static_cast<int64_t>(timeout_s * 1000)));
  const grpc::Slice empty(std::string{});
  grpc::ByteBuffer request(&empty, 1), response;
  std::promise<grpc::Status> finished;
  stub.UnaryCall(context.get(), "/grpc.health.v1.Health/Check", grpc::StubOptions(), &request, &response,
                 [&finished](grpc::Status status) { finished.set_value(std::move(status)); });
  const grpc::Status status = finished.get_future().get();
  if (!status.ok()) return report(status_of(status, connection.server));
  std::vector<grpc::Slice> slices;
  std::string bytes;
  if (response.Dump(&slices).ok()) {
    for (const grpc::Slice& slice : slices) bytes.append(reinterpret_cast<const char*>(slice.begin()), slice.size());
  }
  const int serving = bytes.size() >= 2 && bytes[0] == 0x08 ? bytes[1] : 0;
  static const char* const kNames[] = {"UNKNOWN", "SERVING", "NOT_SERVING", "SERVICE_UNKNOWN"};
  std::printf("%s\n", kNames[serving >= 0 && serving <= 3 ? serving : 0]);
  return serving == 1 ? 0 : 1;
}

}  // namespace posewarp::cli
