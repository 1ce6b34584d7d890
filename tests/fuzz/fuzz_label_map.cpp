// Label map JSON: any bytes give a map or an error; a map writes back and reads again.
#include <cstddef>
#include <cstdint>
#include <cstdlib>
#include <string>

#include "posewarp/labels/label_map.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  const posewarp::Result<posewarp::labels::LabelMap> map = posewarp::labels::label_map_from_json(text, "fuzz");
  if (map.ok() && !posewarp::labels::label_map_from_json(posewarp::labels::label_map_to_json(*map), "again").ok()) {
    std::abort();  // what we write, we must read
  }
  return 0;
}
