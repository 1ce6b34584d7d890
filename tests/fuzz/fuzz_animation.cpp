// Animation JSON: any bytes give an animation or an error.
#include <cstddef>
#include <cstdint>
#include <string>

#include "posewarp/pose/animation.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  (void)posewarp::pose::animation_from_json(text, "fuzz");
  return 0;
}
