// The service's two counted resources, each under its own mutex: pose slots with their bounded queue, and the preview
// streams each client has open.
#pragma once

#include <condition_variable>
#include <functional>
#include <map>
#include <mutex>
#include <string>
#include <utility>

#include "posewarp/api/files.h"

namespace posewarp::server {

// Poses running at once (`slots`), and how many may wait for one (`queue`); past that RESOURCE_EXHAUSTED at once.
class PoseSlots {
 public:
  // Held while the engine poses; given back by release() (as soon as the engine is done) or at the latest by the
  // destructor.
  class Slot {
   public:
    Slot(Slot&& other) noexcept : slots_(std::exchange(other.slots_, nullptr)) {}
    Slot& operator=(Slot&&) = delete;
    ~Slot() { release(); }
    void release();

   private:
    friend class PoseSlots;
    explicit Slot(PoseSlots* slots) : slots_(slots) {}
    PoseSlots* slots_;
  };

  PoseSlots(int slots, int queue) : slots_(slots), queue_(queue) {}
  // A slot, waiting in the queue for one; UNAVAILABLE once stopped, RESOURCE_EXHAUSTED when the queue is full,
  // CANCELLED when `cancelled()` turns true while waiting.
  Result<Slot> acquire(const std::function<bool()>& cancelled);
  // Refuses every later acquire(); poses holding a slot finish.
  void stop();
  int running() const;
  int waiting() const;

 private:
  const int slots_;
  const int queue_;
  mutable std::mutex mutex_;
  std::condition_variable freed_;
  bool stopping_ = false;
  int running_ = 0;
  int waiting_ = 0;
};

// Preview streams open per client, at most `per_client` each.
class PreviewStreams {
 public:
  // One open stream, counted until it is destroyed.
  class Open {
   public:
    Open(Open&& other) noexcept : streams_(std::exchange(other.streams_, nullptr)), client_(std::move(other.client_)) {}
    Open& operator=(Open&&) = delete;
    ~Open();

   private:
    friend class PreviewStreams;
    Open(PreviewStreams* streams, std::string client) : streams_(streams), client_(std::move(client)) {}
    PreviewStreams* streams_;
    std::string client_;
  };

  explicit PreviewStreams(int per_client) : per_client_(per_client) {}
  // RESOURCE_EXHAUSTED naming --preview-streams-per-client when `client` has as many open already.
  Result<Open> open(const std::string& client);
  int count() const;

 private:
  const int per_client_;
  mutable std::mutex mutex_;
  std::map<std::string, int> by_client_;
};

}  // namespace posewarp::server
