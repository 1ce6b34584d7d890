#include "table_sections.h"

#include <libdeflate.h>

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdint>
#include <cstring>
#include <memory>

#include "posewarp/common/parallel.h"
#include "posewarp/resample/tet_warp.h"

namespace posewarp::api::internal {
namespace {

Status check_summary(const Rig& rig) {
  if (rig.tet_region.empty() && rig.rest_label_counts.empty() && !rig.ct_lowest) return ok_status();
  const auto segments = static_cast<int64_t>(rig.skeleton.segments.size());
  bool fits = static_cast<int64_t>(rig.tet_region.size()) == rig.mesh.tet_count() &&
              rig.ct_lowest.has_value() == rig.ct.has_value();
  for (const int16_t region : rig.tet_region) fits &= region >= -1 && region < segments;
  int64_t counted = 0;
  for (const auto& [label, count] : rig.rest_label_counts) {
    fits &= count > 0 && count <= rig.labels.voxel_count() - counted;
    counted += fits ? count : 0;
  }
  if (!fits || counted != rig.labels.voxel_count()) {
    return data_loss_error(
        "rig's engine summary (section ENGN) does not fit its mesh, skeleton and volumes; the "
        "file is damaged. Rebuild the rig");
  }
  return ok_status();
}

}  // namespace

Status check_engine_tables(const Rig& rig) {
  if (!rig.skin_vertex.empty() && static_cast<int64_t>(rig.skin_vertex.size()) != rig.mesh.vertex_count()) {
    return data_loss_error(
        "rig's skin table (section SKIN) does not hold one value per mesh vertex; the file is "
        "damaged. Rebuild the rig");
  }
  POSEWARP_RETURN_IF_ERROR(check_summary(rig));
  if (rig.rest_owner.empty() && rig.body_region.empty() && !rig.bone_substitute) return ok_status();
  const auto voxels = static_cast<size_t>(rig.labels.voxel_count());
  if (rig.rest_owner.size() != rig.labels.size() || rig.body_region.size() != rig.labels.size() ||
      rig.rest_owner.fill() != -1 || rig.body_region.fill() != -1 || !rig.bone_substitute ||
      rig.bone_substitute->voxel.size() != rig.bone_substitute->substitute.size()) {
    return data_loss_error("rig's owner, region and substitute tables (sections OWNR, REGN, SUBS) do not hold one "
                           "value per voxel of its volumes; the file is damaged. Rebuild the rig");
  }
  const int64_t tets = rig.mesh.tet_count();
  const auto segments = static_cast<int64_t>(rig.skeleton.segments.size());
  // The values the tables keep (every voxel off them holds -1, which both allow).
  std::atomic<bool> in_range{true};
  const int32_t* owners = rig.rest_owner.values();
  parallel_for(0, static_cast<int64_t>(rig.rest_owner.stored()), int64_t{1} << 20, [&](int64_t begin, int64_t end) {
    bool ok = true;
    for (int64_t v = begin; v < end; ++v) {
      // A tet (>= 0), a tet's skin shell (-2 - tet), the background (-1) or nothing (kNoSample).
      const int64_t owner = owners[v];
      ok &= (owner >= -1 - tets && owner < tets) || owner == resample::TetWarp::kNoSample;
    }
    if (!ok) in_range = false;
  });
  const int16_t* regions = rig.body_region.values();
  for (size_t v = 0; v < rig.body_region.stored(); ++v) {
    if (regions[v] < -1 || regions[v] >= segments) in_range = false;
  }
  bool ascending = true;
  const BoneSubstitutes& substitutes = *rig.bone_substitute;
  for (size_t e = 0; e < substitutes.voxel.size(); ++e) {
    const int32_t v = substitutes.voxel[e], s = substitutes.substitute[e];
    ascending &= v >= 0 && static_cast<size_t>(v) < voxels && (e == 0 || v > substitutes.voxel[e - 1]) && s >= 0 &&
                 static_cast<size_t>(s) < voxels;
  }
  if (!in_range || !ascending) {
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
struct Runs {
  std::vector<T> values;
  std::vector<uint32_t> lengths;

  // `length` more of `value`: the last run grows when it holds the same value.
  void extend(T value, uint32_t length) {
    if (length == 0) return;
    if (!values.empty() && values.back() == value && lengths.back() <= UINT32_MAX - length) {
      lengths.back() += length;
    } else {
      values.push_back(value);
      lengths.push_back(length);
    }
  }

  std::string packed(uint64_t count) const {
    const std::string packed_values = deflated(values.data(), values.size() * sizeof(T));
    std::string section;
    put<uint64_t>(section, count);
    put<uint64_t>(section, values.size());
    put<uint64_t>(section, packed_values.size());
    section += packed_values;
    section += deflated(lengths.data(), lengths.size() * sizeof(uint32_t));
    return section;
  }
};

template <typename T>
std::string runs_section(const std::vector<T>& values) {
  Runs<T> runs;
  for (const T& value : values) runs.extend(value, 1);
  return runs.packed(values.size());
}

// A table's runs, inflated and checked: a table of another size than the rig's grid (`voxels`) and runs that do not
// add up to it are refused before the runs are allocated.
template <typename T>
Result<Runs<T>> read_runs(std::string_view payload, const char* name, int64_t voxels) {
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
  Runs<T> out{std::vector<T>(static_cast<size_t>(runs)), std::vector<uint32_t>(static_cast<size_t>(runs))};
  if (!inflate_exactly(packed_values, out.values.data(), out.values.size() * sizeof(T)) ||
      !inflate_exactly(packed_lengths, out.lengths.data(), out.lengths.size() * sizeof(uint32_t))) {
    return damaged("does not decompress");
  }
  uint64_t total = 0;
  for (const uint32_t length : out.lengths) total += length;
  if (total != count) return damaged("has runs that do not add up to its values");
  return out;
}

// A table kept on its rows' spans as runs: each row's leading fill, its span's values, its trailing fill.
template <typename T>
std::string runs_section(const RowPacked<T>& table) {
  Runs<T> runs;
  const Index3& m = table.size();
  for (int64_t z = 0; z < m[2]; ++z) {
    for (int64_t y = 0; y < m[1]; ++y) {
      int64_t lo = 0, hi = 0;
      const T* span = table.row(y, z, lo, hi);
      runs.extend(table.fill(), static_cast<uint32_t>(lo));
      for (int64_t x = lo; x < hi; ++x) runs.extend(span[x - lo], 1);
      runs.extend(table.fill(), static_cast<uint32_t>(m[0] - hi));
    }
  }
  return runs.packed(static_cast<uint64_t>(table.voxel_count()));
}

// A runs section read straight onto the rows' spans of grid m (fill -1): the whole grid is never expanded.
template <typename T>
Status read_runs_section(std::string_view payload, const char* name, const Index3& m, RowPacked<T>& table) {
  const int64_t voxels = m[0] > 0 && m[1] > 0 && m[2] > 0 ? m[0] * m[1] * m[2] : -1;
  POSEWARP_ASSIGN_OR_RETURN(const Runs<T> runs, read_runs<T>(payload, name, voxels));
  table = RowPacked<T>::from_runs(runs.values.data(), runs.lengths.data(), runs.values.size(), m, T{-1});
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

std::string owner_section(const RowPacked<int32_t>& owner) {
  return runs_section(owner);
}

std::string region_section(const RowPacked<int16_t>& region) {
  return runs_section(region);
}

// Each substitute is stored as its offset from its own voxel: 0 but at the bones listed.
std::string substitute_section(const BoneSubstitutes& substitutes, int64_t voxels) {
  Runs<int32_t> runs;
  uint32_t at = 0;  // the first voxel not yet in a run
  for (size_t e = 0; e < substitutes.voxel.size(); ++e) {
    const auto v = static_cast<uint32_t>(substitutes.voxel[e]);
    runs.extend(0, v - at);
    runs.extend(static_cast<int32_t>(static_cast<uint32_t>(substitutes.substitute[e]) - v), 1);
    at = v + 1;
  }
  runs.extend(0, static_cast<uint32_t>(voxels) - at);
  return runs.packed(static_cast<uint64_t>(voxels));
}

std::string summary_section(const Rig& rig) {
  std::string section;
  put<uint64_t>(section, rig.rest_label_counts.size());
  for (const auto& [label, count] : rig.rest_label_counts) {
    put<int32_t>(section, label);
    put<int64_t>(section, count);
  }
  put<uint8_t>(section, rig.ct_lowest ? 1 : 0);
  put<float>(section, rig.ct_lowest.value_or(0.0f));
  const std::string regions = deflated(rig.tet_region.data(), rig.tet_region.size() * sizeof(int16_t));
  put<uint64_t>(section, rig.tet_region.size());
  put<uint64_t>(section, regions.size());
  return section + regions;
}

Status read_summary_section(std::string_view payload, Rig& rig) {
  auto damaged = [](const std::string& what) {
    return data_loss_error("rig section ENGN " + what + "; the file is damaged. Rebuild the rig");
  };
  size_t at = 0;
  auto get = [&](auto& value) {
    if (payload.size() - at < sizeof(value)) return false;
    std::memcpy(&value, payload.data() + at, sizeof(value));
    at += sizeof(value);
    return true;
  };
  uint64_t labels = 0;
  if (!get(labels) || labels > payload.size() / 12) return damaged("ends early");
  rig.rest_label_counts.clear();
  for (uint64_t e = 0; e < labels; ++e) {
    int32_t label = 0;
    int64_t count = 0;
    if (!get(label) || !get(count)) return damaged("ends early");
    if (!rig.rest_label_counts.emplace(label, count).second) return damaged("counts a label twice");
  }
  uint8_t has_ct = 0;
  float lowest = 0.0f;
  uint64_t tets = 0, packed = 0;
  if (!get(has_ct) || !get(lowest) || !get(tets) || !get(packed) || packed != payload.size() - at) {
    return damaged("ends early");
  }
  if (has_ct > 1 || std::isnan(lowest)) return damaged("holds a value out of its range");
  rig.ct_lowest.reset();
  if (has_ct) rig.ct_lowest = lowest;
  // Deflate packs at most 1032:1: more regions than that is damage, refused before they are allocated.
  if (tets / 1032 > (packed + 64) / sizeof(int16_t)) return damaged("claims more tets than it holds");
  rig.tet_region.resize(static_cast<size_t>(tets));
  if (!inflate_exactly(payload.substr(at), rig.tet_region.data(), rig.tet_region.size() * sizeof(int16_t))) {
    return damaged("does not decompress");
  }
  return ok_status();
}

Status read_owner_section(std::string_view payload, const Index3& grid, RowPacked<int32_t>& owner) {
  return read_runs_section(payload, "OWNR", grid, owner);
}

Status read_region_section(std::string_view payload, const Index3& grid, RowPacked<int16_t>& region) {
  return read_runs_section(payload, "REGN", grid, region);
}

Status read_substitute_section(std::string_view payload, int64_t voxels, BoneSubstitutes& substitutes) {
  POSEWARP_ASSIGN_OR_RETURN(const Runs<int32_t> runs, read_runs<int32_t>(payload, "SUBS", voxels));
  size_t listed = 0;
  for (size_t r = 0; r < runs.values.size(); ++r) listed += runs.values[r] != 0 ? runs.lengths[r] : 0;
  substitutes.voxel.clear();
  substitutes.substitute.clear();
  substitutes.voxel.reserve(listed);
  substitutes.substitute.reserve(listed);
  auto index = uint32_t{0};
  for (size_t r = 0; r < runs.values.size(); ++r) {
    const auto offset = static_cast<uint32_t>(runs.values[r]);
    if (offset == 0) {
      index += runs.lengths[r];
      continue;
    }
    for (uint32_t i = 0; i < runs.lengths[r]; ++i, ++index) {
      substitutes.voxel.push_back(static_cast<int32_t>(index));
      substitutes.substitute.push_back(static_cast<int32_t>(offset + index));
    }
  }
  return ok_status();
}

}  // namespace posewarp::api::internal
