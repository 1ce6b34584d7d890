// Rig files: any bytes give a rig or an error, never a crash or a large allocation. A mutated rig would almost
// never get past its section checksums, so the target first recomputes every checksum and the end marker's content
// hash of whatever section frames it finds: mutations inside a payload then reach the section parsers and the
// consistency checks, which is where a crafted file (checksums recomputed by an attacker) would go.
// Seeds: small rig files (tests/fuzz/corpus/rig_file).
#include <cstddef>
#include <cstdint>
#include <string>

#include "posewarp/api/rig_file.h"
#include "rig_bytes_support.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  const std::string bytes(reinterpret_cast<const char*>(data), size);
  (void)posewarp::api::rig_from_bytes(posewarp::testing::with_rig_checksums(bytes), "fuzz input");
  return 0;
}
