// Remote commands over the generated gRPC client.
#include "remote.h"

#include <grpcpp/grpcpp.h>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <filesystem>
#include <memory>

#include "cli_support.h"
#include "posewarp/api/files.h"
#include "posewarp/v1/posewarp.grpc.pb.h"

#include <nlohmann/json.hpp>

namespace posewarp::cli {
namespace {

namespace fs = std::filesystem;

// A failed call as the local commands report it: the server's code is the core's, so the exit code table holds.
int report_rpc(const grpc::Status& status, const std::string& server) {
  if (status.error_code() == grpc::StatusCode::UNAVAILABLE) {
    return report(unavailable_error("cannot reach posewarp-server at " + server + ": " + status.error_message() +
                                    " (is it running, and is the address right?)"));
  }
  return report(Status(static_cast<StatusCode>(status.error_code()), status.error_message()));
}

// The channel and what every call carries: the bearer token, and the rig id (so a load balancer can keep each rig
// on one replica).
class Remote {
 public:
  static Result<Remote> open(const Connection& c) {
    Remote remote;
    remote.server_ = c.server;
    std::shared_ptr<grpc::ChannelCredentials> credentials = grpc::InsecureChannelCredentials();
    if (!c.tls_ca.empty()) {
      grpc::SslCredentialsOptions ssl;
      POSEWARP_ASSIGN_OR_RETURN(ssl.pem_root_certs, api::read_text_input(c.tls_ca, "TLS CA certificate"));
      credentials = grpc::SslCredentials(ssl);
    }
    if (!c.token_file.empty()) {
      POSEWARP_ASSIGN_OR_RETURN(std::string token, api::read_text_input(c.token_file, "token file", 1 << 16));
      const size_t first = token.find_first_not_of(" \t\r\n");
      const size_t last = token.find_last_not_of(" \t\r\n");
      if (first == std::string::npos) return invalid_argument_error("token file '" + c.token_file + "' is empty");
      remote.token_ = token.substr(first, last - first + 1);
    }
    grpc::ChannelArguments arguments;
    arguments.SetMaxReceiveMessageSize(64 << 20);
    remote.stub_ = v1::Posewarp::NewStub(grpc::CreateCustomChannel(c.server, credentials, arguments));
    return remote;
  }
  v1::Posewarp::Stub* operator->() const { return stub_.get(); }
  v1::Posewarp::Stub& operator*() const { return *stub_; }
  const std::string& server() const { return server_; }
  // A call's context with the token and the rig id.
  std::unique_ptr<grpc::ClientContext> context(const std::string& rig_id = "") const {
    auto context = std::make_unique<grpc::ClientContext>();
    if (!token_.empty()) context->AddMetadata("authorization", "Bearer " + token_);
    if (!rig_id.empty()) context->AddMetadata("x-posewarp-rig", rig_id);
    return context;
  }

 private:
  std::string server_, token_;
  std::unique_ptr<v1::Posewarp::Stub> stub_;
};

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

Result<std::string> upload(const Remote& stub, const std::string& path, v1::VolumeKind kind) {
  const std::string& server = stub.server();
  const v1::FileFormat format = format_of(path);
  if (format == v1::FILE_FORMAT_UNSPECIFIED) {
    return invalid_argument_error("'" + path + "': the server takes .nii.gz, .nii, .nrrd or .mha files (convert "
                                  "others with `posewarp convert`)");
  }
  POSEWARP_ASSIGN_OR_RETURN(const std::string bytes, api::read_text_input(path, "volume", int64_t{8} << 30));
  const auto context = stub.context();
  v1::Volume volume;
  auto writer = stub->UploadVolume(context.get(), &volume);
  v1::UploadVolumeRequest part;
  part.mutable_header()->set_kind(kind);
  part.mutable_header()->set_format(format);
  part.mutable_header()->set_size_bytes(bytes.size());
  part.mutable_header()->set_sha256(api::sha256_hex(bytes));
  bool open = writer->Write(part);
  for (size_t offset = 0; open && offset < bytes.size(); offset += size_t{1} << 20) {
    v1::UploadVolumeRequest chunk;
    chunk.set_chunk(bytes.substr(offset, size_t{1} << 20));
    open = writer->Write(chunk);
  }
  writer->WritesDone();
  const grpc::Status status = writer->Finish();
  if (!status.ok()) {
    if (status.error_code() == grpc::StatusCode::UNAVAILABLE) {
      return unavailable_error("cannot reach posewarp-server at " + server + ": " + status.error_message());
    }
    return Status(static_cast<StatusCode>(status.error_code()), "'" + path + "': " + status.error_message());
  }
  say("uploaded " + path + " as volume " + volume.id().substr(0, 12));
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

int run_build_remote(const RemoteBuild& o) {
  Result<Remote> remote = Remote::open(o.connection);
  if (!remote.ok()) return report(remote.status());
  const Remote& stub = *remote;
  const std::string& server = o.connection.server;
  v1::BuildRigRequest request;
  Result<std::string> labels = upload(stub, o.labels_path, v1::VOLUME_KIND_LABELS);
  if (!labels.ok()) return report(labels.status());
  request.set_labels_volume_id(*labels);
  if (!o.ct_path.empty()) {
    Result<std::string> ct = upload(stub, o.ct_path, v1::VOLUME_KIND_INTENSITY);
    if (!ct.ok()) return report(ct.status());
    request.set_ct_volume_id(*ct);
  }
  if (!o.label_map_path.empty()) {
    Result<std::string> map = api::read_text_input(o.label_map_path, "label map");
    if (!map.ok()) return report(map.status());
    request.set_label_map_json(*map);
  }
  request.set_preset(o.preset);
  if (!o.spec_path.empty()) {
    Result<std::string> spec = api::read_text_input(o.spec_path, "rig spec");
    if (!spec.ok()) return report(spec.status());
    request.set_rig_spec_json(*spec);
  }
  request.set_name(o.name.empty() ? fs::path(o.labels_path).filename().string() : o.name);
  v1::Operation operation;
  {
    const auto context = stub.context();
    if (grpc::Status s = stub->BuildRig(context.get(), request, &operation); !s.ok()) return report_rpc(s, server);
  }
  // Progress as the local build shows it, from the operation's stream.
  const ProgressHooks bar = progress_bar();
  const auto context = stub.context();
  v1::GetOperationRequest watch;
  watch.set_operation_id(operation.id());
  auto reader = stub->WatchOperation(context.get(), watch);
  v1::Operation state;
  while (reader->Read(&state)) {
    operation = state;
    if (bar.on_progress && !state.stage().empty()) bar.on_progress(state.stage(), state.stage_fraction());
  }
  if (grpc::Status s = reader->Finish(); !s.ok()) return report_rpc(s, server);
  if (operation.state() != v1::Operation::SUCCEEDED) {
    return report(Status(static_cast<StatusCode>(operation.error_code() == 0 ? 2 : operation.error_code()),
                         "the build failed on the server: " + operation.error_message()));
  }
  say("rig " + operation.rig_id() + " built on " + server + " in " + std::to_string(operation.elapsed_s()) + " s");
  std::printf("%s\n", operation.rig_id().c_str());
  return 0;
}

int run_list_remote(const Connection& connection) {
  Result<Remote> remote = Remote::open(connection);
  if (!remote.ok()) return report(remote.status());
  const std::string& server = connection.server;
  v1::ListRigsRequest request;
  request.set_page_size(1000);
  for (;;) {
    const auto context = remote->context();
    v1::ListRigsResponse page;
    if (grpc::Status s = (*remote)->ListRigs(context.get(), request, &page); !s.ok()) return report_rpc(s, server);
    for (const v1::Rig& rig : page.rigs()) {
      std::printf("%s  %-24s %10.1f MB  %s\n", rig.id().c_str(), rig.name().c_str(),
                  static_cast<double>(rig.size_bytes()) / 1e6, rig.created().c_str());
    }
    if (page.next_page_token().empty()) return 0;
    request.set_page_token(page.next_page_token());
  }
}

int run_pose_remote(const RemotePose& o) {
  if (!api::is_hex_id(o.rig_id)) {
    return report(invalid_argument_error("with --server the rig is a rig id (64 hex digits, from `posewarp rig build "
                                         "--server` or `posewarp rig list --server`), not '" + o.rig_id + "'"));
  }
  if (Status s = refuse_overwriting_inputs({o.labels_out, o.ct_out, o.report_out}, {o.pose_path}); !s.ok()) {
    return report(s);
  }
  if (Status s = check_output_files({o.labels_out, o.ct_out, o.report_out}); !s.ok()) return report(s);
  Result<std::string> pose = api::read_text_input(o.pose_path, "pose");
  if (!pose.ok()) return report(pose.status());
  if (Result<pose::Pose> parsed = api::pose_from_json(*pose, "'" + o.pose_path + "'"); !parsed.ok()) {
    return report(parsed.status());
  }
  v1::PoseRequest request;
  request.set_rig_id(o.rig_id);
  request.set_pose_json(*pose);
  request.set_method(o.method == "dqs" ? v1::METHOD_DQS : o.method == "lbs" ? v1::METHOD_LBS : v1::METHOD_COR);
  request.set_grid(o.grid == "grow" ? v1::GRID_POLICY_GROW : v1::GRID_POLICY_INPUT);
  request.set_want_labels(!o.labels_out.empty() || !o.report_out.empty());
  request.set_want_ct(!o.ct_out.empty());
  request.set_want_surfaces(!o.surfaces_out.empty());
  request.set_max_output_bytes(static_cast<uint64_t>(o.max_output_mb) << 20);
  Result<Remote> remote = Remote::open(o.connection);
  if (!remote.ok()) return report(remote.status());
  const auto context = remote->context(o.rig_id);
  auto reader = (*remote)->Pose(context.get(), request);
  v1::PoseResponse part;
  ImageGeometry grid;
  v1::PoseHeader header;
  std::string labels, ct, report_json;
  std::vector<surface::SurfaceMesh> surfaces;
  while (reader->Read(&part)) {
    if (part.has_header()) {
      header = part.header();
      grid = grid_of(header.grid());
      labels.reserve(header.label_bytes());
      ct.reserve(header.ct_bytes());
    } else if (part.has_labels()) {
      labels += part.labels().data();
    } else if (part.has_ct()) {
      ct += part.ct().data();
    } else if (part.has_surface()) {
      const v1::Surface& s = part.surface();
      surface::SurfaceMesh mesh;
      mesh.name = s.name();
      mesh.label = s.label();
      mesh.vertices.resize(s.vertices_size() / 3, 3);
      for (int i = 0; i < s.vertices_size(); ++i) mesh.vertices(i / 3, i % 3) = s.vertices(i);
      mesh.triangles.resize(s.triangles_size() / 3, 3);
      for (int i = 0; i < s.triangles_size(); ++i) mesh.triangles(i / 3, i % 3) = s.triangles(i);
      surfaces.push_back(std::move(mesh));
    } else if (part.has_report()) {
      report_json = part.report().json();
      for (const std::string& warning : part.report().warnings()) say("warning: " + warning);
    }
  }
  if (grpc::Status s = reader->Finish(); !s.ok()) return report_rpc(s, o.connection.server);
  if (labels.size() != header.label_bytes() || ct.size() != header.ct_bytes()) {
    return report(data_loss_error("the server's answer ended early (labels " + std::to_string(labels.size()) + " of " +
                                  std::to_string(header.label_bytes()) + " bytes); run the pose again"));
  }
  if (!o.labels_out.empty()) {
    Result<LabelVolume> volume = volume_from_samples<Label>(labels, header.label_sample_type(), grid,
                                                            header.label_pixel_type());
    if (!volume.ok()) return report(volume.status());
    if (Status s = api::write_volume(*volume, o.labels_out); !s.ok()) return report(s);
    say("wrote " + o.labels_out);
  }
  if (!o.ct_out.empty() && !ct.empty()) {
    Result<IntensityVolume> volume = volume_from_samples<float>(ct, header.ct_sample_type(), grid,
                                                                header.ct_pixel_type());
    if (!volume.ok()) return report(volume.status());
    if (Status s = api::write_volume(*volume, o.ct_out); !s.ok()) return report(s);
    say("wrote " + o.ct_out);
  }
  if (!o.report_out.empty()) {
    if (Status s = api::write_file_atomically(o.report_out, report_json, "report"); !s.ok()) return report(s);
    say("wrote " + o.report_out);
  }
  if (!o.surfaces_out.empty()) {
    std::error_code ec;
    fs::create_directories(o.surfaces_out, ec);
    for (const surface::SurfaceMesh& s : surfaces) {
      if (Status w = api::write_surface(s, (fs::path(o.surfaces_out) / (s.name + "." + o.surface_format)).string());
          !w.ok()) {
        return report(w);
      }
    }
    say("wrote " + std::to_string(surfaces.size()) + " surfaces to " + o.surfaces_out);
  }
  return 0;
}

namespace {

Status check_rig_id(const std::string& rig_id) {
  if (api::is_hex_id(rig_id)) return ok_status();
  return invalid_argument_error("with --server the rig is a rig id (64 hex digits, from `posewarp rig list --server`), "
                                "not '" + rig_id + "'");
}

}  // namespace

int run_info_remote(const Connection& connection, const std::string& rig_id, bool as_json) {
  if (Status s = check_rig_id(rig_id); !s.ok()) return report(s);
  Result<Remote> remote = Remote::open(connection);
  if (!remote.ok()) return report(remote.status());
  v1::GetRigRequest request;
  request.set_rig_id(rig_id);
  v1::Rig rig;
  const auto context = remote->context(rig_id);
  if (grpc::Status s = (*remote)->GetRig(context.get(), request, &rig); !s.ok()) return report_rpc(s, connection.server);
  if (as_json) {
    nlohmann::json out = {{"id", rig.id()}, {"name", rig.name()}, {"size_bytes", rig.size_bytes()},
                          {"created", rig.created()}, {"last_used", rig.last_used()},
                          {"tet_vertices", rig.tet_vertices()}, {"tets", rig.tets()}, {"has_ct", rig.has_ct()},
                          {"software_version", rig.software_version()}, {"segments", rig.segments()}};
    for (const v1::Joint& j : rig.joints()) {
      out["joints"].push_back({{"name", j.name()}, {"parent", j.parent()}, {"child", j.child()}, {"kind", j.kind()},
                               {"centre_mm", j.centre_mm()}});
    }
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
  }
  for (const v1::StageTime& t : rig.stage_seconds()) std::printf("  %-10s %8.2f s\n", t.stage().c_str(), t.seconds());
  return 0;
}

int run_delete_remote(const Connection& connection, const std::string& rig_id) {
  if (Status s = check_rig_id(rig_id); !s.ok()) return report(s);
  Result<Remote> remote = Remote::open(connection);
  if (!remote.ok()) return report(remote.status());
  v1::GetRigRequest request;
  request.set_rig_id(rig_id);
  v1::DeleteRigResponse deleted;
  const auto context = remote->context(rig_id);
  if (grpc::Status s = (*remote)->DeleteRig(context.get(), request, &deleted); !s.ok()) {
    return report_rpc(s, connection.server);
  }
  say("deleted rig " + rig_id + " on " + connection.server);
  return 0;
}

int run_export_remote(const Connection& connection, const std::string& rig_id, const std::string& rig_out) {
  if (Status s = check_rig_id(rig_id); !s.ok()) return report(s);
  if (Status s = check_output_files({rig_out}); !s.ok()) return report(s);
  Result<Remote> remote = Remote::open(connection);
  if (!remote.ok()) return report(remote.status());
  v1::GetRigRequest request;
  request.set_rig_id(rig_id);
  const auto context = remote->context(rig_id);
  auto reader = (*remote)->DownloadRig(context.get(), request);
  v1::RigChunk chunk;
  std::string bytes, sha;
  uint64_t size = 0;
  while (reader->Read(&chunk)) {
    if (chunk.offset() == 0) {
      sha = chunk.sha256();
      size = chunk.size_bytes();
      bytes.reserve(size);
    }
    bytes += chunk.data();
  }
  if (grpc::Status s = reader->Finish(); !s.ok()) return report_rpc(s, connection.server);
  if (bytes.size() != size || api::sha256_hex(bytes) != sha) {
    return report(data_loss_error("the rig arrived incomplete or altered (size or SHA-256 differ); run the export "
                                  "again"));
  }
  if (Status s = api::write_file_atomically(rig_out, bytes, "rig file"); !s.ok()) return report(s);
  say("wrote " + rig_out + " (" + std::to_string(bytes.size() >> 20) + " MB)");
  return 0;
}

}  // namespace posewarp::cli
