// Pose slots and preview streams per client.
#include "slots.h"

#include <chrono>
#include <utility>

namespace posewarp::server {

void PoseSlots::Slot::release() {
  PoseSlots* slots = std::exchange(slots_, nullptr);
  if (slots == nullptr) return;
  {
    std::lock_guard<std::mutex> lock(slots->mutex_);
    --slots->running_;
  }
  slots->freed_.notify_all();
}

Result<PoseSlots::Slot> PoseSlots::acquire(const std::function<bool()>& cancelled) {
  std::unique_lock<std::mutex> lock(mutex_);
  if (stopping_) return unavailable_error("the server is shutting down; try again shortly");
  if (running_ >= slots_ && waiting_ >= queue_) {
    return resource_exhausted_error("the server is busy (" + std::to_string(queue_) +
                                    " poses waiting); try again later");
  }
  ++waiting_;
  // Woken by a freed slot; the timeout notices a client that cancelled while waiting.
  while (running_ >= slots_ && !cancelled()) freed_.wait_for(lock, std::chrono::milliseconds(100));
  --waiting_;
  if (cancelled()) return cancelled_error("the client cancelled the pose");
  ++running_;
  return Slot(this);
}

void PoseSlots::stop() {
  std::lock_guard<std::mutex> lock(mutex_);
  stopping_ = true;
}

int PoseSlots::running() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return running_;
}

int PoseSlots::waiting() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return waiting_;
}

PreviewStreams::Open::~Open() {
  if (streams_ == nullptr) return;
  std::lock_guard<std::mutex> lock(streams_->mutex_);
  if (--streams_->by_client_[client_] <= 0) streams_->by_client_.erase(client_);
}

Result<PreviewStreams::Open> PreviewStreams::open(const std::string& client) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (by_client_[client] >= per_client_) {
    return resource_exhausted_error("this client has " + std::to_string(per_client_) +
                                    " preview streams open already (the server's --preview-streams-per-client); "
                                    "close one");
  }
  ++by_client_[client];
  return Open(this, client);
}

int PreviewStreams::count() const {
  std::lock_guard<std::mutex> lock(mutex_);
  int open = 0;
  for (const auto& [client, n] : by_client_) open += n;
  return open;
}

}  // namespace posewarp::server
