// Recomputes the checksums of a rig file's bytes after a test or a fuzzer changed a payload: what an attacker who
// crafts a rig would do, so that the section parsers and consistency checks (not the checksums) must refuse it.
#pragma once

#include <cstdint>
#include <cstdlib>
#include <cstring>
#include <string>

#include "posewarp/api/rig.h"

namespace posewarp::testing {

// Walks the section frames (u32 tag | u32 flags | u64 size | u64 checksum | payload) from the header on, rewrites
// each checksum and the end marker's content hash; stops quietly where the framing itself is broken.
inline std::string with_rig_checksums(std::string file) {
  auto hash = [](const std::string& bytes) {
    return std::strtoull(api::hash_bytes(bytes.data(), bytes.size()).c_str(), nullptr, 16);
  };
  auto put64 = [&file](size_t at, uint64_t value) { std::memcpy(file.data() + at, &value, 8); };
  std::string digest;
  size_t offset = 16;
  while (offset + 24 <= file.size()) {
    uint64_t size = 0;
    std::memcpy(&size, file.data() + offset + 8, 8);
    const std::string name = file.substr(offset, 4);
    if (name == "END!") {
      put64(offset + 16, hash(digest));
      break;
    }
    if (size > file.size() - offset - 24) break;
    const std::string payload = file.substr(offset + 24, size);
    put64(offset + 16, hash(payload));
    if (name != "PROV") digest += name + api::hash_bytes(payload.data(), payload.size());
    offset += 24 + size;
  }
  return file;
}

}  // namespace posewarp::testing
