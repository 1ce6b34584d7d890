// Pixel type names and ranges.
#include "posewarp/common/volume.h"

#include <bit>
#include <cmath>
#include <cstring>
#include <limits>

namespace posewarp {

std::string_view pixel_type_name(PixelType type) {
  switch (type) {
    case PixelType::kUInt8: return "uint8";
    case PixelType::kInt8: return "int8";
    case PixelType::kUInt16: return "uint16";
    case PixelType::kInt16: return "int16";
    case PixelType::kUInt32: return "uint32";
    case PixelType::kInt32: return "int32";
    case PixelType::kUInt64: return "uint64";
    case PixelType::kInt64: return "int64";
    case PixelType::kFloat32: return "float32";
    case PixelType::kFloat64: return "float64";
  }
  return "unknown";
}

bool is_floating(PixelType type) { return type == PixelType::kFloat32 || type == PixelType::kFloat64; }

namespace {
template <typename T>
constexpr double lowest() {
  return static_cast<double>(std::numeric_limits<T>::lowest());
}
template <typename T>
constexpr double highest() {
  return static_cast<double>(std::numeric_limits<T>::max());
}
}  // namespace

double pixel_type_min(PixelType type) {
  switch (type) {
    case PixelType::kUInt8: return lowest<uint8_t>();
    case PixelType::kInt8: return lowest<int8_t>();
    case PixelType::kUInt16: return lowest<uint16_t>();
    case PixelType::kInt16: return lowest<int16_t>();
    case PixelType::kUInt32: return lowest<uint32_t>();
    case PixelType::kInt32: return lowest<int32_t>();
    case PixelType::kUInt64: return lowest<uint64_t>();
    case PixelType::kInt64: return lowest<int64_t>();
    case PixelType::kFloat32: return lowest<float>();
    case PixelType::kFloat64: return lowest<double>();
  }
  return 0.0;
}

double pixel_type_max(PixelType type) {
  switch (type) {
    case PixelType::kUInt8: return highest<uint8_t>();
    case PixelType::kInt8: return highest<int8_t>();
    case PixelType::kUInt16: return highest<uint16_t>();
    case PixelType::kInt16: return highest<int16_t>();
    case PixelType::kUInt32: return highest<uint32_t>();
    case PixelType::kInt32: return highest<int32_t>();
    case PixelType::kUInt64: return highest<uint64_t>();
    case PixelType::kInt64: return highest<int64_t>();
    case PixelType::kFloat32: return highest<float>();
    case PixelType::kFloat64: return highest<double>();
  }
  return 0.0;
}

int pixel_type_bytes(PixelType type) {
  switch (type) {
    case PixelType::kUInt8:
    case PixelType::kInt8: return 1;
    case PixelType::kUInt16:
    case PixelType::kInt16: return 2;
    case PixelType::kUInt32:
    case PixelType::kInt32:
    case PixelType::kFloat32: return 4;
    case PixelType::kUInt64:
    case PixelType::kInt64:
    case PixelType::kFloat64: return 8;
  }
  return 0;
}

namespace {

static_assert(std::endian::native == std::endian::little, "samples are written in the machine's byte order");

template <typename Out, typename In>
bool convert_to(const In* in, int64_t n, char* out) {
  // Each sample through memcpy: `out` need not be aligned (a file's header may come before it).
  auto put = [out](int64_t v, Out value) { std::memcpy(out + v * static_cast<int64_t>(sizeof(Out)), &value, sizeof(Out)); };
  if constexpr (std::is_same_v<Out, In>) {
    std::memcpy(out, in, static_cast<size_t>(n) * sizeof(In));
    return true;
  } else if constexpr (std::is_floating_point_v<Out>) {
    for (int64_t v = 0; v < n; ++v) put(v, static_cast<Out>(in[v]));
    return true;
  } else {
    constexpr double lo = static_cast<double>(std::numeric_limits<Out>::lowest());
    constexpr double hi = static_cast<double>(std::numeric_limits<Out>::max());
    bool fits = true;
    for (int64_t v = 0; v < n; ++v) {
      double value = static_cast<double>(in[v]);
      if constexpr (std::is_floating_point_v<In>) {
        // Half away from zero, as std::round, without a libm call per voxel: d +- 0.5 is exact for any float, and
        // the cast truncates toward zero. Anything in (lo - 1, hi + 1) truncates into [lo, hi]; NaN fits nothing.
        value = value >= 0.0 ? value + 0.5 : value - 0.5;
        const bool ok = value > lo - 1.0 && value < hi + 1.0;
        fits &= ok;
        put(v, ok ? static_cast<Out>(value) : Out{0});
      } else {
        const bool ok = value >= lo && value <= hi;
        fits &= ok;
        put(v, ok ? static_cast<Out>(in[v]) : Out{0});
      }
    }
    return fits;
  }
}

template <typename In>
bool convert_any(const In* in, int64_t n, PixelType type, char* out) {
  switch (type) {
    case PixelType::kUInt8: return convert_to<uint8_t>(in, n, out);
    case PixelType::kInt8: return convert_to<int8_t>(in, n, out);
    case PixelType::kUInt16: return convert_to<uint16_t>(in, n, out);
    case PixelType::kInt16: return convert_to<int16_t>(in, n, out);
    case PixelType::kUInt32: return convert_to<uint32_t>(in, n, out);
    case PixelType::kInt32: return convert_to<int32_t>(in, n, out);
    case PixelType::kUInt64: return convert_to<uint64_t>(in, n, out);
    case PixelType::kInt64: return convert_to<int64_t>(in, n, out);
    case PixelType::kFloat32: return convert_to<float>(in, n, out);
    case PixelType::kFloat64: return convert_to<double>(in, n, out);
  }
  return false;
}

template <typename Sample, typename Out>
void read_as(const char* in, int64_t n, Out* out) {
  for (int64_t i = 0; i < n; ++i) {
    Sample value;
    std::memcpy(&value, in + i * static_cast<int64_t>(sizeof(Sample)), sizeof(Sample));
    out[i] = static_cast<Out>(value);
  }
}

template <typename Out>
bool read_any(const char* in, int64_t n, PixelType type, Out* out) {
  switch (type) {
    case PixelType::kUInt8: read_as<uint8_t>(in, n, out); return true;
    case PixelType::kInt8: read_as<int8_t>(in, n, out); return true;
    case PixelType::kUInt16: read_as<uint16_t>(in, n, out); return true;
    case PixelType::kInt16: read_as<int16_t>(in, n, out); return true;
    case PixelType::kUInt32: read_as<uint32_t>(in, n, out); return true;
    case PixelType::kInt32: read_as<int32_t>(in, n, out); return true;
    case PixelType::kFloat32: read_as<float>(in, n, out); return true;
    case PixelType::kFloat64: read_as<double>(in, n, out); return true;
    default: return false;
  }
}

}  // namespace

bool read_samples(const char* in, int64_t n, PixelType type, int32_t* out) { return read_any(in, n, type, out); }
bool read_samples(const char* in, int64_t n, PixelType type, float* out) { return read_any(in, n, type, out); }
bool read_samples(const char* in, int64_t n, PixelType type, int16_t* out) {
  const bool fits = type == PixelType::kUInt8 || type == PixelType::kInt8 || type == PixelType::kInt16;
  return fits && read_any(in, n, type, out);
}

bool convert_samples(const int32_t* in, int64_t n, PixelType type, char* out) { return convert_any(in, n, type, out); }
bool convert_samples(const float* in, int64_t n, PixelType type, char* out) { return convert_any(in, n, type, out); }
bool convert_samples(const int16_t* in, int64_t n, PixelType type, char* out) {
  return convert_any(in, n, type, out);
}

}  // namespace posewarp
