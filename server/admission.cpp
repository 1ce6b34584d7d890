// StallWatch, MemoryBudget and ClientLimits.
#include "admission.h"

#include <algorithm>

#include "posewarp/api/support.h"

namespace posewarp::server {
namespace {

int64_t now_ns() {
  return std::chrono::duration_cast<std::chrono::nanoseconds>(std::chrono::steady_clock::now().time_since_epoch())
      .count();
}

std::string megabytes(int64_t bytes) {
  return std::to_string((bytes + (1 << 20) - 1) >> 20) + " MB";
}

}  // namespace

StallWatch::StallWatch(std::chrono::milliseconds limit, std::function<void()> on_stall)
    : limit_(limit), on_stall_(std::move(on_stall)) {
  thread_ = std::thread([this] { run(); });
}

StallWatch::~StallWatch() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
  }
  stop_.notify_all();
  thread_.join();
}

std::unique_ptr<StallWatch::Stream> StallWatch::watch(grpc::ServerContext* context) {
  std::unique_ptr<Stream> stream(new Stream(this, context));
  std::lock_guard<std::mutex> lock(mutex_);
  streams_.insert(stream.get());
  return stream;
}

StallWatch::Stream::~Stream() {
  std::lock_guard<std::mutex> lock(watch_->mutex_);
  watch_->streams_.erase(this);
}

void StallWatch::Stream::begin() {
  if (depth_.fetch_add(1) == 0) since_ns_.store(now_ns());
}

void StallWatch::Stream::end() {
  if (depth_.fetch_sub(1) == 1) since_ns_.store(0);
}

void StallWatch::run() {
  // A tenth of the limit (at least 50 ms) between looks: a stalled stream is cancelled within 1.1 x the limit.
  const auto period = std::max(std::chrono::milliseconds(50), limit_ / 10);
  std::unique_lock<std::mutex> lock(mutex_);
  while (!stopping_) {
    stop_.wait_for(lock, period, [this] { return stopping_; });
    const int64_t now = now_ns();
    const int64_t limit = std::chrono::duration_cast<std::chrono::nanoseconds>(limit_).count();
    for (Stream* stream : streams_) {
      const int64_t since = stream->since_ns_.load();
      if (since == 0 || now - since < limit || stream->stalled_.load()) continue;
      stream->stalled_.store(true);
      stream->context_->TryCancel();  // the blocked Read or Write returns false; the call's hooks see the cancel
      if (on_stall_) on_stall_();
    }
  }
}

KeptOutputTrim::KeptOutputTrim(std::chrono::milliseconds idle) : idle_(idle) {
  if (idle_.count() > 0) thread_ = std::thread([this] { run(); });
}

KeptOutputTrim::~KeptOutputTrim() {
  {
    std::lock_guard<std::mutex> lock(mutex_);
    stopping_ = true;
  }
  stop_.notify_all();
  if (thread_.joinable()) thread_.join();
}

void KeptOutputTrim::run() {
  const auto period = std::max(std::chrono::milliseconds(100), idle_ / 4);
  std::unique_lock<std::mutex> lock(mutex_);
  while (!stopping_) {
    stop_.wait_for(lock, period, [this] { return stopping_; });
    (void)api::trim_voxel_memory(idle_);
  }
}

MemoryBudget::Reservation& MemoryBudget::Reservation::operator=(Reservation&& other) noexcept {
  if (this != &other) {
    release();
    budget_ = other.budget_;
    bytes_ = other.bytes_;
    other.budget_ = nullptr;
  }
  return *this;
}

void MemoryBudget::Reservation::release() {
  if (budget_ == nullptr) return;
  {
    std::lock_guard<std::mutex> lock(budget_->mutex_);
    budget_->used_ -= bytes_;
  }
  budget_->freed_.notify_all();
  budget_ = nullptr;
}

Result<MemoryBudget::Reservation> MemoryBudget::reserve(int64_t bytes, const std::string& what,
                                                        std::chrono::steady_clock::time_point until,
                                                        const std::function<bool()>& cancelled) {
  bytes = std::max<int64_t>(bytes, 0);
  if (bytes > total_) {
    return resource_exhausted_error(what + " needs about " + megabytes(bytes) + " of memory, more than this server's " +
                                    "whole budget of " + megabytes(total_) +
                                    " (its --memory-mb); ask for less (a coarser or smaller grid, no fields) or ask "
                                    "the operator");
  }
  std::unique_lock<std::mutex> lock(mutex_);
  // Woken by every release; the timeout also notices a caller that went away.
  while (used_ + bytes > total_) {
    if ((cancelled && cancelled()) || std::chrono::steady_clock::now() >= until) {
      return resource_exhausted_error("the server's memory is taken by other work (" + what + " needs about " +
                                      megabytes(bytes) + " of its " + megabytes(total_) + "); try again shortly");
    }
    freed_.wait_for(lock, std::chrono::milliseconds(100));
  }
  used_ += bytes;
  return Reservation(this, bytes);
}

int64_t MemoryBudget::used() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return used_;
}

ClientLimits::Entry::~Entry() {
  if (limits_ != nullptr) limits_->leave(*this);
}

Result<ClientLimits::Entry> ClientLimits::enter_call(const std::string& client) {
  return enter(client, false, 0);
}

Result<ClientLimits::Entry> ClientLimits::enter_upload(const std::string& client, int64_t declared_bytes) {
  return enter(client, true, declared_bytes);
}

Result<ClientLimits::Entry> ClientLimits::enter(const std::string& client, bool upload, int64_t declared_bytes) {
  std::lock_guard<std::mutex> lock(mutex_);
  const Counts counts = clients_.count(client) ? clients_[client] : Counts{};
  if (counts.calls >= options_.calls) {
    return resource_exhausted_error("this client has " + std::to_string(counts.calls) +
                                    " calls in progress, the most this server takes from one client (its "
                                    "--calls-per-client); wait for one to finish");
  }
  if (upload && counts.uploads >= options_.uploads) {
    return resource_exhausted_error("this client has " + std::to_string(counts.uploads) +
                                    " uploads in progress, the most this server takes at once from one client (its "
                                    "--uploads-per-client); send them one after another");
  }
  if (upload && counts.upload_bytes + declared_bytes > options_.upload_bytes) {
    return resource_exhausted_error("this client's uploads in progress would hold " +
                                    megabytes(counts.upload_bytes + declared_bytes) + ", over the " +
                                    megabytes(options_.upload_bytes) +
                                    " one client may have in flight (the server's --upload-mb-per-client); wait for "
                                    "an upload to finish");
  }
  Counts& held = clients_[client];  // made only for a client let in: a refused one leaves nothing behind
  ++held.calls;
  if (upload) {
    ++held.uploads;
    held.upload_bytes += declared_bytes;
  }
  Entry entry;
  entry.limits_ = this;
  entry.client_ = client;
  entry.upload_ = upload;
  entry.bytes_ = upload ? declared_bytes : 0;
  return entry;
}

void ClientLimits::leave(const Entry& entry) {
  std::lock_guard<std::mutex> lock(mutex_);
  const auto it = clients_.find(entry.client_);
  if (it == clients_.end()) return;
  --it->second.calls;
  if (entry.upload_) {
    --it->second.uploads;
    it->second.upload_bytes -= entry.bytes_;
  }
  if (it->second.calls <= 0) clients_.erase(it);
}

std::string client_of(const grpc::ServerContext& context) {
  const auto& metadata = context.client_metadata();
  const auto it = metadata.find("authorization");
  if (it != metadata.end() && !it->second.empty()) {
    return "token:" + sha256_hex(std::string(it->second.data(), it->second.size())).substr(0, 16);
  }
  const std::string peer = context.peer();
  const size_t colon = peer.rfind(':');
  return "peer:" + (colon == std::string::npos ? peer : peer.substr(0, colon));
}

}  // namespace posewarp::server
