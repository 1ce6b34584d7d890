// Pixel type names and ranges.
#include "posewarp/common/volume.h"

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

}  // namespace posewarp
