// Admission under slow and hostile clients: a stall watch that cancels a call whose stream makes no progress, a
// memory budget shared by every pose and upload (and the kept pose outputs given back when idle), and per-client
// limits on concurrent calls, uploads and upload bytes in flight. No gRPC service logic here; the service asks and
// gets a reservation or a refusal.
#pragma once

#include <grpcpp/server_context.h>

#include <atomic>
#include <chrono>
#include <condition_variable>
#include <cstdint>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <set>
#include <string>
#include <thread>

#include "posewarp/api/files.h"

namespace posewarp::server {

// Watches the reads and writes of every open stream: one that blocks longer than `limit` (a client that stopped
// reading its answer, or stopped sending its upload) has its call cancelled (ServerContext::TryCancel), which ends
// the blocked Read or Write and whatever work the call was doing.
class StallWatch {
 public:
  class Stream {
   public:
    ~Stream();
    Stream(const Stream&) = delete;
    Stream& operator=(const Stream&) = delete;
    // Runs one blocking stream operation (a Read or Write) under the watch; its result as it is.
    template <typename Operation>
    bool io(Operation&& operation) {
      begin();
      const bool ok = operation();
      end();
      return ok;
    }
    // The call was cancelled by the watch.
    bool stalled() const { return stalled_.load(); }

   private:
    friend class StallWatch;
    Stream(StallWatch* watch, grpc::ServerContext* context) : watch_(watch), context_(context) {}
    void begin();
    void end();
    StallWatch* watch_;
    grpc::ServerContext* context_;
    std::atomic<int> depth_{0};         // operations in progress (the volume sender may overlap the call's own)
    std::atomic<int64_t> since_ns_{0};  // steady-clock time the oldest one started; 0: none
    std::atomic<bool> stalled_{false};
  };

  // `on_stall` is called (on the watch's thread) each time a stream is cancelled.
  StallWatch(std::chrono::milliseconds limit, std::function<void()> on_stall);
  ~StallWatch();
  StallWatch(const StallWatch&) = delete;
  StallWatch& operator=(const StallWatch&) = delete;

  std::unique_ptr<Stream> watch(grpc::ServerContext* context);
  std::chrono::milliseconds limit() const { return limit_; }

 private:
  void run();
  std::chrono::milliseconds limit_;
  std::function<void()> on_stall_;
  std::mutex mutex_;
  std::condition_variable stop_;
  bool stopping_ = false;
  std::set<Stream*> streams_;
  std::thread thread_;
};

// Gives the pose outputs kept for a next pose (posewarp/api/support.h) back to the system once no pose has taken them
// for `idle`: a server that was busy and then waits keeps no more than it needs. Looks every quarter of `idle` (at
// least every 100 ms) from a thread of its own; an idle time of 0 (nothing is kept) starts none.
class KeptOutputTrim {
 public:
  explicit KeptOutputTrim(std::chrono::milliseconds idle);
  ~KeptOutputTrim();
  KeptOutputTrim(const KeptOutputTrim&) = delete;
  KeptOutputTrim& operator=(const KeptOutputTrim&) = delete;

 private:
  void run();
  const std::chrono::milliseconds idle_;
  std::mutex mutex_;
  std::condition_variable stop_;
  bool stopping_ = false;
  std::thread thread_;
};

// Bytes of memory that poses and uploads in flight may hold together. A request reserves its estimate before it
// allocates; one larger than the whole budget is refused at once, others wait for room (until their deadline).
class MemoryBudget {
 public:
  class Reservation {
   public:
    Reservation() = default;
    Reservation(Reservation&& other) noexcept : budget_(other.budget_), bytes_(other.bytes_) {
      other.budget_ = nullptr;
    }
    Reservation& operator=(Reservation&& other) noexcept;
    ~Reservation() { release(); }
    int64_t bytes() const { return bytes_; }
    void release();

   private:
    friend class MemoryBudget;
    Reservation(MemoryBudget* budget, int64_t bytes) : budget_(budget), bytes_(bytes) {}
    MemoryBudget* budget_ = nullptr;
    int64_t bytes_ = 0;
  };

  explicit MemoryBudget(int64_t total_bytes) : total_(total_bytes) {}
  // `bytes` for `what` ("this pose's output"): at once when there is room; RESOURCE_EXHAUSTED when it exceeds the
  // whole budget, or when no room came before `until` or `cancelled()` turned true.
  Result<Reservation> reserve(int64_t bytes, const std::string& what, std::chrono::steady_clock::time_point until,
                              const std::function<bool()>& cancelled);
  int64_t total() const { return total_; }
  int64_t used() const;

 private:
  int64_t total_;
  mutable std::mutex mutex_;
  std::condition_variable freed_;
  int64_t used_ = 0;
};

// Per-client limits. A client is its bearer token when it sent one (so clients behind one proxy are told apart),
// else its address.
struct ClientLimitOptions {
  // Generous enough for many users behind one proxy without tokens (all one address): a hostile client is held by
  // the memory budget and the stall watch first, these keep it from taking every slot and queue place.
  int calls = 64;                           // concurrent heavy calls (poses, uploads, downloads)
  int uploads = 16;                         // concurrent uploads (volumes and rigs)
  int64_t upload_bytes = int64_t{4} << 30;  // the declared sizes of a client's open uploads together
};

class ClientLimits {
 public:
  // Held for the length of a call; gives back what it took.
  class Entry {
   public:
    Entry() = default;
    Entry(Entry&& other) noexcept
        : limits_(other.limits_), client_(std::move(other.client_)), upload_(other.upload_), bytes_(other.bytes_) {
      other.limits_ = nullptr;
    }
    Entry& operator=(Entry&&) = delete;
    ~Entry();

   private:
    friend class ClientLimits;
    ClientLimits* limits_ = nullptr;
    std::string client_;
    bool upload_ = false;
    int64_t bytes_ = 0;
  };

  explicit ClientLimits(ClientLimitOptions options) : options_(options) {}
  // A heavy call of `client`; RESOURCE_EXHAUSTED naming the option when the client is at its limit.
  Result<Entry> enter_call(const std::string& client);
  // An upload of `declared_bytes` (also a call).
  Result<Entry> enter_upload(const std::string& client, int64_t declared_bytes);

 private:
  struct Counts {
    int calls = 0;
    int uploads = 0;
    int64_t upload_bytes = 0;
  };
  Result<Entry> enter(const std::string& client, bool upload, int64_t declared_bytes);
  void leave(const Entry& entry);
  ClientLimitOptions options_;
  std::mutex mutex_;
  std::map<std::string, Counts> clients_;
};

// Who a call comes from, for the per-client limits and never for a log: a digest of its bearer token when it sent
// one, else the host of its peer address.
std::string client_of(const grpc::ServerContext& context);

}  // namespace posewarp::server
