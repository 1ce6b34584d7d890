// CompactIntensities: the intensities (CT in HU, MRI) a rig keeps, in two bytes a voxel where they fit.
#pragma once

#include <cstdint>
#include <utility>
#include <variant>

#include "posewarp/common/volume.h"

namespace posewarp {

// A volume of intensities held as int16 where every value is a whole number in int16's range (nearly every CT: what
// it was read from was int16, uint8 or int8), as float otherwise: a 20M-voxel CT in 40 MB instead of 80. The values
// are the float volume's exactly, so whatever samples it (the warp) gives the same bits either way. source_type() is
// the type the volume had on disk, whichever of the two holds it.
class CompactIntensities {
 public:
  CompactIntensities() = default;
  // Narrowed to int16 when every value comes back from int16 bit for bit (not -0.0, NaN or a fraction).
  explicit CompactIntensities(IntensityVolume volume);
  explicit CompactIntensities(Volume<int16_t> volume) : held_(std::move(volume)) {}

  const ImageGeometry& geometry() const {
    return std::visit([](const auto& v) -> const ImageGeometry& { return v.geometry(); }, held_);
  }
  PixelType source_type() const {
    return std::visit([](const auto& v) { return v.source_type(); }, held_);
  }
  int64_t voxel_count() const {
    return std::visit([](const auto& v) { return v.voxel_count(); }, held_);
  }
  bool empty() const { return voxel_count() == 0; }
  // Bytes of the voxels held.
  int64_t voxel_bytes() const {
    return voxel_count() * static_cast<int64_t>(as_int16() ? sizeof(int16_t) : sizeof(float));
  }

  // The volume held: one of the two is not null.
  const Volume<int16_t>* as_int16() const { return std::get_if<Volume<int16_t>>(&held_); }
  const IntensityVolume* as_float() const { return std::get_if<IntensityVolume>(&held_); }
  // A float copy (what a caller that reads floats, as ITK's resampler or the body mask, is given).
  IntensityVolume to_float() const;

  // f(volume) for the volume held, Volume<int16_t> or IntensityVolume.
  template <typename F>
  decltype(auto) visit(F&& f) const {
    return std::visit(std::forward<F>(f), held_);
  }

 private:
  std::variant<IntensityVolume, Volume<int16_t>> held_;
};

}  // namespace posewarp
