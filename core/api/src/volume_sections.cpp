#include "volume_sections.h"

#include <libdeflate.h>

#include <algorithm>
#include <atomic>
#include <cstring>
#include <memory>
#include <vector>

#include "posewarp/common/parallel.h"
#include "table_sections.h"

namespace posewarp::api::internal {
namespace {

// Samples per chunk: 1M (1 to 4 MB) keeps every thread busy on a small study and costs nothing in ratio.
constexpr int64_t kChunkVoxels = int64_t{1} << 20;
// The grid, the source type: where both formats begin.
constexpr size_t kGridBytes = 3 * 8 + 3 * 8 + 3 * 8 + 9 * 8 + 4;

// The type a volume's samples are read into.
template <typename T>
constexpr PixelType native_type() {
  if constexpr (std::is_same_v<T, float>) return PixelType::kFloat32;
  if constexpr (std::is_same_v<T, int16_t>) return PixelType::kInt16;
  return PixelType::kInt32;
}
// The type its samples are stored in where its source's will not do: int16 intensities as the float volume of the
// same values would store them, so that the section's bytes do not depend on which of the two holds them.
template <typename T>
constexpr PixelType fallback_type() {
  return std::is_same_v<T, int16_t> ? PixelType::kFloat32 : native_type<T>();
}

void put_grid(std::string& out, const ImageGeometry& g, PixelType source) {
  auto put = [&out](const auto& value) { out.append(reinterpret_cast<const char*>(&value), sizeof(value)); };
  for (const int64_t n : g.size) put(n);
  for (const double s : g.spacing) put(s);
  for (const double o : g.origin) put(o);
  for (const double d : g.direction) put(d);
  put(static_cast<int32_t>(source));
}

// Reads plain values from a payload, front to back; false past its end.
class Cursor {
 public:
  explicit Cursor(std::string_view bytes) : bytes_(bytes) {}
  template <typename V>
  bool get(V& value) {
    if (bytes_.size() - at_ < sizeof(V)) return false;
    std::memcpy(&value, bytes_.data() + at_, sizeof(V));
    at_ += sizeof(V);
    return true;
  }
  uint64_t left() const { return bytes_.size() - at_; }
  bool get_view(std::string_view& view, uint64_t size) {
    if (size > bytes_.size() - at_) return false;
    view = bytes_.substr(at_, size);
    at_ += size;
    return true;
  }

 private:
  std::string_view bytes_;
  size_t at_ = 0;
};

bool get_grid(Cursor& in, ImageGeometry& g, int32_t& source) {
  for (int64_t& n : g.size) if (!in.get(n)) return false;
  for (double& s : g.spacing) if (!in.get(s)) return false;
  for (double& o : g.origin) if (!in.get(o)) return false;
  for (double& d : g.direction) if (!in.get(d)) return false;
  return in.get(source);
}

bool is_pixel_type(int32_t type) { return type >= 0 && type <= static_cast<int32_t>(PixelType::kFloat64); }

// Each chunk of `volume` stored as `type`, deflated; false when a value does not come back exactly from `type`.
template <typename T>
bool deflate_chunks(const Volume<T>& volume, PixelType type, std::vector<std::string>& chunks) {
  const int64_t voxels = volume.voxel_count();
  chunks.assign(static_cast<size_t>((voxels + kChunkVoxels - 1) / kChunkVoxels), std::string());
  const int bytes = pixel_type_bytes(type);
  std::atomic<bool> exact{true};
  parallel_for(0, static_cast<int64_t>(chunks.size()), 1, [&](int64_t begin, int64_t end) {
    const std::unique_ptr<libdeflate_compressor, decltype(&libdeflate_free_compressor)> compressor(
        libdeflate_alloc_compressor(1), &libdeflate_free_compressor);
    if (!compressor) throw std::bad_alloc();
    std::vector<char> stored;
    std::vector<T> back;
    for (int64_t c = begin; c < end && exact; ++c) {
      const int64_t first = c * kChunkVoxels, n = std::min(kChunkVoxels, voxels - first);
      const T* values = volume.data() + first;
      if (type != native_type<T>()) {
        stored.resize(static_cast<size_t>(n * bytes));
        // From int16 a conversion that fits is exact (the other types hold the value or refuse it); from int32 or
        // float it is checked by reading the samples back.
        bool fits = convert_samples(values, n, type, stored.data());
        if constexpr (!std::is_same_v<T, int16_t>) {
          back.resize(static_cast<size_t>(n));
          fits =
              fits && read_samples(stored.data(), n, type, back.data()) && std::equal(back.begin(), back.end(), values);
        }
        if (!fits) {
          exact = false;
          break;
        }
        values = nullptr;
      }
      const char* raw = values ? reinterpret_cast<const char*>(values) : stored.data();
      std::string& chunk = chunks[static_cast<size_t>(c)];
      chunk.resize(libdeflate_zlib_compress_bound(compressor.get(), static_cast<size_t>(n * bytes)));
      chunk.resize(libdeflate_zlib_compress(compressor.get(), raw, static_cast<size_t>(n * bytes), chunk.data(),
                                            chunk.size()));
    }
  });
  return exact;
}

template <typename T>
Status read_format_1(Cursor& in, const std::string& name, const ImageGeometry& g, Volume<T>& volume) {
  uint64_t raw = 0, size = 0;
  std::string_view packed;
  if (!in.get(raw) || !in.get(size) || !in.get_view(packed, size)) {
    return data_loss_error("rig section " + name + " ends early; the file is damaged");
  }
  if (raw != static_cast<uint64_t>(g.voxel_count()) * sizeof(T)) {
    return data_loss_error("rig section " + name + " describes an inconsistent volume");
  }
  // zlib cannot pack more than 1032:1, so a claim beyond that is damage, refused before the volume is allocated.
  if (raw / 1032 > packed.size() + 64) {
    return data_loss_error("rig section " + name + " claims " + std::to_string(raw) + " bytes from " +
                           std::to_string(packed.size()) + " compressed bytes; the file is damaged");
  }
  volume = Volume<T>(g);
  if (!inflate_exactly(packed, volume.data(), static_cast<size_t>(raw))) {
    return data_loss_error("rig section " + name + " does not decompress; the file is damaged");
  }
  return ok_status();
}

template <typename T>
Status read_format_2(Cursor& in, const std::string& name, const ImageGeometry& g, Volume<T>& volume) {
  auto damaged = [&name](const std::string& what) {
    return data_loss_error("rig section " + name + " " + what + "; the file is damaged");
  };
  int32_t stored = 0;
  uint64_t chunk_voxels = 0, chunks = 0;
  if (!in.get(stored) || !in.get(chunk_voxels) || !in.get(chunks)) return damaged("ends early");
  const auto voxels = static_cast<uint64_t>(g.voxel_count());
  // Chunks of at most 2^40 voxels, so that no chunk count or offset below overflows.
  if (!is_pixel_type(stored) || chunk_voxels == 0 || chunk_voxels > (uint64_t{1} << 40) ||
      chunks != (voxels + chunk_voxels - 1) / chunk_voxels) {
    return damaged("describes an inconsistent volume");
  }
  const auto type = static_cast<PixelType>(stored);
  const auto bytes = static_cast<uint64_t>(pixel_type_bytes(type));
  if (chunks > voxels) return damaged("describes an inconsistent volume");
  std::vector<uint64_t> sizes(static_cast<size_t>(chunks));
  uint64_t total = 0;
  for (uint64_t& size : sizes) {
    if (!in.get(size) || size > in.left()) return damaged("ends early");
    total += size;
  }
  std::vector<std::string_view> packed(sizes.size());
  for (size_t c = 0; c < sizes.size(); ++c) {
    if (!in.get_view(packed[c], sizes[c])) return damaged("ends early");
  }
  // Deflate packs at most 1032:1: a grid beyond what the chunks can hold is refused before it is allocated.
  if (voxels / 1032 > (total + 64 * chunks) / bytes) {
    return damaged("claims more voxels than its compressed bytes can hold");
  }
  volume = Volume<T>(g);
  std::atomic<bool> whole{true};
  parallel_for(0, static_cast<int64_t>(packed.size()), 1, [&](int64_t begin, int64_t end) {
    std::vector<char> buffer;
    for (int64_t c = begin; c < end; ++c) {
      const auto first = static_cast<int64_t>(static_cast<uint64_t>(c) * chunk_voxels);
      const int64_t n = std::min(static_cast<int64_t>(chunk_voxels), volume.voxel_count() - first);
      T* out = volume.data() + first;
      if (type == native_type<T>()) {
        whole = whole && inflate_exactly(packed[static_cast<size_t>(c)], out, static_cast<size_t>(n) * sizeof(T));
      } else {
        buffer.resize(static_cast<size_t>(n) * bytes);
        whole = whole && inflate_exactly(packed[static_cast<size_t>(c)], buffer.data(), buffer.size()) &&
                read_samples(buffer.data(), n, type, out);
      }
    }
  });
  if (!whole) return damaged("does not decompress");
  return ok_status();
}

}  // namespace

template <typename T>
std::string volume_section(const Volume<T>& volume) {
  std::string section;
  put_grid(section, volume.geometry(), volume.source_type());
  // The source's type when every value comes back from it exactly (64-bit types are never read as samples).
  const PixelType source = volume.source_type();
  std::vector<std::string> chunks;
  PixelType stored = pixel_type_bytes(source) < 8 ? source : fallback_type<T>();
  if (!deflate_chunks(volume, stored, chunks)) {
    stored = fallback_type<T>();
    deflate_chunks(volume, stored, chunks);
  }
  auto put = [&section](const auto& value) { section.append(reinterpret_cast<const char*>(&value), sizeof(value)); };
  put(static_cast<int32_t>(stored));
  put(static_cast<uint64_t>(kChunkVoxels));
  put(static_cast<uint64_t>(chunks.size()));
  for (const std::string& chunk : chunks) put(static_cast<uint64_t>(chunk.size()));
  for (const std::string& chunk : chunks) section += chunk;
  return section;
}

template <typename T>
Status read_volume_section(std::string_view payload, const std::string& name, uint32_t format, Volume<T>& volume) {
  Cursor in(payload);
  ImageGeometry g;
  int32_t source = 0;
  if (!get_grid(in, g, source)) return data_loss_error("rig section " + name + " ends early; the file is damaged");
  if (!g.validate().ok() || !is_pixel_type(source)) {
    return data_loss_error("rig section " + name + " describes an inconsistent volume");
  }
  POSEWARP_RETURN_IF_ERROR(format == 1 ? read_format_1(in, name, g, volume) : read_format_2(in, name, g, volume));
  volume.set_source_type(static_cast<PixelType>(source));
  return ok_status();
}

std::string intensity_section(const CompactIntensities& intensities) {
  return intensities.visit([](const auto& volume) { return volume_section(volume); });
}

Status read_intensity_section(std::string_view payload, const std::string& name, uint32_t format,
                              CompactIntensities& intensities) {
  Cursor in(payload);
  ImageGeometry g;
  int32_t source = 0, stored = 0;
  const bool narrow =
      format == 2 && get_grid(in, g, source) && in.get(stored) &&
      (stored == static_cast<int32_t>(PixelType::kInt16) || stored == static_cast<int32_t>(PixelType::kUInt8) ||
       stored == static_cast<int32_t>(PixelType::kInt8));
  auto read_into = [&](auto volume) -> Status {
    POSEWARP_RETURN_IF_ERROR(read_volume_section(payload, name, format, volume));
    intensities = CompactIntensities(std::move(volume));
    return ok_status();
  };
  return narrow ? read_into(Volume<int16_t>()) : read_into(IntensityVolume());
}

template std::string volume_section(const Volume<Label>&);
template std::string volume_section(const Volume<float>&);
template std::string volume_section(const Volume<int16_t>&);
template Status read_volume_section(std::string_view, const std::string&, uint32_t, Volume<Label>&);
template Status read_volume_section(std::string_view, const std::string&, uint32_t, Volume<float>&);
template Status read_volume_section(std::string_view, const std::string&, uint32_t, Volume<int16_t>&);

}  // namespace posewarp::api::internal
