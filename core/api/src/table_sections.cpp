#include "table_sections.h"

#include <libdeflate.h>

#include <atomic>
#include <algorithm>
#include <cstdint>
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

std::string deflated(const void* bytes, size_t size) {
  const std::unique_ptr<libdeflate_compressor, decltype(&libdeflate_free_compressor)> compressor(
      libdeflate_alloc_compressor(1), &libdeflate_free_compressor);
  if (!compressor) throw std::bad_alloc();
  std::string packed(libdeflate_zlib_compress_bound(compressor.get(), size), '\0');
  packed.resize(libdeflate_zlib_compress(compressor.get(), bytes, size, packed.data(), packed.size()));
  return packed;
}

template <typename T>
void put(std::string& out, T value) {
  out.append(reinterpret_cast<const char*>(&value), sizeof(T));
}

// A table as runs of equal values (a tet owns a few voxels in a row, a region or an offset of 0 thousands): the value
// count, the run count, then the runs' values and their lengths, each deflated (libdeflate's fastest level, zlib
// format). Filling runs is several times faster than inflating every value.
template <typename T>
std::string runs_section(const std::vector<T>& values) {
  std::vector<T> run_values;
  std::vector<uint32_t> run_lengths;
  for (size_t v = 0; v < values.size();) {
    size_t end = v + 1;
    while (end < values.size() && values[end] == values[v] && end - v < UINT32_MAX) ++end;
    run_values.push_back(values[v]);
    run_lengths.push_back(static_cast<uint32_t>(end - v));
    v = end;
  }
  const std::string packed_values = deflated(run_values.data(), run_values.size() * sizeof(T));
  std::string section;
  put<uint64_t>(section, values.size());
  put<uint64_t>(section, run_values.size());
  put<uint64_t>(section, packed_values.size());
  section += packed_values;
  section += deflated(run_lengths.data(), run_lengths.size() * sizeof(uint32_t));
  return section;
}

// Refuses a table of another size than the rig's grid (`voxels`) and runs that do not add up to it, before the
// table is allocated.
// With `plus_index`, each value is stored as its offset from its own index (the substitutes: 0 but at bones).
template <typename T>
Status read_runs_section(std::string_view payload, const char* name, int64_t voxels, std::vector<T>& values,
                         bool plus_index = false) {
  auto damaged = [name](const std::string& what) {
    return data_loss_error(std::string("rig section ") + name + " " + what + "; the file is damaged. Rebuild the rig");
  };
  uint64_t count = 0, runs = 0, values_bytes = 0;
  if (payload.size() < 24) return damaged("ends early");
  std::memcpy(&count, payload.data(), 8);
  std::memcpy(&runs, payload.data() + 8, 8);
  std::memcpy(&values_bytes, payload.data() + 16, 8);
  if (count != static_cast<uint64_t>(voxels)) return damaged("does not hold one value per voxel of the rig's grid");
  if (values_bytes > payload.size() - 24 || runs > count) return damaged("declares more than it holds");
  const std::string_view packed_values = payload.substr(24, values_bytes);
  const std::string_view packed_lengths = payload.substr(24 + values_bytes);
  // Deflate packs at most 1032:1: a run count beyond that is damage, refused before the runs are allocated.
  if (runs > (packed_lengths.size() + 64) * 1032 / sizeof(uint32_t)) return damaged("claims more runs than it holds");
  std::vector<T> run_values(static_cast<size_t>(runs));
  std::vector<uint32_t> run_lengths(static_cast<size_t>(runs));
  if (!inflate_exactly(packed_values, run_values.data(), run_values.size() * sizeof(T)) ||
      !inflate_exactly(packed_lengths, run_lengths.data(), run_lengths.size() * sizeof(uint32_t))) {
    return damaged("does not decompress");
  }
  uint64_t total = 0;
  for (const uint32_t length : run_lengths) total += length;
  if (total != count) return damaged("has runs that do not add up to its values");
  values.resize(static_cast<size_t>(count));
  T* out = values.data();
  if (!plus_index) {
    for (size_t r = 0; r < run_values.size(); ++r) out = std::fill_n(out, run_lengths[r], run_values[r]);
    return ok_status();
  }
  auto index = uint32_t{0};
  for (size_t r = 0; r < run_values.size(); ++r) {
    const auto offset = static_cast<uint32_t>(run_values[r]);
    for (uint32_t i = 0; i < run_lengths[r]; ++i) *out++ = static_cast<T>(offset + index++);
  }
  return ok_status();
}

// Substitutes as offsets from their own voxel: 0 for every voxel but the bones'.
std::vector<int32_t> offsets(const std::vector<int32_t>& values) {
  std::vector<int32_t> offset(values.size());
  for (size_t v = 0; v < values.size(); ++v) {
    offset[v] = static_cast<int32_t>(static_cast<uint32_t>(values[v]) - static_cast<uint32_t>(v));
  }
  return offset;
}

}  // namespace

bool inflate_exactly(std::string_view packed, void* out, size_t out_bytes) {
  const std::unique_ptr<libdeflate_decompressor, decltype(&libdeflate_free_decompressor)> decompressor(
      libdeflate_alloc_decompressor(), &libdeflate_free_decompressor);
  if (!decompressor) throw std::bad_alloc();
  return libdeflate_zlib_decompress(decompressor.get(), packed.data(), packed.size(), out, out_bytes, nullptr) ==
         LIBDEFLATE_SUCCESS;
}

std::string owner_section(const std::vector<int32_t>& owner) { return runs_section(owner); }

std::string region_section(const std::vector<int16_t>& region) { return runs_section(region); }

std::string substitute_section(const std::vector<int32_t>& substitute) {
  return runs_section(offsets(substitute));
}

Status read_owner_section(std::string_view payload, int64_t voxels, std::vector<int32_t>& owner) {
  return read_runs_section(payload, "OWNR", voxels, owner);
}

Status read_region_section(std::string_view payload, int64_t voxels, std::vector<int16_t>& region) {
  return read_runs_section(payload, "REGN", voxels, region);
}

Status read_substitute_section(std::string_view payload, int64_t voxels, std::vector<int32_t>& substitute) {
  return read_runs_section(payload, "SUBS", voxels, substitute, true);
}

}  // namespace posewarp::api::internal
