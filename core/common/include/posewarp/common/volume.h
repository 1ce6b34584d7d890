// Volume<T>: a typed, contiguous 3D image with physical geometry; LabelVolume and IntensityVolume.
#pragma once

#include <algorithm>
#include <cstddef>
#include <cstdint>
#include <memory>
#include <new>
#include <string_view>
#include <type_traits>
#include <utility>
#include <vector>

#include "posewarp/common/image_geometry.h"
#include "posewarp/common/parallel.h"
#include "posewarp/common/voxel_memory.h"

namespace posewarp {

// The voxel type a volume had on disk, kept so that writing gives back what was read.
enum class PixelType { kUInt8, kInt8, kUInt16, kInt16, kUInt32, kInt32, kUInt64, kInt64, kFloat32, kFloat64 };

std::string_view pixel_type_name(PixelType type);
bool is_floating(PixelType type);
// Smallest and largest value the type holds.
double pixel_type_min(PixelType type);
double pixel_type_max(PixelType type);
// Bytes of one sample.
int pixel_type_bytes(PixelType type);
// n values stored as `type` into out (n * pixel_type_bytes(type) bytes, little-endian), as volume files store them:
// rounded to the nearest integer for integer types. False when a value does not fit the type (it is stored as 0):
// the caller reports it, nothing is clipped silently.
bool convert_samples(const int32_t* in, int64_t n, PixelType type, char* out);
bool convert_samples(const float* in, int64_t n, PixelType type, char* out);
bool convert_samples(const int16_t* in, int64_t n, PixelType type, char* out);
// The other way: n little-endian samples of `type` read into out. False for 64-bit integer types (not read).
bool read_samples(const char* in, int64_t n, PixelType type, int32_t* out);
bool read_samples(const char* in, int64_t n, PixelType type, float* out);
// Into int16 only from the types int16 holds every value of (uint8, int8, int16); false for the others.
bool read_samples(const char* in, int64_t n, PixelType type, int16_t* out);

// The allocator of a volume's voxels: blocks from allocate_voxels (a pose's outputs reuse the last pose's pages).
// Elements it constructs without a value are left uninitialised: a Volume fills its voxels itself on every thread, so
// that a 20M-voxel output is not written by one thread before the parallel warp starts.
template <typename T>
struct VoxelAllocator {
  using value_type = T;
  VoxelAllocator() = default;
  template <typename U>
  VoxelAllocator(const VoxelAllocator<U>&) noexcept {}  // NOLINT(google-explicit-constructor): as std::allocator
  T* allocate(size_t n) {
    if (n > std::allocator_traits<std::allocator<T>>::max_size(std::allocator<T>())) throw std::bad_array_new_length();
    return static_cast<T*>(allocate_voxels(n * sizeof(T)));
  }
  void deallocate(T* p, size_t n) noexcept { free_voxels(p, n * sizeof(T)); }
  template <typename U>
  void construct(U* p) noexcept(std::is_nothrow_default_constructible_v<U>) {
    ::new (static_cast<void*>(p)) U;  // default-initialised: no write for arithmetic types
  }
  template <typename U, typename... Args>
  void construct(U* p, Args&&... args) {
    ::new (static_cast<void*>(p)) U(std::forward<Args>(args)...);
  }
  friend bool operator==(const VoxelAllocator&, const VoxelAllocator&) { return true; }
  friend bool operator!=(const VoxelAllocator&, const VoxelAllocator&) { return false; }
};

template <typename T>
using VoxelVector = std::vector<T, VoxelAllocator<T>>;

template <typename T>
class Volume {
 public:
  using value_type = T;

  Volume() = default;
  // Every voxel `fill`, written on all threads.
  explicit Volume(ImageGeometry geometry, T fill = T{})
      : geometry_(geometry), voxels_(static_cast<size_t>(geometry.voxel_count())) {
    T* voxels = voxels_.data();
    parallel_for(0, voxel_count(), int64_t{1} << 18,
                 [&](int64_t begin, int64_t end) { std::fill(voxels + begin, voxels + end, fill); });
  }

  const ImageGeometry& geometry() const { return geometry_; }
  // Changes placement only (origin, spacing, direction); the size must stay the same.
  void set_placement(const ImageGeometry& geometry) {
    const Index3 size = geometry_.size;
    geometry_ = geometry;
    geometry_.size = size;
  }

  const Index3& size() const { return geometry_.size; }
  int64_t voxel_count() const { return static_cast<int64_t>(voxels_.size()); }
  bool empty() const { return voxels_.empty(); }

  T* data() { return voxels_.data(); }
  const T* data() const { return voxels_.data(); }
  VoxelVector<T>& voxels() { return voxels_; }
  const VoxelVector<T>& voxels() const { return voxels_; }

  T& at(int64_t i, int64_t j, int64_t k) { return voxels_[static_cast<size_t>(geometry_.offset(i, j, k))]; }
  const T& at(int64_t i, int64_t j, int64_t k) const {
    return voxels_[static_cast<size_t>(geometry_.offset(i, j, k))];
  }
  bool contains(int64_t i, int64_t j, int64_t k) const {
    return i >= 0 && j >= 0 && k >= 0 && i < geometry_.size[0] && j < geometry_.size[1] && k < geometry_.size[2];
  }

  PixelType source_type() const { return source_type_; }
  void set_source_type(PixelType type) { source_type_ = type; }

 private:
  ImageGeometry geometry_;
  VoxelVector<T> voxels_;
  PixelType source_type_ = default_source_type();

  static constexpr PixelType default_source_type() {
    if constexpr (std::is_same_v<T, float>) return PixelType::kFloat32;
    if constexpr (std::is_same_v<T, double>) return PixelType::kFloat64;
    if constexpr (std::is_same_v<T, uint8_t>) return PixelType::kUInt8;
    if constexpr (std::is_same_v<T, int16_t>) return PixelType::kInt16;
    if constexpr (std::is_same_v<T, uint16_t>) return PixelType::kUInt16;
    return PixelType::kInt32;
  }
};

// Labels are held as int32 whatever their type on disk (uint8 ... int32); source_type() remembers that type.
using Label = int32_t;
using LabelVolume = Volume<Label>;
// Intensities (CT in HU, MRI) are held as float; source_type() remembers the type on disk.
using IntensityVolume = Volume<float>;

}  // namespace posewarp
