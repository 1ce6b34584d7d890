// BVH joint maps (JSON): any bytes give a map or an error.
#include <cstddef>
#include <cstdint>
#include <string>

#include "posewarp/pose/bvh_map.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  (void)posewarp::pose::bvh_map_from_json(text, "fuzz");
  return 0;
}
