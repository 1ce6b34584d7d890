// RigStore on the file system: volumes/<sha256>.<ext> (+ .kind), rigs/<id>.rig (+ .name).
#include "store.h"

#include <sys/stat.h>

#include <algorithm>
#include <chrono>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iterator>

#include "posewarp/api/files.h"

namespace posewarp::server {
namespace {

namespace fs = std::filesystem;

std::string read_small(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

std::string iso_time(fs::file_time_type when) {
  const auto system = std::chrono::time_point_cast<std::chrono::seconds>(
      when - fs::file_time_type::clock::now() + std::chrono::system_clock::now());
  const std::time_t t = std::chrono::system_clock::to_time_t(system);
  std::tm utc{};
  gmtime_r(&t, &utc);
  char text[32];
  std::strftime(text, sizeof(text), "%Y-%m-%dT%H:%M:%SZ", &utc);
  return text;
}

}  // namespace

Result<RigStore> RigStore::open(const std::string& directory) {
  std::error_code ec;
  for (const char* sub : {"volumes", "rigs"}) {
    fs::create_directories(fs::path(directory) / sub, ec);
    if (ec) return invalid_argument_error("cannot create the store at '" + directory + "': " + ec.message());
    api::remove_stale_partial_files((fs::path(directory) / sub).string());
  }
  return RigStore(directory);
}

Result<StoredVolume> RigStore::put_volume(const std::string& id, const std::string& extension, const std::string& kind,
                                          std::string_view bytes) {
  if (!api::is_hex_id(id)) return invalid_argument_error("a volume id is 64 lowercase hex digits");
  const fs::path base = fs::path(directory_) / "volumes" / id;
  const fs::path file = base.string() + extension;
  std::error_code ec;
  if (!fs::exists(file, ec)) {
    POSEWARP_RETURN_IF_ERROR(api::write_file_atomically(file.string(), bytes, "volume"));
  }
  POSEWARP_RETURN_IF_ERROR(api::write_file_atomically(base.string() + ".kind", kind, "volume kind"));
  return volume(id);
}

Result<StoredVolume> RigStore::volume(const std::string& id) const {
  if (!api::is_hex_id(id)) return invalid_argument_error("a volume id is 64 lowercase hex digits");
  const fs::path base = fs::path(directory_) / "volumes" / id;
  for (const char* extension : {".nii.gz", ".nii", ".nrrd", ".mha"}) {
    const fs::path file = base.string() + extension;
    std::error_code ec;
    if (fs::is_regular_file(file, ec)) {
      return StoredVolume{id, file.string(), read_small(base.string() + ".kind"),
                          static_cast<uint64_t>(fs::file_size(file, ec))};
    }
  }
  return not_found_error("no volume " + id + " in the store; upload it first");
}

Status RigStore::put_rig(const std::string& id, const std::string& name, std::string_view bytes) {
  if (!api::is_hex_id(id)) return invalid_argument_error("a rig id is 64 lowercase hex digits");
  const fs::path base = fs::path(directory_) / "rigs" / id;
  POSEWARP_RETURN_IF_ERROR(api::write_file_atomically(base.string() + ".rig", bytes, "rig file"));
  if (!name.empty()) POSEWARP_RETURN_IF_ERROR(api::write_file_atomically(base.string() + ".name", name, "rig name"));
  return ok_status();
}

Result<StoredRig> RigStore::rig(const std::string& id) const {
  if (!api::is_hex_id(id)) return invalid_argument_error("a rig id is 64 lowercase hex digits");
  const fs::path base = fs::path(directory_) / "rigs" / id;
  const fs::path file = base.string() + ".rig";
  std::error_code ec;
  if (!fs::is_regular_file(file, ec)) return not_found_error("no rig " + id + " in the store; build it first");
  return StoredRig{id, file.string(), read_small(base.string() + ".name"),
                   static_cast<uint64_t>(fs::file_size(file, ec)), iso_time(fs::last_write_time(file, ec))};
}

std::vector<StoredRig> RigStore::rigs() const {
  std::vector<StoredRig> found;
  std::error_code ec;
  for (fs::directory_iterator it(fs::path(directory_) / "rigs", ec), end; !ec && it != end; it.increment(ec)) {
    const fs::path& p = it->path();
    if (p.extension() != ".rig" || !api::is_hex_id(p.stem().string())) continue;
    Result<StoredRig> r = rig(p.stem().string());
    if (r.ok()) found.push_back(*r);
  }
  std::sort(found.begin(), found.end(), [](const StoredRig& a, const StoredRig& b) { return a.id < b.id; });
  return found;
}

}  // namespace posewarp::server
