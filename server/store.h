// The store: uploaded volumes and built rigs as content-addressed files under one directory. Every file is written
// through AtomicFile, so a crash leaves either the whole file or none; ids are checked to be hex of the expected
// length before they name a file, so no path ever comes from a client.
#pragma once

#include <cstdint>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "posewarp/api/files.h"

namespace posewarp::server {

struct StoredVolume {
  std::string id;         // SHA-256 of the file
  std::string path;       // in the store
  std::string kind;       // "labels" or "intensity"
  uint64_t size_bytes = 0;
};

struct StoredRig {
  std::string id;
  std::string path;
  std::string name;
  uint64_t size_bytes = 0;
  std::string created;  // ISO 8601, UTC
};

class RigStore {
 public:
  // Opens (creating) the store's directories and removes partial files of writers that died.
  static Result<RigStore> open(const std::string& directory);

  // Stores an upload (already checked) under its id; the same bytes again are stored once.
  Result<StoredVolume> put_volume(const std::string& id, const std::string& extension, const std::string& kind,
                                  std::string_view bytes);
  Result<StoredVolume> volume(const std::string& id) const;

  Status put_rig(const std::string& id, const std::string& name, std::string_view bytes);
  Result<StoredRig> rig(const std::string& id) const;
  std::vector<StoredRig> rigs() const;

  const std::string& directory() const { return directory_; }

 private:
  explicit RigStore(std::string directory) : directory_(std::move(directory)) {}
  std::string directory_;
};

}  // namespace posewarp::server
