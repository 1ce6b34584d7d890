// SHA-256 (OpenSSL's EVP), for content ids: rig ids, uploaded volume ids, upload checks.
#pragma once

#include <cstddef>
#include <memory>
#include <string>
#include <string_view>

namespace posewarp {

class Sha256 {
 public:
  Sha256();
  ~Sha256();
  Sha256(const Sha256&) = delete;
  Sha256& operator=(const Sha256&) = delete;

  Sha256& update(const void* data, size_t size);
  Sha256& update(std::string_view text) { return update(text.data(), text.size()); }
  // 64 lowercase hex digits; the hasher is spent afterwards.
  std::string hex_digest();

 private:
  struct State;
  std::unique_ptr<State> state_;
};

std::string sha256_hex(std::string_view bytes);

// True for a string of exactly `digits` lowercase hex digits (ids handed in by clients are checked with this
// before they name anything).
bool is_hex_id(std::string_view text, size_t digits = 64);

}  // namespace posewarp
