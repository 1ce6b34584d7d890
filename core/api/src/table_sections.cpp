#include "table_sections.h"

#include <libdeflate.h>

#include <atomic>
#include <cstring>
#include <memory>

#include "posewarp/common/parallel.h"
#include "posewarp/resample/tet_warp.h"

namespace posewarp::api::internal {

Status check_engine_tables(const Rig& rig) {
  if (rig.rest_owner.empty() && rig.body_region.empty() && rig.bone_substitute.empty()) return ok_status();
  const auto voxels = static_cast<size_t>(rig.labels.voxel_count());
  if (rig.rest_owner.size() != voxels || rig.body_region.size() != voxels || rig.bone_substitute.size() != voxels) {
    return data_loss_error("rig's owner, region and substitute tables (sections OWNR, REGN, SUBS) do not hold one "
                           "value per voxel of its volumes; the file is damaged. Rebuild the rig");
  }
  const int64_t tets = rig.mesh.tet_count();
  const auto segments = static_cast<int64_t>(rig.skeleton.segments.size());
  std::atomic<bool> in_range{true};
  parallel_for(0, static_cast<int64_t>(voxels), int64_t{1} << 20, [&](int64_t begin, int64_t end) {
    bool ok = true;
    for (int64_t v = begin; v < end; ++v) {
      // A tet (>= 0), a tet's skin shell (-2 - tet), the background (-1) or nothing (kNoSample).
      const int64_t owner = rig.rest_owner[static_cast<size_t>(v)];
      const int16_t region = rig.body_region[static_cast<size_t>(v)];
      const int32_t substitute = rig.bone_substitute[static_cast<size_t>(v)];
      ok &= ((owner >= -1 - tets && owner < tets) || owner == resample::TetWarp::kNoSample) && region >= -1 &&
            region < segments && substitute >= 0 && static_cast<size_t>(substitute) < voxels;
    }
    if (!ok) in_range = false;
  });
  if (!in_range) {
    return data_loss_error("rig's owner, region or substitute table (sections OWNR, REGN, SUBS) names a tet, segment "
                           "or voxel the rig does not have; the file is damaged. Rebuild the rig");
  }
  return ok_status();
}

namespace {

// The count, then the values deflated (libdeflate's fastest level, zlib format).
template <typename T>
std::string table_section(const std::vector<T>& values) {
  const std::unique_ptr<libdeflate_compressor, decltype(&libdeflate_free_compressor)> compressor(
      libdeflate_alloc_compressor(1), &libdeflate_free_compressor);
  if (!compressor) throw std::bad_alloc();
  const size_t raw = values.size() * sizeof(T);
  std::string section(sizeof(uint64_t), '\0');
  const uint64_t count = values.size();
  std::memcpy(section.data(), &count, sizeof(count));
  const size_t bound = libdeflate_zlib_compress_bound(compressor.get(), raw);
  section.resize(sizeof(uint64_t) + bound);
  const size_t packed =
      libdeflate_zlib_compress(compressor.get(), values.data(), raw, section.data() + sizeof(uint64_t), bound);
  section.resize(sizeof(uint64_t) + packed);
  return section;
}

template <typename T>
Status read_table_section(std::string_view payload, const char* name, std::vector<T>& values) {
  uint64_t count = 0;
  if (payload.size() < sizeof(count)) return data_loss_error(std::string("rig section ") + name + " ends early");
  std::memcpy(&count, payload.data(), sizeof(count));
  const std::string_view packed = payload.substr(sizeof(count));
  // Deflate packs at most 1032:1: a count beyond that is damage, refused before the table is allocated.
  if (count > (packed.size() + 64) * 1032 / sizeof(T)) {
    return data_loss_error(std::string("rig section ") + name + " claims more values than its bytes can hold");
  }
  values.resize(static_cast<size_t>(count));
  if (!inflate_exactly(packed, values.data(), values.size() * sizeof(T))) {
    return data_loss_error(std::string("rig section ") + name + " does not decompress; the file is damaged");
  }
  return ok_status();
}

}  // namespace

bool inflate_exactly(std::string_view packed, void* out, size_t out_bytes) {
  const std::unique_ptr<libdeflate_decompressor, decltype(&libdeflate_free_decompressor)> decompressor(
      libdeflate_alloc_decompressor(), &libdeflate_free_decompressor);
  if (!decompressor) throw std::bad_alloc();
  return libdeflate_zlib_decompress(decompressor.get(), packed.data(), packed.size(), out, out_bytes, nullptr) ==
         LIBDEFLATE_SUCCESS;
}

std::string owner_section(const std::vector<int32_t>& owner) {
  std::vector<int32_t> delta(owner.size());
  int32_t last = 0;
  for (size_t v = 0; v < owner.size(); ++v) {
    delta[v] = static_cast<int32_t>(static_cast<uint32_t>(owner[v]) - static_cast<uint32_t>(last));
    last = owner[v];
  }
  return table_section(delta);
}

std::string region_section(const std::vector<int16_t>& region) { return table_section(region); }

std::string substitute_section(const std::vector<int32_t>& substitute) {
  std::vector<int32_t> offset(substitute.size());
  for (size_t v = 0; v < substitute.size(); ++v) {
    offset[v] = static_cast<int32_t>(static_cast<uint32_t>(substitute[v]) - static_cast<uint32_t>(v));
  }
  return table_section(offset);
}

Status read_owner_section(std::string_view payload, std::vector<int32_t>& owner) {
  POSEWARP_RETURN_IF_ERROR(read_table_section(payload, "OWNR", owner));
  uint32_t last = 0;
  for (int32_t& value : owner) {
    last += static_cast<uint32_t>(value);
    value = static_cast<int32_t>(last);
  }
  return ok_status();
}

Status read_region_section(std::string_view payload, std::vector<int16_t>& region) {
  return read_table_section(payload, "REGN", region);
}

Status read_substitute_section(std::string_view payload, std::vector<int32_t>& substitute) {
  POSEWARP_RETURN_IF_ERROR(read_table_section(payload, "SUBS", substitute));
  for (size_t v = 0; v < substitute.size(); ++v) {
    substitute[v] = static_cast<int32_t>(static_cast<uint32_t>(substitute[v]) + static_cast<uint32_t>(v));
  }
  return ok_status();
}

}  // namespace posewarp::api::internal
