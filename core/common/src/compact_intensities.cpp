#include "posewarp/common/compact_intensities.h"

#include <algorithm>
#include <atomic>
#include <bit>

#include "posewarp/common/parallel.h"

namespace posewarp {

CompactIntensities::CompactIntensities(IntensityVolume volume) {
  const float* in = volume.data();
  std::atomic<bool> fits{true};
  // Comparing the bits, not the values: -0.0 or NaN does not come back from int16.
  parallel_for(0, volume.voxel_count(), int64_t{1} << 18, [&](int64_t begin, int64_t end) {
    for (int64_t v = begin; v < end && fits; ++v) {
      const float x = in[v];
      if (!(x >= -32768.0f && x <= 32767.0f) ||
          std::bit_cast<uint32_t>(static_cast<float>(static_cast<int16_t>(x))) != std::bit_cast<uint32_t>(x)) {
        fits = false;
      }
    }
  });
  if (!fits) {
    held_ = std::move(volume);
    return;
  }
  Volume<int16_t> narrow(volume.geometry());
  int16_t* out = narrow.data();
  parallel_for(0, volume.voxel_count(), int64_t{1} << 18, [&](int64_t begin, int64_t end) {
    std::transform(in + begin, in + end, out + begin, [](float x) { return static_cast<int16_t>(x); });
  });
  narrow.set_source_type(volume.source_type());
  held_ = std::move(narrow);
}

IntensityVolume CompactIntensities::to_float() const {
  if (const IntensityVolume* floats = as_float()) return *floats;
  const Volume<int16_t>& narrow = *as_int16();
  IntensityVolume out(narrow.geometry());
  const int16_t* in = narrow.data();
  float* dst = out.data();
  parallel_for(0, narrow.voxel_count(), int64_t{1} << 18, [&](int64_t begin, int64_t end) {
    std::transform(in + begin, in + end, dst + begin, [](int16_t x) { return static_cast<float>(x); });
  });
  out.set_source_type(narrow.source_type());
  return out;
}

}  // namespace posewarp
