// The memory of volumes and per-voxel tables: large blocks kept when freed and handed out again for the same size.
#pragma once

#include <chrono>
#include <cstddef>
#include <cstdint>

namespace posewarp {

// A block of at least `bytes` for voxels (aligned as operator new aligns). A block of 8 MB or more that was freed
// with free_voxels and is still kept is handed out again: a service posing one rig again and again reuses its last
// outputs' pages instead of faulting in fresh ones (a first touch costs many times a write to pages already mapped).
// Throws std::bad_alloc.
void* allocate_voxels(size_t bytes);
// Gives a block from allocate_voxels back. Large blocks are kept, the oldest freed first when the kept total would
// pass the limit; the rest are freed.
void free_voxels(void* p, size_t bytes) noexcept;

// How many bytes of freed blocks are kept at most (default 512 MB; 0 keeps none and frees what is kept).
void set_voxel_memory_kept_limit(size_t bytes);
// Bytes kept now (for tests and the server's metrics).
size_t voxel_memory_kept();
// Frees the kept blocks that no allocation has taken for `unused_for` since they were freed, and returns their bytes:
// a service calls it now and then, so that an idle process gives the memory kept for a next pose back to the system.
size_t trim_voxel_memory(std::chrono::steady_clock::duration unused_for);

}  // namespace posewarp
