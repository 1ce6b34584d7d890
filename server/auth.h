// Bearer tokens: read from a file (one per line; blank lines and '#' comments skipped), kept only as SHA-256
// digests in memory, re-read on SIGHUP. With no token file every call is let in.
#pragma once

#include <mutex>
#include <set>
#include <string>

#include "posewarp/api/files.h"

namespace posewarp::server {

class Tokens {
 public:
  // Reads `path` (empty: tokens off). On an error the tokens in force stay.
  Status load(const std::string& path);
  Status reload() { return load(path_); }
  bool enabled() const;
  // The "authorization" metadata value ("Bearer <token>") is one of the tokens.
  bool allows(const std::string& authorization) const;
  size_t size() const;

 private:
  mutable std::mutex mutex_;
  std::string path_;
  std::set<std::string> digests_;
};

}  // namespace posewarp::server
