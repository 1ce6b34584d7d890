// PosewarpService: proto <-> core conversion, the build queue, pose slots and the engine cache.
#include "service.h"

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <optional>
#include <thread>
#include <utility>

#include <nlohmann/json.hpp>

#include "posewarp/api/files.h"
#include "posewarp/api/rig_file.h"

namespace posewarp::server {
namespace {

namespace fs = std::filesystem;

void put_grid(const ImageGeometry& g, v1::Grid* grid) {
  for (int a = 0; a < 3; ++a) {
    grid->add_size(g.size[static_cast<size_t>(a)]);
    grid->add_spacing(g.spacing[static_cast<size_t>(a)]);
    grid->add_origin(g.origin[static_cast<size_t>(a)]);
  }
  for (int e = 0; e < 9; ++e) grid->add_direction(g.direction[static_cast<size_t>(e)]);
}

const char* extension_of(v1::FileFormat format) {
  switch (format) {
    case v1::FILE_FORMAT_NIFTI_GZ: return ".nii.gz";
    case v1::FILE_FORMAT_NIFTI: return ".nii";
    case v1::FILE_FORMAT_NRRD: return ".nrrd";
    case v1::FILE_FORMAT_MHA: return ".mha";
    default: return nullptr;
  }
}

skinning::Method method_of(v1::Method method) {
  switch (method) {
    case v1::METHOD_DQS: return skinning::Method::kDqs;
    case v1::METHOD_LBS: return skinning::Method::kLbs;
    default: return skinning::Method::kCor;
  }
}

// Streams `bytes` as chunks of at most `chunk` bytes through `put`.
template <typename Put>
bool stream_chunks(const char* data, uint64_t size, uint64_t chunk, Put&& put) {
  for (uint64_t offset = 0; offset < size; offset += chunk) {
    if (!put(offset, std::string(data + offset, std::min(chunk, size - offset)))) return false;
  }
  return true;
}

}  // namespace

PosewarpService::PosewarpService(RigStore store, ServiceOptions options)
    : store_(std::move(store)), options_(options), build_thread_([this] { build_worker(); }) {}

PosewarpService::~PosewarpService() { shutdown(); }

void PosewarpService::shutdown() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (stopping_) return;
    stopping_ = true;
    for (auto& [id, job] : operations_) {
      job->cancel.cancel();
      if (job->operation.state() == v1::Operation::QUEUED) {
        job->operation.set_state(v1::Operation::CANCELLED);
        job->operation.set_error_message("the server stopped before the build started");
      }
    }
    build_queue_.clear();
  }
  changed_.notify_all();
  if (build_thread_.joinable()) build_thread_.join();
}

// The core's codes are gRPC's. Messages name store files by id only: no server path reaches a client.
grpc::Status PosewarpService::to_grpc(const Status& status) const {
  if (status.ok()) return grpc::Status::OK;
  std::string message = status.message();
  for (const char* sub : {"/volumes/", "/rigs/"}) {
    const std::string prefix = store_.directory() + sub;
    for (size_t at = message.find(prefix); at != std::string::npos; at = message.find(prefix)) {
      message.replace(at, prefix.size(), std::strcmp(sub, "/rigs/") == 0 ? "rig " : "volume ");
    }
  }
  return {static_cast<grpc::StatusCode>(status.code()), message};
}

grpc::Status PosewarpService::UploadVolume(grpc::ServerContext* context,
                                           grpc::ServerReader<v1::UploadVolumeRequest>* reader, v1::Volume* response) {
  v1::UploadVolumeRequest part;
  if (!reader->Read(&part) || !part.has_header()) {
    return {grpc::StatusCode::INVALID_ARGUMENT, "an upload starts with its header (kind, format, size, sha256)"};
  }
  const v1::UploadVolumeHeader header = part.header();
  const char* extension = extension_of(header.format());
  if (extension == nullptr) {
    return {grpc::StatusCode::INVALID_ARGUMENT, "upload format must be NIFTI_GZ, NIFTI, NRRD or MHA"};
  }
  if (header.kind() != v1::VOLUME_KIND_LABELS && header.kind() != v1::VOLUME_KIND_INTENSITY) {
    return {grpc::StatusCode::INVALID_ARGUMENT, "upload kind must be LABELS or INTENSITY"};
  }
  if (!api::is_hex_id(header.sha256())) {
    return {grpc::StatusCode::INVALID_ARGUMENT, "upload sha256 must be 64 lowercase hex digits"};
  }
  if (header.size_bytes() == 0 || header.size_bytes() > static_cast<uint64_t>(options_.max_upload_bytes)) {
    return {grpc::StatusCode::RESOURCE_EXHAUSTED,
            "upload size must be 1 to " + std::to_string(options_.max_upload_bytes) + " bytes (the server's limit)"};
  }
  std::string bytes;
  bytes.reserve(header.size_bytes());
  api::Sha256 hash;
  while (reader->Read(&part)) {
    if (context->IsCancelled()) return {grpc::StatusCode::CANCELLED, "the client cancelled the upload"};
    if (part.part_case() != v1::UploadVolumeRequest::kChunk) {
      return {grpc::StatusCode::INVALID_ARGUMENT, "an upload has one header, then chunks"};
    }
    if (bytes.size() + part.chunk().size() > header.size_bytes()) {
      return {grpc::StatusCode::INVALID_ARGUMENT, "the upload sent more bytes than its header's size_bytes"};
    }
    hash.update(part.chunk());
    bytes += part.chunk();
  }
  if (bytes.size() != header.size_bytes()) {
    return {grpc::StatusCode::DATA_LOSS, "the upload ended after " + std::to_string(bytes.size()) + " of " +
                                             std::to_string(header.size_bytes()) + " bytes; send it again"};
  }
  if (hash.hex_digest() != header.sha256()) {
    return {grpc::StatusCode::DATA_LOSS, "the upload's bytes do not match its sha256; send it again"};
  }
  // The volume is read as posing will read it before it gets its name in the store.
  const std::string kind = header.kind() == v1::VOLUME_KIND_LABELS ? "labels" : "intensity";
  const fs::path staging = fs::path(store_.directory()) / "volumes" / (".staging-" + header.sha256() + extension);
  if (Status s = api::write_file_atomically(staging.string(), bytes, "upload"); !s.ok()) return to_grpc(s);
  Result<ImageGeometry> grid = [&]() -> Result<ImageGeometry> {
    if (kind == "labels") {
      POSEWARP_ASSIGN_OR_RETURN(const LabelVolume labels, api::read_label_volume(staging.string()));
      return labels.geometry();
    }
    POSEWARP_ASSIGN_OR_RETURN(const IntensityVolume ct, api::read_intensity_volume(staging.string()));
    return ct.geometry();
  }();
  std::error_code ec;
  fs::remove(staging, ec);
  if (!grid.ok()) {
    std::string message = grid.status().message();
    for (size_t at = message.find(staging.string()); at != std::string::npos; at = message.find(staging.string())) {
      message.replace(at, staging.string().size(), "uploaded volume");
    }
    return {static_cast<grpc::StatusCode>(grid.status().code()), message};
  }
  Result<StoredVolume> stored = store_.put_volume(header.sha256(), extension, kind, bytes);
  if (!stored.ok()) return to_grpc(stored.status());
  response->set_id(stored->id);
  response->set_kind(header.kind());
  put_grid(*grid, response->mutable_grid());
  response->set_size_bytes(stored->size_bytes);
  return grpc::Status::OK;
}

grpc::Status PosewarpService::BuildRig(grpc::ServerContext*, const v1::BuildRigRequest* request,
                                       v1::Operation* response) {
  if (!api::is_hex_id(request->labels_volume_id()) ||
      (!request->ct_volume_id().empty() && !api::is_hex_id(request->ct_volume_id()))) {
    return {grpc::StatusCode::INVALID_ARGUMENT, "volume ids are 64 lowercase hex digits (from UploadVolume)"};
  }
  if (Result<StoredVolume> v = store_.volume(request->labels_volume_id()); !v.ok()) return to_grpc(v.status());
  if (!request->ct_volume_id().empty()) {
    if (Result<StoredVolume> v = store_.volume(request->ct_volume_id()); !v.ok()) return to_grpc(v.status());
  }
  auto job = std::make_shared<Job>();
  job->request = *request;
  job->operation.set_id(api::sha256_hex(request->SerializeAsString() +
                                   std::to_string(std::chrono::steady_clock::now().time_since_epoch().count()))
                            .substr(0, 32));
  job->operation.set_state(v1::Operation::QUEUED);
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (stopping_) return {grpc::StatusCode::UNAVAILABLE, "the server is shutting down; try another replica"};
    if (static_cast<int>(build_queue_.size()) >= options_.build_queue) {
      return {grpc::StatusCode::RESOURCE_EXHAUSTED,
              "the build queue is full (" + std::to_string(options_.build_queue) + " waiting); try again later"};
    }
    operations_[job->operation.id()] = job;
    build_queue_.push_back(job);
    *response = job->operation;
  }
  changed_.notify_all();
  return grpc::Status::OK;
}

void PosewarpService::build_worker() {
  for (;;) {
    std::shared_ptr<Job> job;
    {
      std::unique_lock<std::mutex> lock(mutex_);
      changed_.wait(lock, [this] { return stopping_ || !build_queue_.empty(); });
      if (stopping_) return;
      job = build_queue_.front();
      build_queue_.pop_front();
      job->operation.set_state(v1::Operation::RUNNING);
      job->started = std::chrono::steady_clock::now();
    }
    changed_.notify_all();
    run_build(job);
  }
}

void PosewarpService::set_operation(const std::shared_ptr<Job>& job,
                                    const std::function<void(v1::Operation&)>& change) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    change(job->operation);
    job->operation.set_elapsed_s(std::chrono::duration<double>(std::chrono::steady_clock::now() - job->started).count());
  }
  changed_.notify_all();
}

void PosewarpService::run_build(const std::shared_ptr<Job>& job) {
  auto fail = [&](const Status& status) {
    const grpc::Status g = to_grpc(status);
    set_operation(job, [&](v1::Operation& op) {
      op.set_state(status.code() == StatusCode::kCancelled ? v1::Operation::CANCELLED : v1::Operation::FAILED);
      op.set_error_code(static_cast<int32_t>(g.error_code()));
      op.set_error_message(g.error_message());
    });
  };
  const v1::BuildRigRequest& request = job->request;
  api::BuildInputs inputs;
  {
    Result<StoredVolume> labels = store_.volume(request.labels_volume_id());
    if (!labels.ok()) return fail(labels.status());
    Result<LabelVolume> volume = api::read_label_volume(labels->path);
    if (!volume.ok()) return fail(volume.status());
    inputs.labels = std::move(volume).value();
  }
  if (!request.ct_volume_id().empty()) {
    Result<StoredVolume> ct = store_.volume(request.ct_volume_id());
    if (!ct.ok()) return fail(ct.status());
    Result<IntensityVolume> volume = api::read_intensity_volume(ct->path);
    if (!volume.ok()) return fail(volume.status());
    inputs.ct = std::move(volume).value();
  }
  Result<labels::LabelMap> map = request.label_map_json().empty()
                                     ? api::preset_by_name(request.preset().empty() ? "totalsegmentator"
                                                                                        : request.preset())
                                     : api::label_map_from_json(request.label_map_json(), "in the request");
  if (!map.ok()) return fail(map.status());
  inputs.label_map = std::move(map).value();
  if (!request.rig_spec_json().empty()) {
    Result<rig::RigSpec> spec = api::rig_spec_from_json(request.rig_spec_json(), "in the request");
    if (!spec.ok()) return fail(spec.status());
    inputs.spec = std::move(spec).value();
  }
  inputs.labels_source = "volume " + request.labels_volume_id();
  const api::BuildParams params;
  const std::string id = api::rig_id_of(inputs, params);
  if (store_.rig(id).ok()) {  // built before from the same inputs
    return set_operation(job, [&](v1::Operation& op) {
      op.set_state(v1::Operation::SUCCEEDED);
      op.set_rig_id(id);
    });
  }
  ProgressHooks hooks;
  hooks.threads = options_.build_threads;
  hooks.cancel_requested = job->cancel.as_hook();
  hooks.on_progress = [&](std::string_view stage, double fraction) {
    set_operation(job, [&](v1::Operation& op) {
      op.set_stage(std::string(stage));
      op.set_stage_fraction(fraction);
    });
  };
  Result<api::Rig> rig = api::build_rig(inputs, params, hooks);
  if (!rig.ok()) return fail(rig.status());
  if (Status s = store_.put_rig(rig->id(), request.name(), api::rig_to_bytes(*rig)); !s.ok()) return fail(s);
  set_operation(job, [&](v1::Operation& op) {
    op.set_state(v1::Operation::SUCCEEDED);
    op.set_rig_id(rig->id());
  });
}

grpc::Status PosewarpService::GetOperation(grpc::ServerContext*, const v1::GetOperationRequest* request,
                                           v1::Operation* response) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = operations_.find(request->operation_id());
  if (it == operations_.end()) return {grpc::StatusCode::NOT_FOUND, "no such operation on this server"};
  *response = it->second->operation;
  return grpc::Status::OK;
}

grpc::Status PosewarpService::WatchOperation(grpc::ServerContext* context, const v1::GetOperationRequest* request,
                                             grpc::ServerWriter<v1::Operation>* writer) {
  std::unique_lock<std::mutex> lock(mutex_);
  const auto it = operations_.find(request->operation_id());
  if (it == operations_.end()) return {grpc::StatusCode::NOT_FOUND, "no such operation on this server"};
  const std::shared_ptr<Job> job = it->second;
  std::string last;
  for (;;) {
    const v1::Operation now = job->operation;
    const std::string serialized = now.SerializeAsString();
    const bool final = now.state() == v1::Operation::SUCCEEDED || now.state() == v1::Operation::FAILED ||
                       now.state() == v1::Operation::CANCELLED;
    if (serialized != last) {
      last = serialized;
      lock.unlock();
      const bool written = writer->Write(now);
      lock.lock();
      if (!written) return {grpc::StatusCode::CANCELLED, "the client went away"};
    }
    if (final) return grpc::Status::OK;
    if (context->IsCancelled()) return {grpc::StatusCode::CANCELLED, "the client cancelled the watch"};
    changed_.wait_for(lock, std::chrono::milliseconds(200));
  }
}

grpc::Status PosewarpService::CancelOperation(grpc::ServerContext*, const v1::GetOperationRequest* request,
                                              v1::Operation* response) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = operations_.find(request->operation_id());
  if (it == operations_.end()) return {grpc::StatusCode::NOT_FOUND, "no such operation on this server"};
  const std::shared_ptr<Job>& job = it->second;
  job->cancel.cancel();
  if (job->operation.state() == v1::Operation::QUEUED) {
    build_queue_.erase(std::remove(build_queue_.begin(), build_queue_.end(), job), build_queue_.end());
    job->operation.set_state(v1::Operation::CANCELLED);
  }
  *response = job->operation;
  changed_.notify_all();
  return grpc::Status::OK;
}

grpc::Status PosewarpService::GetRig(grpc::ServerContext*, const v1::GetRigRequest* request, v1::Rig* response) {
  Result<StoredRig> stored = store_.rig(request->rig_id());
  if (!stored.ok()) return to_grpc(stored.status());
  Result<std::shared_ptr<const api::PoseEngine>> engine = this->engine(request->rig_id());
  if (!engine.ok()) return to_grpc(engine.status());
  const api::Rig& rig = (*engine)->rig();
  response->set_id(stored->id);
  response->set_name(stored->name);
  response->set_size_bytes(stored->size_bytes);
  response->set_created(stored->created);
  put_grid(rig.source_geometry, response->mutable_grid());
  for (const rig::Segment& s : rig.skeleton.segments) response->add_segments(s.name);
  for (const rig::Joint& j : rig.skeleton.joints) {
    v1::Joint* joint = response->add_joints();
    joint->set_name(j.name);
    joint->set_parent(rig.skeleton.segments[static_cast<size_t>(j.parent)].name);
    joint->set_child(rig.skeleton.segments[static_cast<size_t>(j.child)].name);
    for (int a = 0; a < 3; ++a) joint->add_centre_mm(j.centre_mm[a]);
    joint->set_kind(std::string(api::joint_kind_name(j.kind)));
    for (int a = 0; a < 3; ++a) {
      joint->add_flexion_axis(j.frame(a, 0));
      joint->add_abduction_axis(j.frame(a, 1));
      joint->add_rotation_axis(j.frame(a, 2));
    }
  }
  response->set_tet_vertices(rig.mesh.vertex_count());
  response->set_tets(rig.mesh.tet_count());
  return grpc::Status::OK;
}

grpc::Status PosewarpService::ListRigs(grpc::ServerContext*, const v1::ListRigsRequest* request,
                                       v1::ListRigsResponse* response) {
  const int page = request->page_size() <= 0 ? 50 : std::min(request->page_size(), 1000);
  for (const StoredRig& r : store_.rigs()) {
    if (!request->page_token().empty() && r.id <= request->page_token()) continue;
    if (response->rigs_size() == page) {
      response->set_next_page_token(response->rigs(page - 1).id());
      break;
    }
    v1::Rig* rig = response->add_rigs();
    rig->set_id(r.id);
    rig->set_name(r.name);
    rig->set_size_bytes(r.size_bytes);
    rig->set_created(r.created);
  }
  return grpc::Status::OK;
}

Result<std::shared_ptr<const api::PoseEngine>> PosewarpService::engine(const std::string& rig_id) {
  std::promise<std::shared_ptr<EngineResult>> loading;
  std::shared_future<std::shared_ptr<EngineResult>> waiting;
  {
    std::lock_guard<std::mutex> lock(cache_mutex_);
    const auto it = cache_.find(rig_id);
    if (it != cache_.end()) {
      it->second.last_used = std::chrono::steady_clock::now();
      waiting = it->second.engine;
    } else {
      // This caller loads; the ones arriving meanwhile wait for the same future (a cold rig is loaded once).
      cache_[rig_id] = {loading.get_future().share(), 0, std::chrono::steady_clock::now()};
    }
  }
  if (waiting.valid()) return *waiting.get();
  auto result = std::make_shared<EngineResult>([&]() -> EngineResult {
    POSEWARP_ASSIGN_OR_RETURN(const StoredRig stored, store_.rig(rig_id));
    POSEWARP_ASSIGN_OR_RETURN(api::Rig rig, api::load_rig(stored.path));
    ProgressHooks hooks;
    hooks.threads = options_.pose_threads;
    POSEWARP_ASSIGN_OR_RETURN(api::PoseEngine engine, api::PoseEngine::create(std::move(rig), hooks));
    return std::make_shared<const api::PoseEngine>(std::move(engine));
  }());
  loading.set_value(result);
  std::lock_guard<std::mutex> lock(cache_mutex_);
  if (!result->ok()) {
    cache_.erase(rig_id);  // a failure is not cached: the next request tries again
    return *result;
  }
  cache_[rig_id].bytes = (**result)->rig().footprint_bytes();
  // Least recently used engines leave until the cache is within its budget (the one just loaded stays).
  for (;;) {
    int64_t total = 0;
    auto oldest = cache_.end();
    for (auto it = cache_.begin(); it != cache_.end(); ++it) {
      total += it->second.bytes;
      if (it->first != rig_id && it->second.bytes > 0 &&
          (oldest == cache_.end() || it->second.last_used < oldest->second.last_used)) {
        oldest = it;
      }
    }
    if (total <= options_.cache_bytes || oldest == cache_.end()) break;
    cache_.erase(oldest);
  }
  return *result;
}

grpc::Status PosewarpService::Pose(grpc::ServerContext* context, const v1::PoseRequest* request,
                                   grpc::ServerWriter<v1::PoseResponse>* writer) {
  if (!api::is_hex_id(request->rig_id())) return {grpc::StatusCode::INVALID_ARGUMENT, "a rig id is 64 lowercase hex digits"};
  Result<pose::Pose> pose = api::pose_from_json(request->pose_json(), "in the request");
  if (!pose.ok()) return to_grpc(pose.status());
  // A slot, or a place in the bounded queue, or RESOURCE_EXHAUSTED at once.
  {
    std::unique_lock<std::mutex> lock(mutex_);
    if (stopping_) return {grpc::StatusCode::UNAVAILABLE, "the server is shutting down; try another replica"};
    if (poses_running_ >= options_.pose_slots && poses_waiting_ >= options_.pose_queue) {
      return {grpc::StatusCode::RESOURCE_EXHAUSTED, "the server is busy (" + std::to_string(options_.pose_queue) +
                                                        " poses waiting); try again later"};
    }
    ++poses_waiting_;
    changed_.wait(lock, [&] { return poses_running_ < options_.pose_slots || context->IsCancelled(); });
    --poses_waiting_;
    if (context->IsCancelled()) return {grpc::StatusCode::CANCELLED, "the client cancelled the pose"};
    ++poses_running_;
  }
  struct Slot {
    PosewarpService* service;
    ~Slot() {
      {
        std::lock_guard<std::mutex> lock(service->mutex_);
        --service->poses_running_;
      }
      service->changed_.notify_all();
    }
  } slot{this};

  Result<std::shared_ptr<const api::PoseEngine>> engine = this->engine(request->rig_id());
  if (!engine.ok()) return to_grpc(engine.status());
  api::PoseRequest core;
  core.pose = std::move(pose).value();
  core.method = method_of(request->method());
  core.grid = request->grid() == v1::GRID_POLICY_GROW ? resample::GridPolicy::kGrow : resample::GridPolicy::kInput;
  core.want_labels = request->want_labels();
  core.want_ct = request->want_ct() && (*engine)->rig().ct.has_value();
  core.want_surfaces = request->want_surfaces();
  core.resample.max_output_bytes =
      request->max_output_bytes() > 0 ? static_cast<int64_t>(request->max_output_bytes()) : options_.max_output_bytes;
  if (Result<api::PosePlan> plan = (*engine)->plan(core); !plan.ok()) return to_grpc(plan.status());
  ProgressHooks hooks;
  hooks.threads = options_.pose_threads;
  hooks.cancel_requested = [context] { return context->IsCancelled(); };
  if (context->deadline() != std::chrono::system_clock::time_point::max()) {
    hooks.deadline = std::chrono::steady_clock::now() + (context->deadline() - std::chrono::system_clock::now());
  }
  Result<api::PoseResult> result = (*engine)->pose(core, hooks);
  if (!result.ok()) return to_grpc(result.status());

  v1::PoseResponse message;
  v1::PoseHeader* header = message.mutable_header();
  put_grid(result->output_grid, header->mutable_grid());
  const uint64_t label_bytes = result->labels ? result->labels->voxel_count() * sizeof(Label) : 0;
  const uint64_t ct_bytes = result->ct ? result->ct->voxel_count() * sizeof(float) : 0;
  header->set_label_bytes(label_bytes);
  header->set_ct_bytes(ct_bytes);
  header->set_surface_count(static_cast<int32_t>(result->surfaces.size()));
  if (result->labels) header->set_label_pixel_type(std::string(pixel_type_name(result->labels->source_type())));
  if (result->ct) header->set_ct_pixel_type(std::string(pixel_type_name(result->ct->source_type())));
  if (!writer->Write(message)) return {grpc::StatusCode::CANCELLED, "the client went away"};
  const uint64_t chunk = request->chunk_bytes() > 0 ? std::min<uint64_t>(request->chunk_bytes(), 4 << 20) : 1 << 20;
  // Label and CT voxels as chunks, each message's chunk in `field` (labels or ct).
  auto send_voxels = [&](const char* data, uint64_t size, v1::VolumeChunk* (v1::PoseResponse::*field)()) {
    return stream_chunks(data, size, chunk, [&](uint64_t offset, std::string bytes) {
      v1::PoseResponse m;
      (m.*field)()->set_offset(offset);
      (m.*field)()->set_data(std::move(bytes));
      return writer->Write(m);
    });
  };
  if (result->labels && !send_voxels(reinterpret_cast<const char*>(result->labels->data()), label_bytes,
                                     &v1::PoseResponse::mutable_labels)) {
    return {grpc::StatusCode::CANCELLED, "the client went away"};
  }
  if (result->ct && !send_voxels(reinterpret_cast<const char*>(result->ct->data()), ct_bytes,
                                 &v1::PoseResponse::mutable_ct)) {
    return {grpc::StatusCode::CANCELLED, "the client went away"};
  }
  for (const surface::SurfaceMesh& s : result->surfaces) {
    v1::PoseResponse m;
    v1::Surface* surface = m.mutable_surface();
    surface->set_name(s.name);
    surface->set_label(s.label);
    for (Eigen::Index v = 0; v < s.vertices.rows(); ++v) {
      for (int a = 0; a < 3; ++a) surface->add_vertices(s.vertices(v, a));
    }
    for (Eigen::Index t = 0; t < s.triangles.rows(); ++t) {
      for (int a = 0; a < 3; ++a) surface->add_triangles(s.triangles(t, a));
    }
    if (!writer->Write(m)) return {grpc::StatusCode::CANCELLED, "the client went away"};
  }
  v1::PoseResponse last;
  v1::QualityReport* report = last.mutable_report();
  report->set_json(report::to_json(result->report));
  report->set_inverted_tets(result->report.mesh.inverted_tets);
  report->set_bone_rigidity_error_mm(result->report.bone_rigidity_error_mm);
  for (const std::string& w : result->report.warnings) report->add_warnings(w);
  writer->Write(last);
  return grpc::Status::OK;
}

grpc::Status PosewarpService::Preview(grpc::ServerContext* context,
                                      grpc::ServerReaderWriter<v1::PreviewResponse, v1::PreviewRequest>* stream) {
  // A reader thread keeps only the newest update; this thread answers whatever is newest when it is free.
  std::mutex mutex;
  std::condition_variable arrived;
  std::optional<v1::PreviewRequest> latest;
  uint64_t skipped = 0;
  bool closed = false;
  std::string rig_id;
  std::thread reader([&] {
    v1::PreviewRequest update;
    while (stream->Read(&update)) {
      std::lock_guard<std::mutex> lock(mutex);
      if (rig_id.empty()) rig_id = update.rig_id();
      if (latest) ++skipped;
      latest = std::move(update);
      arrived.notify_one();
    }
    std::lock_guard<std::mutex> lock(mutex);
    closed = true;
    arrived.notify_one();
  });
  // On an early return (an error) the client may still be sending: cancel the call so the reader's Read ends.
  struct Join {
    std::thread& thread;
    grpc::ServerContext* context;
    std::mutex& mutex;
    bool& closed;
    ~Join() {
      bool reading = false;
      {
        std::lock_guard<std::mutex> lock(mutex);
        reading = !closed;
      }
      if (reading) context->TryCancel();
      thread.join();
    }
  } join{reader, context, mutex, closed};

  std::shared_ptr<const api::PoseEngine> engine;
  bool topology_sent = false;
  for (;;) {
    v1::PreviewRequest update;
    uint64_t dropped = 0;
    {
      std::unique_lock<std::mutex> lock(mutex);
      arrived.wait(lock, [&] { return latest.has_value() || closed; });
      if (!latest) return grpc::Status::OK;  // the client closed and everything was answered
      update = std::move(*latest);
      latest.reset();
      dropped = std::exchange(skipped, 0);
      if (update.rig_id().empty()) update.set_rig_id(rig_id);
    }
    if (context->IsCancelled()) return {grpc::StatusCode::CANCELLED, "the client cancelled the preview"};
    // A refused update is answered with its code; the stream goes on (a slider's next move may be fine).
    auto refuse = [&](const grpc::Status& status) {
      v1::PreviewResponse answer;
      answer.set_sequence(update.sequence());
      answer.set_dropped(dropped);
      answer.set_error_code(static_cast<int32_t>(status.error_code()));
      answer.set_error_message(status.error_message());
      return stream->Write(answer);
    };
    if (!engine) {
      Result<std::shared_ptr<const api::PoseEngine>> loaded =
          api::is_hex_id(update.rig_id()) ? this->engine(update.rig_id())
                                     : Result<std::shared_ptr<const api::PoseEngine>>(invalid_argument_error(
                                           "the first preview update names the rig (64 hex digits)"));
      if (!loaded.ok()) {
        if (!refuse(to_grpc(loaded.status()))) return {grpc::StatusCode::CANCELLED, "the client went away"};
        continue;
      }
      engine = *loaded;
    }
    const auto start = std::chrono::steady_clock::now();
    Result<pose::Pose> pose = api::pose_from_json(update.pose_json(), "in preview update " +
                                                                          std::to_string(update.sequence()));
    Result<api::PreviewResult> preview =
        pose.ok() ? engine->preview(*pose, method_of(update.method())) : Result<api::PreviewResult>(pose.status());
    if (!preview.ok()) {
      if (!refuse(to_grpc(preview.status()))) return {grpc::StatusCode::CANCELLED, "the client went away"};
      continue;
    }
    v1::PreviewResponse answer;
    answer.set_sequence(update.sequence());
    answer.set_dropped(dropped);
    const std::vector<surface::SurfaceMesh>& rest = engine->rig().surfaces;
    for (size_t i = 0; i < preview->surface_vertices.size(); ++i) {
      v1::SurfacePositions* positions = answer.add_surfaces();
      positions->set_name(rest[i].name);
      const Eigen::MatrixXd& v = preview->surface_vertices[i];
      positions->mutable_vertices()->Reserve(static_cast<int>(v.size()));
      for (Eigen::Index r = 0; r < v.rows(); ++r) {
        for (int a = 0; a < 3; ++a) positions->add_vertices(static_cast<float>(v(r, a)));
      }
      if (!topology_sent) {
        v1::Surface* topology = answer.add_topology();
        topology->set_name(rest[i].name);
        topology->set_label(rest[i].label);
        for (Eigen::Index t = 0; t < rest[i].triangles.rows(); ++t) {
          for (int a = 0; a < 3; ++a) topology->add_triangles(rest[i].triangles(t, a));
        }
      }
    }
    topology_sent = true;
    answer.set_server_ms(1000.0 * std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
    if (!stream->Write(answer)) return {grpc::StatusCode::CANCELLED, "the client went away"};
  }
}

}  // namespace posewarp::server
