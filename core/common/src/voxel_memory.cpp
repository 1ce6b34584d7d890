// Freed voxel blocks kept for reuse (see voxel_memory.h).
#include "posewarp/common/voxel_memory.h"

#include <deque>
#include <mutex>
#include <new>

namespace posewarp {
namespace {

constexpr size_t kKeptFrom = size_t{8} << 20;

struct Kept {
  void* block;
  size_t bytes;
  std::chrono::steady_clock::time_point freed;
};

struct Cache {
  std::mutex lock;
  std::deque<Kept> blocks;  // oldest first
  size_t total = 0;
  size_t limit = size_t{512} << 20;

  // Frees the oldest block; returns its bytes. Called with the lock held, blocks not empty.
  size_t free_oldest() {
    const size_t bytes = blocks.front().bytes;
    ::operator delete(blocks.front().block);
    total -= bytes;
    blocks.pop_front();
    return bytes;
  }

  // Frees the oldest blocks until `room` more bytes fit under the limit. Called with the lock held.
  void make_room(size_t room) {
    while (!blocks.empty() && total + room > limit) free_oldest();
  }
};

Cache& cache() {
  static Cache* c = new Cache();  // never destroyed: blocks may be freed by static destructors after main
  return *c;
}

}  // namespace

void* allocate_voxels(size_t bytes) {
  if (bytes >= kKeptFrom) {
    Cache& c = cache();
    const std::lock_guard<std::mutex> guard(c.lock);
    for (auto it = c.blocks.rbegin(); it != c.blocks.rend(); ++it) {  // the newest of that size: its pages are warmest
      if (it->bytes == bytes) {
        void* block = it->block;
        c.total -= bytes;
        c.blocks.erase(std::next(it).base());
        return block;
      }
    }
  }
  return ::operator new(bytes);
}

void free_voxels(void* p, size_t bytes) noexcept {
  if (!p) return;
  if (bytes >= kKeptFrom) {
    Cache& c = cache();
    const std::lock_guard<std::mutex> guard(c.lock);
    if (bytes <= c.limit) {
      c.make_room(bytes);
      c.blocks.push_back({p, bytes, std::chrono::steady_clock::now()});
      c.total += bytes;
      return;
    }
  }
  ::operator delete(p);
}

void set_voxel_memory_kept_limit(size_t bytes) {
  Cache& c = cache();
  const std::lock_guard<std::mutex> guard(c.lock);
  c.limit = bytes;
  c.make_room(0);
}

size_t voxel_memory_kept() {
  Cache& c = cache();
  const std::lock_guard<std::mutex> guard(c.lock);
  return c.total;
}

size_t trim_voxel_memory(std::chrono::steady_clock::duration unused_for) {
  Cache& c = cache();
  const std::lock_guard<std::mutex> guard(c.lock);
  // Blocks are kept in the order they were freed: the ones unused for that long are at the front.
  const auto before = std::chrono::steady_clock::now() - unused_for;
  size_t freed = 0;
  while (!c.blocks.empty() && c.blocks.front().freed <= before) freed += c.free_oldest();
  return freed;
}

}  // namespace posewarp
