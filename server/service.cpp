// PosewarpService: the handlers, the build queue, pose slots and the engine cache.
#include "service.h"

#include <spdlog/spdlog.h>

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <future>
#include <optional>
#include <random>
#include <set>
#include <thread>
#include <utility>

#include "convert.h"
#include "intake.h"
#include "posewarp/api/files.h"
#include "posewarp/api/rig_file.h"
#include "status_map.h"

namespace posewarp::server {
namespace {

namespace fs = std::filesystem;

const grpc::Status kClientGone{grpc::StatusCode::CANCELLED, "the client went away"};

// Streams `size` bytes from `data` as chunks of at most `chunk` bytes through `put(offset, bytes)`.
template <typename Put>
bool stream_chunks(const char* data, uint64_t size, uint64_t chunk, Put&& put) {
  for (uint64_t offset = 0; offset < size; offset += chunk) {
    if (!put(offset, std::string(data + offset, std::min(chunk, size - offset)))) return false;
  }
  return true;
}

// How a pose's volumes travel: raw samples or a file format's bytes, in the sample types the client chose.
struct VolumeEncoding {
  std::optional<api::VolumeFormat> format;  // none: raw samples
  bool gzip = false;
  PixelType label_type = PixelType::kInt32;
  PixelType ct_type = PixelType::kFloat32;
};

Result<VolumeEncoding> volume_encoding(const v1::PoseRequest& request, const api::Rig& rig) {
  VolumeEncoding e;
  switch (request.format()) {
    case v1::FILE_FORMAT_UNSPECIFIED:
    case v1::FILE_FORMAT_RAW: break;
    case v1::FILE_FORMAT_NIFTI_GZ: e.format = api::VolumeFormat::kNifti, e.gzip = true; break;
    case v1::FILE_FORMAT_NIFTI: e.format = api::VolumeFormat::kNifti; break;
    case v1::FILE_FORMAT_NRRD: e.format = api::VolumeFormat::kNrrd, e.gzip = true; break;
    default:
      return invalid_argument_error("a pose's volumes come as raw samples, NIfTI (.nii, .nii.gz) or NRRD bytes; "
                                    "ask for one of those (MHA is not offered)");
  }
  if (request.samples() == v1::SAMPLE_TYPE_STORED) {
    // The study's own types, as the CLI writes them; the wire carries no 64-bit integers (labels fit int32).
    const PixelType labels = rig.labels.source_type();
    e.label_type = wire_pixel_type(labels) != v1::PIXEL_TYPE_UNSPECIFIED ? labels : PixelType::kInt32;
    if (rig.ct) {
      const PixelType ct = rig.ct->source_type();
      e.ct_type = wire_pixel_type(ct) != v1::PIXEL_TYPE_UNSPECIFIED ? ct : PixelType::kFloat32;
    }
  } else if (request.samples() != v1::SAMPLE_TYPE_COMPUTED) {
    return invalid_argument_error("samples is SAMPLE_TYPE_STORED or SAMPLE_TYPE_COMPUTED");
  }
  return e;
}

using ChunkField = v1::VolumeChunk* (v1::PoseResponse::*)();

// n samples as `type` (or n bytes of a file, T = char), in chunks of about chunk_bytes, each converted straight into
// its message (no extra copy). Writes one message of a pose's stream (under the call's stall watch); false when the
// client went away.
using PoseWrite = std::function<bool(const v1::PoseResponse&)>;

template <typename T>
grpc::Status write_samples(const PoseWrite& write, const T* data, int64_t n, PixelType type, uint64_t chunk_bytes,
                           ChunkField field) {
  const int64_t sample = pixel_type_bytes(type);
  const int64_t per_chunk = std::max<int64_t>(1, static_cast<int64_t>(chunk_bytes) / sample);
  for (int64_t first = 0; first < n; first += per_chunk) {
    const int64_t count = std::min(per_chunk, n - first);
    v1::PoseResponse message;
    v1::VolumeChunk* part = (message.*field)();
    part->set_offset(static_cast<uint64_t>(first * sample));
    if (first == 0) part->set_total_bytes(static_cast<uint64_t>(n * sample));
    std::string* bytes = part->mutable_data();
    bytes->resize(static_cast<size_t>(count * sample));
    if constexpr (std::is_same_v<T, char>) {
      std::memcpy(bytes->data(), data + first, static_cast<size_t>(count));  // a file's bytes, as they are
    } else if (!convert_samples(data + first, count, type, bytes->data())) {
      return {grpc::StatusCode::INTERNAL, "a posed value does not fit the study's voxel type " +
                                              std::string(pixel_type_name(type)) + "; ask for computed samples"};
    }
    if (!write(message)) return kClientGone;
  }
  return grpc::Status::OK;
}

// The posed volumes of one call, written to its stream from a thread of their own while the engine goes on. Each
// volume waits for the one before it, and the call writes nothing else until wait(): one writer at a time.
class VolumeSender {
 public:
  VolumeSender(PoseWrite write, VolumeEncoding encoding, uint64_t chunk_bytes)
      : write_(std::move(write)), encoding_(std::move(encoding)), chunk_bytes_(chunk_bytes) {}
  ~VolumeSender() { (void)wait(); }

  template <typename T>
  void send(std::shared_ptr<const Volume<T>> volume, PixelType type, ChunkField field) {
    last_ = std::async(std::launch::async, [this, before = std::move(last_), volume = std::move(volume), type,
                                            field]() mutable -> grpc::Status {
      if (before.valid()) {
        if (grpc::Status s = before.get(); !s.ok()) return s;
      }
      if (!encoding_.format)
        return write_samples(write_, volume->data(), volume->voxel_count(), type, chunk_bytes_, field);
      Result<std::string> bytes = api::encode_volume(*volume, *encoding_.format, encoding_.gzip, type);
      if (!bytes.ok()) return {grpc::StatusCode::INTERNAL, "encoding a posed volume failed: " + bytes.status().message()};
      return write_samples(write_, bytes->data(), static_cast<int64_t>(bytes->size()), PixelType::kUInt8, chunk_bytes_,
                           field);
    });
  }

  // Waits for every volume handed over; OK, or why one was not sent.
  grpc::Status wait() {
    if (!last_.valid()) return status_;
    status_ = last_.get();
    return status_;
  }

 private:
  PoseWrite write_;
  VolumeEncoding encoding_;
  uint64_t chunk_bytes_;
  std::future<grpc::Status> last_;
  grpc::Status status_;
};

// A request id from the client's "x-request-id" metadata when it is a plain token, else one of ours.
std::string request_id_of(const grpc::ServerContext* context, uint64_t counter) {
  const auto& metadata = context->client_metadata();
  const auto it = metadata.find("x-request-id");
  if (it != metadata.end() && it->second.size() <= 64 && !it->second.empty()) {
    const std::string id(it->second.data(), it->second.size());
    if (std::all_of(id.begin(), id.end(), [](char c) { return std::isalnum(static_cast<unsigned char>(c)) || c == '-' || c == '_'; })) {
      return id;
    }
  }
  char text[32];
  std::snprintf(text, sizeof text, "s%06llx", static_cast<unsigned long long>(counter));
  return text;
}

}  // namespace

// One call's frame: the token check, the stall watch over its stream, then at the end the log line and the metrics.
class PosewarpService::Call {
 public:
  Call(PosewarpService& service, grpc::ServerContext* context, const char* method, std::string rig_id = "")
      : service_(service),
        context_(context),
        method_(method),
        rig_id_(std::move(rig_id)),
        request_id_(request_id_of(context, service.next_request_++)),
        start_(std::chrono::steady_clock::now()),
        stream_(service.stall_watch_.watch(context)) {
    if (service_.tokens_.enabled()) {
      const auto& metadata = context->client_metadata();
      const auto it = metadata.find("authorization");
      const std::string value = it == metadata.end() ? "" : std::string(it->second.data(), it->second.size());
      if (!service_.tokens_.allows(value)) {
        refusal_ = grpc::Status(grpc::StatusCode::UNAUTHENTICATED,
                                value.empty() ? "this server needs a bearer token: send 'authorization: Bearer "
                                                "<token>' (the CLI's --token-file)"
                                              : "the bearer token is not one this server accepts; check your token "
                                                "file (tokens are re-read by the server on SIGHUP)");
      }
    }
  }
  bool refused() const { return !refusal_.ok(); }
  grpc::Status refusal() { return done(refusal_); }
  void set_rig(const std::string& rig_id) { rig_id_ = rig_id; }
  // Who the call comes from, for the per-client limits.
  std::string client() const { return client_of(*context_); }

  // One Write or Read of the call's stream, under the stall watch: false when the client went away or stalled.
  template <typename Writer, typename Message>
  bool write(Writer* writer, const Message& message) {
    return stream_->io([&] { return writer->Write(message); });
  }
  template <typename Reader, typename Message>
  bool read(Reader* reader, Message* message) {
    return stream_->io([&] { return reader->Read(message); });
  }
  StallWatch::Stream& stream() { return *stream_; }
  bool cancelled() const { return context_->IsCancelled(); }

  grpc::Status done(grpc::Status status) {
    if (stream_->stalled()) {
      const double limit_s = static_cast<double>(service_.stall_watch_.limit().count()) / 1000.0;
      status = grpc::Status(grpc::StatusCode::DEADLINE_EXCEEDED,
                            "the stream made no progress for " + fmt::format("{:g}", limit_s) +
                                " s (the client stopped reading or sending; the server's --stall-timeout-s); the "
                                "call was cancelled");
    } else if (status.error_code() == grpc::StatusCode::CANCELLED &&
               context_->deadline() <= std::chrono::system_clock::now()) {
      // gRPC cancels a call whose deadline passed: that is the client's deadline, not a cancel.
      status = grpc::Status(grpc::StatusCode::DEADLINE_EXCEEDED, "the client's deadline passed before the call ended");
    }
    const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start_).count();
    const std::string code = status_code_name(static_cast<StatusCode>(status.error_code())).data();
    service_.metrics_.observe(method_, code, seconds);
    if (status.ok() && std::string_view(method_) == "Pose" && api::is_hex_id(rig_id_)) {
      service_.metrics_.count_rig_pose(rig_id_);
    }
    // Ids are hashes and the code is canonical: nothing here names a patient or a client's file.
    const std::string rig = api::is_hex_id(rig_id_) ? " rig=" + rig_id_.substr(0, 16) : "";
    if (status.ok() || status.error_code() == grpc::StatusCode::CANCELLED) {
      spdlog::info("request={} method={}{} status={} ms={:.1f}", request_id_, method_, rig, code, seconds * 1e3);
    } else {
      spdlog::warn("request={} method={}{} status={} ms={:.1f} message=\"{}\"", request_id_, method_, rig, code,
                   seconds * 1e3, status.error_message());
    }
    return status;
  }

 private:
  PosewarpService& service_;
  grpc::ServerContext* context_;
  const char* method_;
  std::string rig_id_;
  std::string request_id_;
  std::chrono::steady_clock::time_point start_;
  std::unique_ptr<StallWatch::Stream> stream_;
  grpc::Status refusal_;
};

PosewarpService::PosewarpService(std::unique_ptr<RigStore> store, ServiceOptions options, const Tokens& tokens,
                                 Metrics& metrics)
    : store_(std::move(store)),
      options_(options),
      stall_watch_(std::chrono::milliseconds(std::max(1, options.stall_timeout_ms)),
                   [&metrics] { metrics.count("streams_stalled"); }),
      memory_(options.memory_bytes),
      client_limits_(options.client),
      tokens_(tokens),
      metrics_(metrics) {
  if (options_.pose_slots <= 0) options_.pose_slots = static_cast<int>(std::max(1u, std::thread::hardware_concurrency()));
  metrics_.set_gauges([this] { return gauges(); });
  for (int i = 0; i < std::max(1, options_.build_workers); ++i) build_threads_.emplace_back([this] { build_worker(); });
  if (store_->index().shared()) {
    lease_thread_ = std::thread([this] { lease_keeper(); });
    // A rig deleted through any replica leaves every replica's cache; after a lost connection (notifications
    // missed), each cached rig is looked up again.
    store_->index().watch_deleted_rigs(
        [this](const std::string& rig_id) {
          evict(rig_id);
          spdlog::info("rig={} deleted by another replica; dropped from the cache", rig_id.substr(0, 16));
        },
        [this] {
          std::vector<std::string> cached;
          {
            std::lock_guard<std::mutex> lock(cache_mutex_);
            for (const auto& [id, entry] : cache_) cached.push_back(id);
          }
          for (const std::string& id : cached) {
            Result<std::optional<RigRecord>> row = store_->index().rig(id);
            if (row.ok() && !*row) evict(id);
          }
        });
  }
}

void PosewarpService::persist(const Job& job) {
  OperationRecord record = record_from(job.operation, job.request);
  record.owner = options_.replica;
  record.lease_s = options_.lease_s;
  if (Status s = store_->index().put_operation(record); !s.ok()) {
    spdlog::error("operation {}: {}", job.operation.id(), s.message());
  }
}

void PosewarpService::lease_keeper() {
  const auto period = std::chrono::milliseconds(std::max(1, options_.lease_s) * 1000 / 3);
  std::unique_lock<std::mutex> lock(mutex_);
  while (!stopping_) {
    // Woken early only to stop (changed_ also carries every build's progress).
    changed_.wait_until(lock, std::chrono::steady_clock::now() + period, [this] { return stopping_; });
    if (stopping_) break;
    lock.unlock();
    if (Status s = store_->index().renew_operations(options_.replica, options_.lease_s); !s.ok()) {
      spdlog::warn("cannot renew this replica's build leases: {}", s.message());
    }
    Result<int> failed = store_->index().fail_expired_operations(
        static_cast<int>(grpc::StatusCode::ABORTED), "the replica running the build stopped; build again");
    if (failed.ok() && *failed > 0) spdlog::warn("{} build(s) of a stopped replica marked failed", *failed);
    lock.lock();
  }
}

Result<bool> PosewarpService::claim_build(const std::shared_ptr<Job>& job, const std::string& rig_id) {
  bool told = false;
  for (;;) {
    POSEWARP_ASSIGN_OR_RETURN(const bool mine, store_->index().claim_build(rig_id, options_.replica, options_.lease_s));
    if (mine) return true;
    if (!told) {
      spdlog::info("operation={} rig={} is being built by another replica; waiting for it", job->operation.id(),
                   rig_id.substr(0, 16));
      set_operation(job, [](v1::Operation& op) { op.set_stage("waiting for another replica's build"); }, false);
      metrics_.count("builds_waited_for_another_replica");
      told = true;
    }
    for (int i = 0; i < 5 && !job->cancel.cancelled(); ++i) std::this_thread::sleep_for(std::chrono::milliseconds(100));
    if (job->cancel.cancelled()) return cancelled_error("the build was cancelled");
    // Built by the other replica: done. Its claim released without a rig (it failed or died): tried again above.
    if (store_->rig(rig_id).ok()) return false;
  }
}

PosewarpService::~PosewarpService() {
  shutdown();
  metrics_.set_gauges(nullptr);
}

std::vector<std::pair<std::string, double>> PosewarpService::gauges() {
  std::vector<std::pair<std::string, double>> values;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    values.emplace_back("builds_running", builds_running_);
    values.emplace_back("build_queue_depth", static_cast<double>(build_queue_.size()));
    values.emplace_back("poses_running", poses_running_);
    values.emplace_back("pose_queue_depth", poses_waiting_);
    int previews = 0;
    for (const auto& [client, n] : previews_by_client_) previews += n;
    values.emplace_back("preview_streams", previews);
  }
  values.emplace_back("memory_reserved_bytes", static_cast<double>(memory_.used()));
  values.emplace_back("memory_budget_bytes", static_cast<double>(memory_.total()));
  std::lock_guard<std::mutex> lock(cache_mutex_);
  int64_t bytes = 0;
  for (const auto& [id, entry] : cache_) bytes += entry.bytes;
  values.emplace_back("cache_bytes", static_cast<double>(bytes));
  values.emplace_back("cache_rigs", static_cast<double>(cache_.size()));
  return values;
}

void PosewarpService::shutdown() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (stopping_) return;
    stopping_ = true;
    for (auto& [id, job] : operations_) {
      job->cancel.cancel();
      if (job->operation.state() == v1::Operation::QUEUED) {
        job->operation.set_state(v1::Operation::CANCELLED);
        job->operation.set_error_code(static_cast<int32_t>(grpc::StatusCode::CANCELLED));
        job->operation.set_error_message("the server stopped before the build started; build again");
        persist(*job);
      }
    }
    build_queue_.clear();
  }
  changed_.notify_all();
  for (std::thread& t : build_threads_) {
    if (t.joinable()) t.join();
  }
  if (lease_thread_.joinable()) lease_thread_.join();
}

grpc::Status PosewarpService::to_grpc(const Status& status) const { return server::to_grpc(status, store_->directory()); }

RequestLimits PosewarpService::request_limits() const {
  RequestLimits limits;
  limits.max_upload_bytes = options_.max_upload_bytes;
  limits.max_volume_voxels = options_.max_volume_voxels;
  return limits;
}

api::ReadOptions PosewarpService::read_options() const {
  api::ReadOptions options;
  options.max_voxels = options_.max_volume_voxels;
  options.voxel_limit_name = "the server's --max-volume-voxels";
  options.inline_data_only = true;
  return options;
}

Status PosewarpService::server_limits_named(const Status& status) const {
  if (status.code() != StatusCode::kResourceExhausted) return status;
  return Status(status.code(), status.message() + " (this server makes output grids of at most " +
                                   std::to_string(options_.max_output_voxels) + " voxels, its --max-output-voxels, " +
                                   "within a memory budget of " + std::to_string(memory_.total() >> 20) +
                                   " MB, its --memory-mb; max_output_bytes lowers it for one request)");
}

ProgressHooks PosewarpService::call_hooks(grpc::ServerContext* context) const {
  ProgressHooks hooks;
  hooks.threads = options_.pose_threads;
  hooks.cancel_requested = [context] { return context->IsCancelled(); };
  if (context->deadline() != std::chrono::system_clock::time_point::max()) {
    hooks.deadline = std::chrono::steady_clock::now() + (context->deadline() - std::chrono::system_clock::now());
  }
  return hooks;
}

Result<MemoryBudget::Reservation> PosewarpService::reserve(grpc::ServerContext* context, int64_t bytes,
                                                          const std::string& what) {
  const auto until = call_hooks(context).deadline.value_or(std::chrono::steady_clock::now() + std::chrono::minutes(1));
  return memory_.reserve(bytes, what, until, [context] { return context->IsCancelled(); });
}

template <typename Request>
grpc::Status PosewarpService::stage_upload(Call& call, grpc::ServerReader<Request>* reader, uint64_t size,
                                           const std::string& sha256, const std::string& file_name,
                                           StagedUpload* staged) {
  Result<ClientLimits::Entry> admitted = client_limits_.enter_upload(call.client(), static_cast<int64_t>(size));
  if (!admitted.ok()) return to_grpc(admitted.status());
  staged->admitted.emplace(std::move(admitted).value());
  // The bytes go to a file in a directory of this upload's own as they arrive (never held whole in memory): a
  // header there that names a data file beside itself finds nothing it did not send.
  Result<std::string> directory = store_->make_staging_directory();
  if (!directory.ok()) return to_grpc(directory.status());
  staged->directory = std::make_unique<StagingDirectory>(*directory);
  staged->path = *directory + "/" + file_name;
  const Status received =
      receive_upload<Request>([&](Request* message) { return call.read(reader, message); }, size, sha256, staged->path);
  if (received.ok()) return grpc::Status::OK;
  return call.stream().stalled() || call.cancelled() ? kClientGone : to_grpc(received);
}

grpc::Status PosewarpService::UploadVolume(grpc::ServerContext* context,
                                           grpc::ServerReader<v1::UploadVolumeRequest>* reader, v1::Volume* response) {
  Call call(*this, context, "UploadVolume");
  if (call.refused()) return call.refusal();
  v1::UploadVolumeRequest part;
  if (!call.read(reader, &part)) return call.done(kClientGone);
  if (!part.has_header()) {
    return call.done({grpc::StatusCode::INVALID_ARGUMENT,
                      "an upload starts with its header (kind, format, size_bytes, "
                      "sha256)"});
  }
  const v1::UploadVolumeHeader header = part.header();
  Result<UploadPlan> checked = check_upload_header(header, request_limits());
  if (!checked.ok()) return call.done(to_grpc(checked.status()));
  const UploadPlan& plan = *checked;
  const bool labels = header.kind() == v1::VOLUME_KIND_LABELS;
  const std::string kind = labels ? "labels" : "intensity";
  // A file the store holds already (its id is its SHA-256) is answered after the header: the client's chunks are
  // never read, so a client re-sending a study does not move its bytes again.
  if (!plan.raw) {
    if (Result<VolumeRecord> existing = store_->volume(header.sha256()); existing.ok() && existing->kind == kind) {
      if (Result<api::VolumeHeader> stored = api::read_header(existing->path, read_options()); stored.ok()) {
        response->set_id(existing->id);
        response->set_kind(header.kind());
        put_grid(stored->geometry, response->mutable_grid());
        response->set_pixel_type(std::string(pixel_type_name(stored->pixel_type)));
        response->set_size_bytes(existing->size_bytes);
        response->set_already_stored(true);
        return call.done(grpc::Status::OK);
      }
    }
  }
  StagedUpload upload;
  if (grpc::Status s = stage_upload(call, reader, header.size_bytes(), header.sha256(), "upload" + plan.extension, &upload);
      !s.ok()) {
    return call.done(s);
  }
  const std::string& staged = upload.path;

  if (plan.raw) {
    // Raw samples become a NIfTI file in the store; the id covers the samples and their geometry.
    const std::string id = api::sha256_hex(header.sha256() + header.raw_grid().SerializeAsString() +
                                           std::to_string(header.raw_pixel_type()) + kind);
    if (Result<VolumeRecord> existing = store_->volume(id); existing.ok()) {
      response->set_id(id);
      response->set_kind(header.kind());
      put_grid(plan.raw_grid, response->mutable_grid());
      response->set_size_bytes(existing->size_bytes);
      return call.done(grpc::Status::OK);
    }
    // The samples, the volume made of them and its .nii.gz, all in memory at once.
    const int64_t voxels = plan.raw_grid.voxel_count();
    Result<MemoryBudget::Reservation> memory =
        reserve(context, static_cast<int64_t>(header.size_bytes()) * 2 + voxels * 4, "this upload");
    if (!memory.ok()) return call.done(to_grpc(memory.status()));
    Result<std::string> encoded = [&]() -> Result<std::string> {
      POSEWARP_ASSIGN_OR_RETURN(const std::string bytes,
                                api::read_text_input(staged, "upload", static_cast<int64_t>(header.size_bytes())));
      if (labels) {
        POSEWARP_ASSIGN_OR_RETURN(const LabelVolume v, labels_from_raw(bytes, plan.raw_type, plan.raw_grid));
        POSEWARP_RETURN_IF_ERROR(api::check_labels_look_like_labels(v, "the uploaded label volume"));
        return api::encode_volume(v, api::VolumeFormat::kNifti, true);
      }
      POSEWARP_ASSIGN_OR_RETURN(const IntensityVolume v, intensity_from_raw(bytes, plan.raw_type, plan.raw_grid));
      return api::encode_volume(v, api::VolumeFormat::kNifti, true);
    }();
    if (!encoded.ok()) return call.done(to_grpc(encoded.status()));
    Result<VolumeRecord> stored = store_->put_volume(id, plan.extension, kind, *encoded);
    if (!stored.ok()) return call.done(to_grpc(stored.status()));
    response->set_id(id);
    response->set_kind(header.kind());
    put_grid(plan.raw_grid, response->mutable_grid());
    response->set_pixel_type(std::string(pixel_type_name(plan.raw_type)));
    response->set_size_bytes(stored->size_bytes);
    return call.done(grpc::Status::OK);
  }
  // A file is read as posing will read it before it gets its name in the store: its header first (the voxel
  // limit, inline data only), then, with memory reserved for them, its voxels.
  Result<api::VolumeHeader> read = [&]() -> Result<api::VolumeHeader> {
    POSEWARP_ASSIGN_OR_RETURN(const api::VolumeHeader h, api::read_header(staged, read_options()));
    const int64_t voxels = h.geometry.voxel_count();
    POSEWARP_ASSIGN_OR_RETURN(
        const MemoryBudget::Reservation memory,
        reserve(context, voxels * (pixel_type_bytes(h.pixel_type) + 4), "reading this upload"));
    if (labels) {
      POSEWARP_ASSIGN_OR_RETURN(const LabelVolume volume, api::read_label_volume(staged, read_options()));
      POSEWARP_RETURN_IF_ERROR(api::check_labels_look_like_labels(volume, "the uploaded label volume"));
    } else {
      POSEWARP_RETURN_IF_ERROR(api::read_intensity_volume(staged, read_options()).status());
    }
    return h;
  }();
  if (!read.ok()) {
    // Named as the client knows it; a path a reader quotes (the store's) never reaches the client.
    const std::string message = without_path(read.status().message(), staged, "the uploaded volume");
    return call.done(to_grpc(Status(read.status().code(), without_path(message, upload.directory->path(), "the upload"))));
  }
  Result<VolumeRecord> stored = store_->put_volume_file(header.sha256(), plan.extension, kind, staged);
  if (!stored.ok()) return call.done(to_grpc(stored.status()));
  response->set_id(stored->id);
  response->set_kind(header.kind());
  put_grid(read->geometry, response->mutable_grid());
  response->set_pixel_type(std::string(pixel_type_name(read->pixel_type)));
  response->set_size_bytes(stored->size_bytes);
  return call.done(grpc::Status::OK);
}

grpc::Status PosewarpService::BuildRig(grpc::ServerContext* context, const v1::BuildRigRequest* request,
                                       v1::Operation* response) {
  Call call(*this, context, "BuildRig");
  if (call.refused()) return call.refusal();
  if (Status s = check_build_request(*request); !s.ok()) return call.done(to_grpc(s));
  // Each volume was uploaded for its purpose: the labels as labels, the CT as intensities (the swap is refused
  // before any work; a volume of an older store, adopted without its kind, is checked by the build).
  Result<VolumeRecord> labels = store_->volume(request->labels_volume_id());
  if (!labels.ok()) return call.done(to_grpc(labels.status().with_context("labels_volume_id")));
  std::optional<VolumeRecord> ct;
  if (!request->ct_volume_id().empty()) {
    Result<VolumeRecord> v = store_->volume(request->ct_volume_id());
    if (!v.ok()) return call.done(to_grpc(v.status().with_context("ct_volume_id")));
    ct = *v;
  }
  const bool labels_wrong = labels->kind == "intensity";
  const bool ct_wrong = ct && ct->kind == "labels";
  if (labels_wrong || ct_wrong) {
    std::string message = labels_wrong && ct_wrong ? "labels_volume_id names an intensity volume and ct_volume_id a "
                                                     "label volume: they are swapped"
                          : labels_wrong           ? "labels_volume_id names a volume uploaded as VOLUME_KIND_INTENSITY"
                                                     " (a CT or MRI); give the segmentation's id"
                                                   : "ct_volume_id names a volume uploaded as VOLUME_KIND_LABELS (a "
                                                     "segmentation); give the CT's id";
    return call.done({grpc::StatusCode::INVALID_ARGUMENT, message});
  }
  v1::BuildRigRequest unnamed = *request;
  unnamed.clear_name();
  const std::string key = api::sha256_hex(unnamed.SerializeAsString());
  auto job = std::make_shared<Job>();
  job->request = *request;
  job->key = key;
  job->operation.set_id(api::sha256_hex(key + std::to_string(std::chrono::system_clock::now().time_since_epoch().count()) +
                                        std::to_string(next_request_++))
                            .substr(0, 32));
  job->operation.set_state(v1::Operation::QUEUED);
  job->operation.set_name(request->name());
  job->operation.set_created(iso_now());
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (stopping_) return call.done({grpc::StatusCode::UNAVAILABLE, "the server is shutting down; try again shortly"});
    // The same build already queued or running: its operation, not a second build.
    if (const auto live = live_by_key_.find(key); live != live_by_key_.end()) {
      *response = live->second->operation;
      return call.done(grpc::Status::OK);
    }
    if (static_cast<int>(build_queue_.size()) >= options_.build_queue) {
      return call.done({grpc::StatusCode::RESOURCE_EXHAUSTED, "the build queue is full (" +
                                                                  std::to_string(options_.build_queue) +
                                                                  " waiting); try again when a build has finished"});
    }
    OperationRecord record = record_from(job->operation, job->request);
    record.owner = options_.replica;
    record.lease_s = options_.lease_s;
    if (Status s = store_->index().put_operation(record); !s.ok()) return call.done(to_grpc(s));
    operations_[job->operation.id()] = job;
    live_by_key_[key] = job;
    build_queue_.push_back(job);
    *response = job->operation;
  }
  changed_.notify_all();
  return call.done(grpc::Status::OK);
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
      ++builds_running_;
      persist(*job);
    }
    changed_.notify_all();
    run_build(job);
    {
      std::lock_guard<std::mutex> lock(mutex_);
      --builds_running_;
      live_by_key_.erase(job->key);
    }
    changed_.notify_all();
  }
}

void PosewarpService::set_operation(const std::shared_ptr<Job>& job, const std::function<void(v1::Operation&)>& change,
                                    bool persist) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    change(job->operation);
    job->operation.set_elapsed_s(std::chrono::duration<double>(std::chrono::steady_clock::now() - job->started).count());
    if (persist) {
      this->persist(*job);
    }
  }
  changed_.notify_all();
}

void PosewarpService::run_build(const std::shared_ptr<Job>& job) {
  const auto started = std::chrono::steady_clock::now();
  auto finish = [&](const Status& status) {
    const grpc::Status g = to_grpc(status);
    const std::string code = status_code_name(status.code()).data();
    metrics_.observe("build", code, std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count());
    spdlog::info("operation={} build status={} s={:.1f}", job->operation.id(), code,
                 std::chrono::duration<double>(std::chrono::steady_clock::now() - started).count());
    set_operation(job, [&](v1::Operation& op) {
      if (status.ok()) return;
      op.set_state(status.code() == StatusCode::kCancelled ? v1::Operation::CANCELLED : v1::Operation::FAILED);
      op.set_error_code(static_cast<int32_t>(g.error_code()));
      op.set_error_message(g.error_message());
    }, true);
  };
  Status status = [&]() -> Status {
    const v1::BuildRigRequest& request = job->request;
    api::BuildInputs inputs;
    POSEWARP_ASSIGN_OR_RETURN(const VolumeRecord labels, store_->volume(request.labels_volume_id()));
    POSEWARP_ASSIGN_OR_RETURN(inputs.labels, api::read_label_volume(labels.path));
    if (!request.ct_volume_id().empty()) {
      POSEWARP_ASSIGN_OR_RETURN(const VolumeRecord ct, store_->volume(request.ct_volume_id()));
      POSEWARP_ASSIGN_OR_RETURN(inputs.ct, api::read_intensity_volume(ct.path));
    }
    POSEWARP_ASSIGN_OR_RETURN(inputs.label_map,
                              request.label_map_json().empty()
                                  ? api::preset_by_name(request.preset().empty() ? "totalsegmentator" : request.preset())
                                  : api::label_map_from_json(request.label_map_json(), "in the request"));
    if (!request.rig_spec_json().empty()) {
      POSEWARP_ASSIGN_OR_RETURN(inputs.spec, api::rig_spec_from_json(request.rig_spec_json(), "in the request"));
    }
    inputs.labels_source = "volume " + request.labels_volume_id();
    if (!request.ct_volume_id().empty()) inputs.ct_source = "volume " + request.ct_volume_id();
    const api::BuildParams params;
    const std::string id = api::rig_id_of(inputs, params);
    const auto succeeded = [&] {
      set_operation(job, [&](v1::Operation& op) {
        op.set_state(v1::Operation::SUCCEEDED);
        op.set_rig_id(id);
      }, true);
      return ok_status();
    };
    if (store_->rig(id).ok()) return succeeded();  // built before from the same inputs: no second build
    // Replicas sharing the store build the same rig once: the claim's holder builds, the others wait for its rig.
    POSEWARP_ASSIGN_OR_RETURN(const bool mine, claim_build(job, id));
    if (!mine) return succeeded();
    struct Release {
      StoreIndex& index;
      const std::string& rig_id;
      const std::string& owner;
      ~Release() { (void)index.release_build(rig_id, owner); }
    } release{store_->index(), id, options_.replica};
    if (store_->rig(id).ok()) return succeeded();  // finished by another replica just before the claim
    ProgressHooks hooks;
    hooks.threads = options_.build_threads;
    hooks.cancel_requested = job->cancel.as_hook();
    hooks.on_progress = [&](std::string_view stage, double fraction) {
      set_operation(job, [&](v1::Operation& op) {
        op.set_stage(std::string(stage));
        op.set_stage_fraction(fraction);
      }, false);
    };
    POSEWARP_ASSIGN_OR_RETURN(const api::Rig rig, api::build_rig(inputs, params, hooks));
    if (job->cancel.cancelled()) return cancelled_error("the build was cancelled");
    RigRecord record;
    record.id = rig.id();
    record.name = request.name();
    record.labels_volume_id = request.labels_volume_id();
    record.ct_volume_id = request.ct_volume_id();
    for (const auto& [stage, seconds] : rig.provenance.stage_seconds) record.build_seconds += seconds;
    POSEWARP_RETURN_IF_ERROR(store_->put_rig(record, api::rig_to_bytes(rig)));
    metrics_.count("rigs_built");  // by this replica (replicas sharing a store build each rig once in all)
    set_operation(job, [&](v1::Operation& op) {
      op.set_state(v1::Operation::SUCCEEDED);
      op.set_rig_id(record.id);
    }, true);
    return ok_status();
  }();
  finish(status);
}

Result<v1::Operation> PosewarpService::find_operation(const std::string& id) {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (const auto it = operations_.find(id); it != operations_.end()) return it->second->operation;
  }
  if (id.empty() || id.size() > 64) return invalid_argument_error("an operation id is 32 hex digits (from BuildRig)");
  POSEWARP_ASSIGN_OR_RETURN(const std::optional<OperationRecord> row, store_->index().operation(id));
  if (!row) return not_found_error("no operation " + id + " on this server (ListOperations shows them)");
  return operation_from(*row);
}

grpc::Status PosewarpService::GetOperation(grpc::ServerContext* context, const v1::GetOperationRequest* request,
                                           v1::Operation* response) {
  Call call(*this, context, "GetOperation");
  if (call.refused()) return call.refusal();
  Result<v1::Operation> operation = find_operation(request->operation_id());
  if (!operation.ok()) return call.done(to_grpc(operation.status()));
  *response = *operation;
  return call.done(grpc::Status::OK);
}

grpc::Status PosewarpService::WatchOperation(grpc::ServerContext* context, const v1::GetOperationRequest* request,
                                             grpc::ServerWriter<v1::Operation>* writer) {
  Call call(*this, context, "WatchOperation");
  if (call.refused()) return call.refusal();
  std::shared_ptr<Job> job;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (const auto it = operations_.find(request->operation_id()); it != operations_.end()) job = it->second;
  }
  if (!job) {
    // An operation of an earlier run (final already), or, with a shared index, one another replica runs: its row
    // is followed until it ends (its state only; the stages are the running replica's).
    std::string last;
    for (;;) {
      Result<v1::Operation> operation = find_operation(request->operation_id());
      if (!operation.ok()) return call.done(to_grpc(operation.status()));
      if (const std::string serialized = operation->SerializeAsString(); serialized != last) {
        last = serialized;
        if (!call.write(writer, *operation)) return call.done(kClientGone);
      }
      if (is_final(operation->state()) || !store_->index().shared()) return call.done(grpc::Status::OK);
      if (context->IsCancelled()) return call.done({grpc::StatusCode::CANCELLED, "the client cancelled the watch"});
      std::this_thread::sleep_for(std::chrono::milliseconds(250));
    }
  }
  std::unique_lock<std::mutex> lock(mutex_);
  std::string last;
  for (;;) {
    const v1::Operation now = job->operation;
    const std::string serialized = now.SerializeAsString();
    if (serialized != last) {
      last = serialized;
      lock.unlock();
      const bool written = call.write(writer, now);
      lock.lock();
      if (!written) return call.done(kClientGone);
    }
    if (is_final(now.state())) return call.done(grpc::Status::OK);
    if (context->IsCancelled()) return call.done({grpc::StatusCode::CANCELLED, "the client cancelled the watch"});
    changed_.wait_for(lock, std::chrono::milliseconds(200));
  }
}

grpc::Status PosewarpService::CancelOperation(grpc::ServerContext* context, const v1::GetOperationRequest* request,
                                              v1::Operation* response) {
  Call call(*this, context, "CancelOperation");
  if (call.refused()) return call.refusal();
  {
    std::lock_guard<std::mutex> lock(mutex_);
    const auto it = operations_.find(request->operation_id());
    if (it != operations_.end()) {
      const std::shared_ptr<Job>& job = it->second;
      job->cancel.cancel();
      if (job->operation.state() == v1::Operation::QUEUED) {
        build_queue_.erase(std::remove(build_queue_.begin(), build_queue_.end(), job), build_queue_.end());
        live_by_key_.erase(job->key);
        job->operation.set_state(v1::Operation::CANCELLED);
        job->operation.set_error_code(static_cast<int32_t>(grpc::StatusCode::CANCELLED));
        job->operation.set_error_message("cancelled before it started");
        persist(*job);
      }
      *response = job->operation;
      changed_.notify_all();
      return call.done(grpc::Status::OK);
    }
  }
  Result<v1::Operation> operation = find_operation(request->operation_id());  // finished in an earlier run
  if (!operation.ok()) return call.done(to_grpc(operation.status()));
  *response = *operation;
  return call.done(grpc::Status::OK);
}

grpc::Status PosewarpService::ListOperations(grpc::ServerContext* context, const v1::ListOperationsRequest* request,
                                             v1::ListOperationsResponse* response) {
  Call call(*this, context, "ListOperations");
  if (call.refused()) return call.refusal();
  const int page = request->page_size() <= 0 ? 50 : std::min(request->page_size(), 1000);
  Result<std::vector<OperationRecord>> rows = store_->index().operations(request->page_token(), page + 1);
  if (!rows.ok()) return call.done(to_grpc(rows.status()));
  for (const OperationRecord& row : *rows) {
    if (response->operations_size() == page) {
      response->set_next_page_token(response->operations(page - 1).id());
      break;
    }
    // A live build shows its progress; the index has its state transitions.
    Result<v1::Operation> live = find_operation(row.id);
    *response->add_operations() = live.ok() ? *live : operation_from(row);
  }
  return call.done(grpc::Status::OK);
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
  if (waiting.valid()) {
    metrics_.count("cache_hits");
    return *waiting.get();
  }
  metrics_.count("cache_misses");
  auto result = std::make_shared<EngineResult>([&]() -> EngineResult {
    POSEWARP_ASSIGN_OR_RETURN(const RigRecord stored, store_->rig(rig_id));
    // Loading holds the file's bytes beside the rig made of them; the loaded engine then counts in the cache.
    POSEWARP_ASSIGN_OR_RETURN(const MemoryBudget::Reservation loading_memory,
                              memory_.reserve(static_cast<int64_t>(stored.size_bytes) * 2, "loading this rig",
                                              std::chrono::steady_clock::now() + std::chrono::seconds(60), nullptr));
    Result<api::Rig> rig = api::load_rig(stored.path);
    if (!rig.ok() && rig.status().code() == StatusCode::kDataLoss) {
      // Never served: moved aside for a person to look at, and the client told to rebuild.
      if (Status q = store_->quarantine_rig(rig_id, rig.status().message()); !q.ok()) spdlog::error("{}", q.message());
      spdlog::error("rig={} failed its checks on load and was quarantined", rig_id.substr(0, 16));
      return data_loss_error("rig " + rig_id + " failed its checksums in the store and was quarantined; build it "
                             "again (or upload a good copy with UploadRig)");
    }
    if (!rig.ok()) return rig.status();
    ProgressHooks hooks;
    hooks.threads = options_.pose_threads;
    POSEWARP_ASSIGN_OR_RETURN(api::PoseEngine engine, api::PoseEngine::create(std::move(rig).value(), hooks));
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
    metrics_.count("cache_evictions");
  }
  return *result;
}

void PosewarpService::evict(const std::string& rig_id) {
  std::lock_guard<std::mutex> lock(cache_mutex_);
  cache_.erase(rig_id);
}

grpc::Status PosewarpService::GetRig(grpc::ServerContext* context, const v1::GetRigRequest* request,
                                     v1::Rig* response) {
  Call call(*this, context, "GetRig", request->rig_id());
  if (call.refused()) return call.refusal();
  Result<RigRecord> stored = store_->rig(request->rig_id());
  if (!stored.ok()) return call.done(to_grpc(stored.status()));
  Result<std::shared_ptr<const api::PoseEngine>> engine = this->engine(request->rig_id());
  if (!engine.ok()) return call.done(to_grpc(engine.status()));
  put_rig(*stored, (*engine)->rig(), response);
  return call.done(grpc::Status::OK);
}

grpc::Status PosewarpService::ListRigs(grpc::ServerContext* context, const v1::ListRigsRequest* request,
                                       v1::ListRigsResponse* response) {
  Call call(*this, context, "ListRigs");
  if (call.refused()) return call.refusal();
  const int page = request->page_size() <= 0 ? 50 : std::min(request->page_size(), 1000);
  if (!request->page_token().empty() && !api::is_hex_id(request->page_token())) {
    return call.done({grpc::StatusCode::INVALID_ARGUMENT, "page_token is the next_page_token of a previous answer"});
  }
  Result<std::vector<RigRecord>> rows = store_->rigs(request->page_token(), page + 1);
  if (!rows.ok()) return call.done(to_grpc(rows.status()));
  for (const RigRecord& row : *rows) {
    if (response->rigs_size() == page) {
      response->set_next_page_token(response->rigs(page - 1).id());
      break;
    }
    put_rig_row(row, response->add_rigs());
  }
  return call.done(grpc::Status::OK);
}

grpc::Status PosewarpService::DeleteRig(grpc::ServerContext* context, const v1::GetRigRequest* request,
                                        v1::DeleteRigResponse*) {
  Call call(*this, context, "DeleteRig", request->rig_id());
  if (call.refused()) return call.refusal();
  evict(request->rig_id());  // poses holding the engine finish with it; new ones find no rig
  return call.done(to_grpc(store_->delete_rig(request->rig_id())));
}

grpc::Status PosewarpService::GetRigAssets(grpc::ServerContext* context, const v1::GetRigAssetsRequest* request,
                                           grpc::ServerWriter<v1::RigAsset>* writer) {
  Call call(*this, context, "GetRigAssets", request->rig_id());
  if (call.refused()) return call.refusal();
  if (!api::is_hex_id(request->rig_id())) {
    return call.done({grpc::StatusCode::INVALID_ARGUMENT, "a rig id is 64 lowercase hex digits"});
  }
  Result<std::shared_ptr<const api::PoseEngine>> engine = this->engine(request->rig_id());
  if (!engine.ok()) return call.done(to_grpc(engine.status()));
  const api::Rig& rig = (*engine)->rig();
  v1::RigAsset asset;
  put_skeleton(rig, asset.mutable_skeleton());
  if (!call.write(writer, asset)) return call.done(kClientGone);
  // Each surface's role, for a viewer: a bone segment's label, the skin (label 0), or another tissue.
  std::set<Label> bone_labels;
  for (const rig::Segment& segment : rig.skeleton.segments) bone_labels.insert(segment.labels.begin(), segment.labels.end());
  for (const surface::SurfaceMesh& mesh : rig.surfaces) {
    const std::string role = mesh.label == 0 ? "skin" : bone_labels.count(mesh.label) ? "bone" : "tissue";
    v1::RigAsset part;
    if (request->format() == v1::ASSET_FORMAT_VTP) {
      Result<std::string> vtp = api::surface_to_vtp_bytes(mesh);
      if (!vtp.ok()) return call.done(to_grpc(vtp.status()));
      part.mutable_vtp()->set_name(mesh.name);
      part.mutable_vtp()->set_label(mesh.label);
      part.mutable_vtp()->set_data(std::move(vtp).value());
      part.mutable_vtp()->set_role(role);
    } else {
      put_surface(mesh, true, part.mutable_surface());
      part.mutable_surface()->set_role(role);
    }
    if (!call.write(writer, part)) return call.done(kClientGone);
  }
  return call.done(grpc::Status::OK);
}

grpc::Status PosewarpService::DownloadRig(grpc::ServerContext* context, const v1::GetRigRequest* request,
                                          grpc::ServerWriter<v1::RigChunk>* writer) {
  Call call(*this, context, "DownloadRig", request->rig_id());
  if (call.refused()) return call.refusal();
  Result<RigRecord> stored = store_->rig(request->rig_id());
  if (!stored.ok()) return call.done(to_grpc(stored.status()));
  Result<ClientLimits::Entry> admitted = client_limits_.enter_call(call.client());
  if (!admitted.ok()) return call.done(to_grpc(admitted.status()));
  Result<MemoryBudget::Reservation> memory =
      reserve(context, static_cast<int64_t>(stored->size_bytes) * 3, "sending this rig");
  if (!memory.ok()) return call.done(to_grpc(memory.status()));
  Result<std::string> bytes = api::read_text_input(stored->path, "rig file", int64_t{1} << 40);
  if (!bytes.ok()) return call.done(to_grpc(bytes.status()));
  // The file as stored, checked first: a damaged rig is quarantined, never sent.
  if (Result<api::Rig> check = api::rig_from_bytes(*bytes, "rig " + stored->id); !check.ok()) {
    evict(stored->id);
    (void)store_->quarantine_rig(stored->id, check.status().message());
    return call.done({grpc::StatusCode::DATA_LOSS, "rig " + stored->id + " failed its checksums in the store and "
                                                   "was quarantined; build it again"});
  }
  const std::string sha = api::sha256_hex(*bytes);
  const bool sent = stream_chunks(bytes->data(), bytes->size(), uint64_t{1} << 20, [&](uint64_t offset, std::string data) {
    v1::RigChunk chunk;
    chunk.set_offset(offset);
    chunk.set_data(std::move(data));
    if (offset == 0) {
      chunk.set_size_bytes(bytes->size());
      chunk.set_sha256(sha);
    }
    return call.write(writer, chunk);
  });
  return call.done(sent ? grpc::Status::OK : kClientGone);
}

grpc::Status PosewarpService::UploadRig(grpc::ServerContext* context, grpc::ServerReader<v1::UploadRigRequest>* reader,
                                        v1::Rig* response) {
  Call call(*this, context, "UploadRig");
  if (call.refused()) return call.refusal();
  v1::UploadRigRequest part;
  if (!call.read(reader, &part)) return call.done(kClientGone);
  if (!part.has_header()) {
    return call.done({grpc::StatusCode::INVALID_ARGUMENT, "a rig upload starts with its header (size_bytes, sha256)"});
  }
  const v1::UploadRigHeader header = part.header();
  if (Status s = check_rig_upload_header(header, request_limits()); !s.ok()) return call.done(to_grpc(s));
  StagedUpload upload;
  if (grpc::Status s = stage_upload(call, reader, header.size_bytes(), header.sha256(), "upload.rig", &upload); !s.ok()) {
    return call.done(s);
  }
  const std::string& staged = upload.path;
  // The file's bytes and the rig read from them are in memory at once.
  Result<MemoryBudget::Reservation> memory =
      reserve(context, static_cast<int64_t>(header.size_bytes()) * 3, "this rig upload");
  if (!memory.ok()) return call.done(to_grpc(memory.status()));
  Result<std::string> read = api::read_text_input(staged, "rig upload", static_cast<int64_t>(header.size_bytes()));
  if (!read.ok()) return call.done(to_grpc(read.status()));
  const std::string& bytes = *read;
  Result<api::Rig> rig = api::rig_from_bytes(bytes, "uploaded rig");
  if (!rig.ok()) return call.done(to_grpc(rig.status()));
  RigRecord record;
  record.id = rig->id();
  call.set_rig(record.id);
  record.name = header.name();
  for (const auto& [stage, seconds] : rig->provenance.stage_seconds) record.build_seconds += seconds;
  if (!store_->rig(record.id).ok()) {
    if (Status s = store_->put_rig(record, bytes); !s.ok()) return call.done(to_grpc(s));
  }
  Result<RigRecord> stored = store_->rig(record.id);
  if (!stored.ok()) return call.done(to_grpc(stored.status()));
  put_rig(*stored, *rig, response);
  return call.done(grpc::Status::OK);
}

grpc::Status PosewarpService::Pose(grpc::ServerContext* context, const v1::PoseRequest* request,
                                   grpc::ServerWriter<v1::PoseResponse>* writer) {
  Call call(*this, context, "Pose", request->rig_id());
  if (call.refused()) return call.refusal();
  Result<CheckedPose> checked = check_pose_request(*request);
  if (!checked.ok()) return call.done(to_grpc(checked.status()));
  Result<ClientLimits::Entry> admitted = client_limits_.enter_call(call.client());
  if (!admitted.ok()) return call.done(to_grpc(admitted.status()));
  // A slot, or a place in the bounded queue, or RESOURCE_EXHAUSTED at once.
  {
    std::unique_lock<std::mutex> lock(mutex_);
    if (stopping_) return call.done({grpc::StatusCode::UNAVAILABLE, "the server is shutting down; try again shortly"});
    if (poses_running_ >= options_.pose_slots && poses_waiting_ >= options_.pose_queue) {
      return call.done({grpc::StatusCode::RESOURCE_EXHAUSTED, "the server is busy (" +
                                                                  std::to_string(options_.pose_queue) +
                                                                  " poses waiting); try again later"});
    }
    ++poses_waiting_;
    // Woken by a freed slot; the timeout notices a client that cancelled while waiting.
    while (poses_running_ >= options_.pose_slots && !context->IsCancelled()) {
      changed_.wait_for(lock, std::chrono::milliseconds(100));
    }
    --poses_waiting_;
    if (context->IsCancelled()) return call.done({grpc::StatusCode::CANCELLED, "the client cancelled the pose"});
    ++poses_running_;
  }
  // Given back as soon as the engine is done: sending what it made (under the stall watch) holds no slot.
  struct Slot {
    PosewarpService* service;
    bool held = true;
    void release() {
      if (!std::exchange(held, false)) return;
      {
        std::lock_guard<std::mutex> lock(service->mutex_);
        --service->poses_running_;
      }
      service->changed_.notify_all();
    }
    ~Slot() { release(); }
  } slot{this};
  if (options_.test_pause_in_pose_s > 0.0) {
    spdlog::info("test hook: pausing {:.1f} s inside a pose", options_.test_pause_in_pose_s);
    std::this_thread::sleep_for(std::chrono::duration<double>(options_.test_pause_in_pose_s));
  }

  Result<std::shared_ptr<const api::PoseEngine>> engine = this->engine(request->rig_id());
  if (!engine.ok()) return call.done(to_grpc(engine.status()));
  store_->touch_rig(request->rig_id());
  const api::Rig& rig = (*engine)->rig();
  api::PoseRequest core;
  core.pose = std::move(checked->pose);
  core.method = method_of(checked->method);
  core.fem.max_iterations = static_cast<int>(std::min<uint32_t>(request->fem().max_iterations(), 1u << 30));
  core.fem.volume_weight = request->fem().volume_weight();  // the engine refuses what is out of range
  core.grid = checked->grid == v1::GRID_POLICY_GROW    ? api::GridPolicy::kGrow
              : checked->grid == v1::GRID_POLICY_GIVEN ? api::GridPolicy::kGiven
                                                       : api::GridPolicy::kInput;
  core.given_grid = checked->given_grid;
  core.ct_interpolation = request->nearest_ct() ? resample::Interpolation::kNearest : resample::Interpolation::kLinear;
  core.want_labels = request->want_labels();
  core.want_ct = request->want_ct() && rig.ct.has_value();
  core.want_surfaces = request->want_surfaces();
  core.want_fields = request->want_fields();
  core.extra_surfaces = std::move(checked->meshes);
  // One pose's output is bounded by the request, the server's option and the whole memory budget, whichever is least.
  int64_t output_budget = memory_.total();
  if (options_.max_output_bytes > 0) output_budget = std::min(output_budget, options_.max_output_bytes);
  if (request->max_output_bytes() > 0) {
    output_budget = std::min(output_budget,
                             static_cast<int64_t>(std::min<uint64_t>(request->max_output_bytes(), uint64_t{1} << 62)));
  }
  core.resample.max_output_bytes = output_budget;
  core.resample.max_output_voxels = options_.max_output_voxels;
  Result<VolumeEncoding> encoding = volume_encoding(*request, rig);
  if (!encoding.ok()) return call.done(to_grpc(encoding.status()));
  Result<api::PosePlan> plan = (*engine)->plan(core);
  if (!plan.ok()) return call.done(to_grpc(server_limits_named(plan.status())));
  // The memory the pose will hold until its answer is sent: the engine's outputs, a file format's encoded copy of
  // each volume, and the skinned mesh with its report.
  const int64_t output_voxels = plan->output_grid.voxel_count();
  int64_t estimate =
      plan->output_bytes + rig.mesh.vertex_count() * 96 + rig.mesh.tet_count() * 48 + (int64_t{16} << 20);
  if (encoding->format) {
    if (core.want_labels) estimate += output_voxels * pixel_type_bytes(encoding->label_type);
    if (core.want_ct) estimate += output_voxels * pixel_type_bytes(encoding->ct_type);
  }
  Result<MemoryBudget::Reservation> memory = reserve(context, estimate, "this pose");
  if (!memory.ok()) return call.done(to_grpc(memory.status()));

  // The header first, from the plan: the client knows what follows before the engine starts.
  {
    v1::PoseResponse message;
    v1::PoseHeader* header = message.mutable_header();
    put_grid(plan->output_grid, header->mutable_grid());
    const uint64_t voxels = static_cast<uint64_t>(output_voxels);
    const bool raw = !encoding->format.has_value();
    if (core.want_labels && raw) header->set_label_bytes(voxels * static_cast<uint64_t>(pixel_type_bytes(encoding->label_type)));
    if (core.want_ct && raw) header->set_ct_bytes(voxels * static_cast<uint64_t>(pixel_type_bytes(encoding->ct_type)));
    header->set_surface_count(core.want_surfaces ? static_cast<int32_t>(rig.surfaces.size() + core.extra_surfaces.size())
                                                 : 0);
    header->set_label_pixel_type(std::string(pixel_type_name(rig.labels.source_type())));
    if (rig.ct) header->set_ct_pixel_type(std::string(pixel_type_name(rig.ct->source_type())));
    if (core.want_labels) header->set_label_sample_type(wire_pixel_type(encoding->label_type));
    if (core.want_ct) header->set_ct_sample_type(wire_pixel_type(encoding->ct_type));
    header->set_format(request->format());
    if (core.want_fields) {
      header->set_inverse_field_bytes(voxels * 12);
      header->set_forward_field_bytes(static_cast<uint64_t>(rig.labels.voxel_count()) * 12);
      put_grid(rig.labels.geometry(), header->mutable_source_grid());
    }
    if (!call.write(writer, message)) return call.done(kClientGone);
  }

  // Each volume is sent from its own thread as soon as the engine has it, while the engine goes on. A client that
  // stops reading is cancelled by the stall watch, which also stops the engine (its cancel hook).
  const uint64_t chunk = checked->chunk_bytes;
  const auto write = [&call, writer](const v1::PoseResponse& message) { return call.write(writer, message); };
  VolumeSender sender(write, *encoding, chunk);
  core.labels_ready = [&](std::shared_ptr<const LabelVolume> labels) {
    sender.send(std::move(labels), encoding->label_type, &v1::PoseResponse::mutable_labels);
  };
  core.ct_ready = [&](std::shared_ptr<const IntensityVolume> ct) {
    sender.send(std::move(ct), encoding->ct_type, &v1::PoseResponse::mutable_ct);
  };
  Result<api::PoseResult> result = (*engine)->pose(core, call_hooks(context));
  slot.release();
  const grpc::Status sent = sender.wait();
  if (call.stream().stalled()) return call.done(kClientGone);
  if (!result.ok()) return call.done(to_grpc(result.status()));
  if (!sent.ok()) return call.done(sent);
  if (core.want_fields) {
    const grpc::Status fields_sent = [&] {
      grpc::Status s =
          write_samples(write, result->inverse_field.data(), static_cast<int64_t>(result->inverse_field.size()),
                        PixelType::kFloat32, chunk, &v1::PoseResponse::mutable_inverse_field);
      if (!s.ok()) return s;
      return write_samples(write, result->forward_field.data(), static_cast<int64_t>(result->forward_field.size()),
                           PixelType::kFloat32, chunk, &v1::PoseResponse::mutable_forward_field);
    }();
    if (!fields_sent.ok()) return call.done(fields_sent);
  }
  for (const surface::SurfaceMesh& s : result->surfaces) {
    v1::PoseResponse m;
    put_surface(s, true, m.mutable_surface());
    if (!call.write(writer, m)) return call.done(kClientGone);
  }
  v1::PoseResponse last;
  put_report(result->report, last.mutable_report());
  call.write(writer, last);
  return call.done(grpc::Status::OK);
}

grpc::Status PosewarpService::Preview(grpc::ServerContext* context,
                                      grpc::ServerReaderWriter<v1::PreviewResponse, v1::PreviewRequest>* stream) {
  Call call(*this, context, "Preview");
  if (call.refused()) return call.refusal();
  const std::string client = call.client();
  {
    std::lock_guard<std::mutex> lock(mutex_);
    if (previews_by_client_[client] >= options_.preview_streams_per_client) {
      return call.done({grpc::StatusCode::RESOURCE_EXHAUSTED,
                        "this client has " + std::to_string(options_.preview_streams_per_client) +
                            " preview streams open already (the server's --preview-streams-per-client); close one"});
    }
    ++previews_by_client_[client];
  }
  struct Open {
    PosewarpService* service;
    std::string client;
    ~Open() {
      std::lock_guard<std::mutex> lock(service->mutex_);
      if (--service->previews_by_client_[client] <= 0) service->previews_by_client_.erase(client);
    }
  } open{this, client};
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
      if (!latest) return call.done(grpc::Status::OK);  // the client closed and everything was answered
      update = std::move(*latest);
      latest.reset();
      dropped = std::exchange(skipped, 0);
      if (update.rig_id().empty()) update.set_rig_id(rig_id);
    }
    metrics_.count("preview_updates");
    if (dropped > 0) metrics_.count("preview_updates_dropped", static_cast<int64_t>(dropped));
    if (context->IsCancelled()) return call.done({grpc::StatusCode::CANCELLED, "the client cancelled the preview"});
    // A refused update is answered with its code; the stream goes on (a slider's next move may be fine).
    auto refuse = [&](const grpc::Status& status) {
      v1::PreviewResponse answer;
      answer.set_sequence(update.sequence());
      answer.set_dropped(dropped);
      answer.set_error_code(static_cast<int32_t>(status.error_code()));
      answer.set_error_message(status.error_message());
      return call.write(stream, answer);
    };
    if (!engine) {
      call.set_rig(update.rig_id());
      Result<std::shared_ptr<const api::PoseEngine>> loaded =
          api::is_hex_id(update.rig_id())
              ? this->engine(update.rig_id())
              : Result<std::shared_ptr<const api::PoseEngine>>(
                    invalid_argument_error("the first preview update names the rig (64 hex digits)"));
      if (!loaded.ok()) {
        if (!refuse(to_grpc(loaded.status()))) return call.done(kClientGone);
        continue;
      }
      engine = *loaded;
    }
    const auto start = std::chrono::steady_clock::now();
    Result<api::Pose> pose = check_preview_request(update);
    Result<api::PreviewResult> preview =
        pose.ok() ? engine->preview(*pose, method_of(update.method())) : Result<api::PreviewResult>(pose.status());
    if (!preview.ok()) {
      if (!refuse(to_grpc(preview.status()))) return call.done(kClientGone);
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
      if (!topology_sent) put_surface(rest[i], false, answer.add_topology());
    }
    topology_sent = true;
    for (const Eigen::Vector3d& c : preview->joint_centres) {
      for (int a = 0; a < 3; ++a) answer.add_joint_centres(c[a]);
    }
    answer.set_server_ms(1000.0 * std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count());
    if (!call.write(stream, answer)) return call.done(kClientGone);
  }
}

}  // namespace posewarp::server
