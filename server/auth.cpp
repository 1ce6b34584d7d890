// Tokens compared by digest: the file's plain tokens never stay in memory beyond the read.
#include "auth.h"

#include <sstream>

#include "posewarp/api/files.h"

namespace posewarp::server {

Status Tokens::load(const std::string& path) {
  if (path.empty()) return ok_status();
  POSEWARP_ASSIGN_OR_RETURN(std::string text, api::read_text_input(path, "token file", int64_t{1} << 20));
  std::set<std::string> digests;
  std::istringstream lines(text);
  for (std::string line; std::getline(lines, line);) {
    const size_t first = line.find_first_not_of(" \t\r");
    if (first == std::string::npos || line[first] == '#') continue;
    const size_t last = line.find_last_not_of(" \t\r");
    digests.insert(api::sha256_hex(line.substr(first, last - first + 1)));
  }
  std::fill(text.begin(), text.end(), '\0');
  if (digests.empty()) {
    return invalid_argument_error("token file '" + path + "' holds no token (one per line); every call would be "
                                  "refused");
  }
  std::lock_guard<std::mutex> lock(mutex_);
  path_ = path;
  digests_ = std::move(digests);
  return ok_status();
}

bool Tokens::enabled() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return !digests_.empty();
}

bool Tokens::allows(const std::string& authorization) const {
  static const std::string kBearer = "Bearer ";
  if (authorization.compare(0, kBearer.size(), kBearer) != 0) return false;
  const std::string digest = api::sha256_hex(authorization.substr(kBearer.size()));
  std::lock_guard<std::mutex> lock(mutex_);
  return digests_.count(digest) != 0;
}

size_t Tokens::size() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return digests_.size();
}

}  // namespace posewarp::server
