// DICOM UIDs under a root: random (UUID version 4) or derived from a seed (version 8), in the "2.25" decimal form.
#include <algorithm>
#include <array>
#include <cstdint>
#include <mutex>
#include <random>
#include <string>

#include "posewarp/common/sha256.h"
#include "posewarp/dicom/ct_series.h"

namespace posewarp::dicom {
namespace {

// 128 bits as a UUID of `version` (4: random, 8: derived from a name), written as one decimal integer (the "2.25"
// UID form).
std::string uuid_decimal(std::array<uint32_t, 4> limbs, uint32_t version) {
  limbs[1] = (limbs[1] & 0xFFFF0FFFu) | (version << 12);  // the version (bits 48-51 of the UUID)
  limbs[2] = (limbs[2] & 0x3FFFFFFFu) | 0x80000000u;      // variant 10
  std::string digits;
  while (std::any_of(limbs.begin(), limbs.end(), [](uint32_t l) { return l != 0; })) {
    uint64_t remainder = 0;
    for (uint32_t& limb : limbs) {  // most significant first
      const uint64_t value = (remainder << 32) | limb;
      limb = static_cast<uint32_t>(value / 10);
      remainder = value % 10;
    }
    digits.push_back(static_cast<char>('0' + remainder));
  }
  std::reverse(digits.begin(), digits.end());
  return digits.empty() ? "0" : digits;
}

std::array<uint32_t, 4> random_bits() {
  static std::mutex mutex;
  static std::random_device device;
  std::array<uint32_t, 4> limbs;
  std::lock_guard<std::mutex> lock(mutex);
  for (uint32_t& limb : limbs) limb = device();
  return limbs;
}

std::array<uint32_t, 4> bits_of(const std::string& text) {
  const std::string hex = sha256_hex(text);
  std::array<uint32_t, 4> limbs;
  for (size_t i = 0; i < 4; ++i) limbs[i] = static_cast<uint32_t>(std::stoul(hex.substr(8 * i, 8), nullptr, 16));
  return limbs;
}

bool valid_uid_root(const std::string& root) {
  if (root.empty() || root.size() > 40 || root.front() == '.' || root.back() == '.') return false;
  for (size_t i = 0; i < root.size(); ++i) {
    const char c = root[i];
    if (c == '.') {
      if (root[i - 1] == '.') return false;
    } else if (c < '0' || c > '9') {
      return false;
    } else if (c == '0' && (i == 0 || root[i - 1] == '.') && i + 1 < root.size() && root[i + 1] != '.') {
      return false;  // a component with a leading zero
    }
  }
  return true;
}

// A UID cut to DICOM's 64 characters, ending neither in a dot nor in a component cut down to a leading zero.
std::string within_64(std::string uid) {
  if (uid.size() > 64) uid.resize(64);
  while (uid.back() == '.' || (uid.size() > 1 && uid[uid.size() - 1] == '0' && uid[uid.size() - 2] == '.'))
    uid.pop_back();
  return uid;
}

}  // namespace

Result<std::string> new_uid(const std::string& root) {
  if (!valid_uid_root(root)) {
    return invalid_argument_error("'" + root +
                                  "' is not a UID root: digits in dot-separated components without "
                                  "leading zeros, at most 40 characters (e.g. 2.25 or your organisation's root)");
  }
  return within_64(root + "." + uuid_decimal(random_bits(), 4));
}

Result<std::string> uid_for(const DerivedSeriesOptions& options, const std::string& purpose) {
  if (options.uid_seed.empty()) return new_uid(options.uid_root);
  if (!valid_uid_root(options.uid_root)) return new_uid(options.uid_root);  // its message
  return within_64(options.uid_root + "." + uuid_decimal(bits_of(options.uid_seed + "\n" + purpose), 8));
}

}  // namespace posewarp::dicom
