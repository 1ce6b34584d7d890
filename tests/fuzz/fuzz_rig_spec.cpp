// Rig spec JSON: any bytes give a spec or an error.
#include <cstddef>
#include <cstdint>
#include <string>

#include "posewarp/rig/skeleton.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  (void)posewarp::rig::rig_spec_from_json(text, "fuzz");
  return 0;
}
