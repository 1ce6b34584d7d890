// Pose JSON: any bytes give a pose or an error, never a crash, a hang or an unbounded allocation.
#include <cstddef>
#include <cstdint>
#include <string>

#include "posewarp/pose/pose.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string text(reinterpret_cast<const char*>(data), size);
  const posewarp::Result<posewarp::pose::Pose> pose = posewarp::pose::pose_from_json(text, "fuzz");
  if (pose.ok()) (void)posewarp::pose::pose_to_json(*pose);
  return 0;
}
