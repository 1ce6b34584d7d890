// RigStore: volumes/<sha256><ext> and rigs/<id>.rig under one directory, index.sqlite beside them, quarantine/ for
// rig files that failed their checks.
#include "store.h"

#include <algorithm>
#include <cerrno>
#include <chrono>
#include <cstring>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <random>
#include <set>
#include <thread>

#include <sys/stat.h>

#include "posewarp/api/files.h"
#include "posewarp/api/rig_file.h"

namespace posewarp::server {

std::string index_schema(const SchemaDialect& d) {
  const std::string big = d.big_integer, real = d.real;
  std::string sql =
      "CREATE TABLE IF NOT EXISTS volumes (\n"
      "  id TEXT PRIMARY KEY, kind TEXT NOT NULL, extension TEXT NOT NULL, size_bytes " + big + " NOT NULL,\n"
      "  created TEXT NOT NULL);\n"
      "CREATE TABLE IF NOT EXISTS rigs (\n"
      "  id TEXT PRIMARY KEY, name TEXT NOT NULL, labels_volume_id TEXT NOT NULL, ct_volume_id TEXT NOT NULL,\n"
      "  size_bytes " + big + " NOT NULL, build_seconds " + real + " NOT NULL, created TEXT NOT NULL,\n"
      "  last_used TEXT NOT NULL);\n"
      "CREATE TABLE IF NOT EXISTS operations (\n"
      "  id TEXT PRIMARY KEY, seq " + d.sequence + ", state TEXT NOT NULL, name TEXT NOT NULL,\n"
      "  labels_volume_id TEXT NOT NULL, ct_volume_id TEXT NOT NULL, rig_id TEXT NOT NULL,\n"
      "  error_code INTEGER NOT NULL, error_message TEXT NOT NULL, elapsed_s " + real + " NOT NULL,\n"
      "  created TEXT NOT NULL" +
      (d.shared ? ",\n  owner TEXT NOT NULL DEFAULT '', lease_until TIMESTAMPTZ" : "") + ");\n"
      "CREATE INDEX IF NOT EXISTS operations_by_seq ON operations(seq);\n";
  if (d.shared) {
    sql += "CREATE TABLE IF NOT EXISTS build_claims (\n"
           "  rig_id TEXT PRIMARY KEY, owner TEXT NOT NULL, lease_until TIMESTAMPTZ NOT NULL);\n";
  }
  return sql;
}
namespace {

namespace fs = std::filesystem;

constexpr const char* kExtensions[] = {".nii.gz", ".nii", ".nrrd", ".mha"};

Result<std::string> read_whole(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return not_found_error("cannot read " + path.filename().string());
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

// "<id><ext>" -> {id, ext} for a volume file name, or nullopt.
std::optional<std::pair<std::string, std::string>> volume_file_name(const std::string& name) {
  for (const char* extension : kExtensions) {
    const std::string ext(extension);
    if (name.size() == 64 + ext.size() && name.compare(64, ext.size(), ext) == 0 && is_hex_id(name.substr(0, 64))) {
      return std::make_pair(name.substr(0, 64), ext);
    }
  }
  return std::nullopt;
}

// A shared store's partial and staging files: another replica may be writing them; after this long, none is.
constexpr std::chrono::hours kAbandonedAfter{6};

bool older_than(const fs::path& path, std::chrono::hours age) {
  std::error_code ec;
  const auto written = fs::last_write_time(path, ec);
  return !ec && fs::file_time_type::clock::now() - written > age;
}

int remove_old_partial_files(const std::string& directory) {
  int removed = 0;
  std::error_code ec;
  for (fs::directory_iterator it(directory, ec), end; !ec && it != end; it.increment(ec)) {
    if (it->path().filename().string().rfind(".posewarp-partial-", 0) != 0) continue;
    std::error_code removing;
    if (older_than(it->path(), kAbandonedAfter) && fs::remove(it->path(), removing)) ++removed;
  }
  return removed;
}

}  // namespace

std::string iso_now() {
  const std::time_t t = std::chrono::system_clock::to_time_t(std::chrono::system_clock::now());
  std::tm utc{};
  gmtime_r(&t, &utc);
  char text[32];
  std::strftime(text, sizeof(text), "%Y-%m-%dT%H:%M:%SZ", &utc);
  return text;
}

Result<std::unique_ptr<RigStore>> RigStore::open(const std::string& directory, const StoreOptions& options,
                                                 const std::function<void(const std::string&)>& log) {
  std::error_code ec;
  for (const char* sub : {"volumes", "rigs", "quarantine", "staging"}) {
    fs::create_directories(fs::path(directory) / sub, ec);
    if (ec) {
      return failed_precondition_error("cannot create the store at '" + directory + "': " + ec.message() +
                                       " (give --store a directory the server may write)");
    }
  }
  std::unique_ptr<StoreIndex> index;
  if (options.database.empty()) {
    POSEWARP_ASSIGN_OR_RETURN(index, open_sqlite_index((fs::path(directory) / "index.sqlite").string()));
  } else {
    POSEWARP_ASSIGN_OR_RETURN(index, open_postgres_index(options.database));
  }
  std::unique_ptr<RigStore> store(new RigStore(directory, options, std::move(index)));
  POSEWARP_RETURN_IF_ERROR(store->reconcile(log));
  return store;
}

Status RigStore::reconcile(const std::function<void(const std::string&)>& log) {
  const fs::path root(directory_);
  const bool shared = index_->shared();
  for (const char* sub : {"volumes", "rigs"}) {
    // Shared by replicas (other machines, other pid namespaces): a partial file is judged by its age, not its pid.
    const int removed = shared ? remove_old_partial_files((root / sub).string())
                               : remove_stale_partial_files((root / sub).string());
    if (removed > 0) {
      log("store: removed " + std::to_string(removed) + " partial file(s) of a writer that died in " + sub + "/");
    }
  }
  // Uploads being checked when their server stopped (a shared store's may be another replica's, live).
  std::error_code staging_ec;
  for (fs::directory_iterator it(root / "staging", staging_ec), end; !staging_ec && it != end;
       it.increment(staging_ec)) {
    std::error_code removing;
    if (!shared || older_than(it->path(), kAbandonedAfter)) fs::remove_all(it->path(), removing);
  }
  POSEWARP_ASSIGN_OR_RETURN(const int interrupted,
                            index_->fail_unfinished_operations(10, "the server stopped during the build; build again"));
  if (interrupted > 0) log("store: " + std::to_string(interrupted) + " build(s) left running were marked failed");
  POSEWARP_RETURN_IF_ERROR(reconcile_rigs(log));
  return reconcile_volumes(log);
}

// Rigs: rows without a file are dropped; files without a row are checked and adopted, or quarantined.
Status RigStore::reconcile_rigs(const std::function<void(const std::string&)>& log) {
  const fs::path root(directory_);
  std::set<std::string> indexed;
  for (std::string after;;) {
    POSEWARP_ASSIGN_OR_RETURN(const std::vector<RigRecord> page, index_->rigs(after, 1000));
    for (const RigRecord& r : page) {
      std::error_code ec;
      if (!fs::is_regular_file(root / "rigs" / (r.id + ".rig"), ec)) {
        POSEWARP_RETURN_IF_ERROR(index_->delete_rig(r.id));
        log("store: rig " + r.id + " was in the index without its file; its row was dropped");
      } else {
        indexed.insert(r.id);
      }
    }
    if (page.size() < 1000) break;
    after = page.back().id;
  }
  std::error_code ec;
  for (fs::directory_iterator it(root / "rigs", ec), end; !ec && it != end; it.increment(ec)) {
    const fs::path& p = it->path();
    const std::string id = p.stem().string();
    if (p.extension() != ".rig" || !is_hex_id(id)) {
      log("store: unexpected file rigs/" + p.filename().string() + " left alone");
      continue;
    }
    if (indexed.count(id) != 0) continue;
    Result<std::string> bytes = read_whole(p);
    Result<api::Rig> rig = bytes.ok() ? api::rig_from_bytes(*bytes, "rig " + id) : Result<api::Rig>(bytes.status());
    if (!rig.ok() || rig->id() != id) {
      POSEWARP_RETURN_IF_ERROR(quarantine_rig(id, rig.ok() ? "its content is not rig " + id : rig.status().message()));
      log("store: rig file " + id + " had no row and failed its checks; moved to quarantine/");
      continue;
    }
    RigRecord record;
    record.id = id;
    record.size_bytes = bytes->size();
    for (const auto& [stage, seconds] : rig->provenance.stage_seconds) record.build_seconds += seconds;
    record.created = record.last_used = iso_now();
    POSEWARP_RETURN_IF_ERROR(index_->put_rig(record));
    log("store: rig file " + id + " had no row (a crash after its write); checked and adopted");
  }
  return ok_status();
}

// Volumes: rows without a file are dropped; a file without a row is adopted when its bytes hash to its name.
Status RigStore::reconcile_volumes(const std::function<void(const std::string&)>& log) {
  const fs::path root(directory_);
  const bool shared = index_->shared();
  std::error_code ec;
  POSEWARP_ASSIGN_OR_RETURN(const std::vector<VolumeRecord> volumes, index_->volumes());
  std::set<std::string> volume_ids;
  for (const VolumeRecord& v : volumes) {
    if (!fs::is_regular_file(root / "volumes" / (v.id + v.extension), ec)) {
      POSEWARP_RETURN_IF_ERROR(index_->delete_volume(v.id));
      log("store: volume " + v.id + " was in the index without its file; its row was dropped");
    } else {
      volume_ids.insert(v.id);
    }
  }
  for (fs::directory_iterator it(root / "volumes", ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    const auto parsed = volume_file_name(name);
    if (!parsed) {
      if (name.rfind(".staging-", 0) == 0) {
        // An upload being checked when its server stopped (a shared store's may be another replica's, live).
        if (!shared || older_than(it->path(), kAbandonedAfter)) fs::remove(it->path(), ec);
      } else {
        log("store: unexpected file volumes/" + name + " left alone");
      }
      continue;
    }
    if (volume_ids.count(parsed->first) != 0) continue;
    Result<std::string> bytes = read_whole(it->path());
    if (bytes.ok() && sha256_hex(*bytes) == parsed->first) {
      POSEWARP_RETURN_IF_ERROR(
          index_->put_volume({parsed->first, "unknown", parsed->second, bytes->size(), iso_now(), ""}));
      log("store: volume file " + parsed->first + " had no row; its bytes match its id, adopted");
    } else {
      fs::remove(it->path(), ec);
      log("store: volume file " + parsed->first + " had no row and does not match its id; removed");
    }
  }
  return ok_status();
}

Status RigStore::check_quota(uint64_t more_bytes) {
  if (options_.quota_bytes == 0) return ok_status();
  POSEWARP_ASSIGN_OR_RETURN(const uint64_t used, index_->total_bytes());
  if (used + more_bytes > options_.quota_bytes) {
    return resource_exhausted_error("the store is full (" + std::to_string(used >> 20) + " of " +
                                    std::to_string(options_.quota_bytes >> 20) + " MB used; this needs " +
                                    std::to_string((more_bytes + (1 << 20) - 1) >> 20) +
                                    " MB): delete rigs you no longer need, or ask the operator for a larger quota");
  }
  return ok_status();
}

Result<VolumeRecord> RigStore::put_volume(const std::string& id, const std::string& extension,
                                          const std::string& kind, std::string_view bytes) {
  if (!is_hex_id(id)) return invalid_argument_error("a volume id is 64 lowercase hex digits");
  std::lock_guard<std::mutex> lock(write_mutex_);
  POSEWARP_ASSIGN_OR_RETURN(const std::optional<VolumeRecord> existing, index_->volume(id));
  if (existing) return volume(id);  // the same bytes, stored once
  POSEWARP_RETURN_IF_ERROR(check_quota(bytes.size()));
  const fs::path file = fs::path(directory_) / "volumes" / (id + extension);
  POSEWARP_RETURN_IF_ERROR(write_file_atomically(file.string(), bytes, "volume"));
  POSEWARP_RETURN_IF_ERROR(index_->put_volume({id, kind, extension, bytes.size(), iso_now(), ""}));
  return volume(id);
}

Result<VolumeRecord> RigStore::put_volume_file(const std::string& id, const std::string& extension,
                                               const std::string& kind, const std::string& staged_path) {
  if (!is_hex_id(id)) return invalid_argument_error("a volume id is 64 lowercase hex digits");
  std::lock_guard<std::mutex> lock(write_mutex_);
  POSEWARP_ASSIGN_OR_RETURN(const std::optional<VolumeRecord> existing, index_->volume(id));
  if (existing) return volume(id);  // the same bytes, stored once
  std::error_code ec;
  const uint64_t size = fs::file_size(staged_path, ec);
  if (ec) return internal_error("an upload's staging file is gone: " + ec.message());
  POSEWARP_RETURN_IF_ERROR(check_quota(size));
  // Durable before it gets its name, and its name durable before the row names it.
  const fs::path target = fs::path(directory_) / "volumes" / (id + extension);
  POSEWARP_RETURN_IF_ERROR(api::AtomicFile::adopt(staged_path, target.string(), "uploaded volume").commit());
  POSEWARP_RETURN_IF_ERROR(index_->put_volume({id, kind, extension, size, iso_now(), ""}));
  return volume(id);
}

Result<std::string> RigStore::make_staging_directory() {
  static std::mutex random_mutex;
  static std::mt19937_64 random{std::random_device{}()};
  for (int attempt = 0; attempt < 8; ++attempt) {
    uint64_t n = 0;
    {
      std::lock_guard<std::mutex> lock(random_mutex);
      n = random();
    }
    char name[32];
    std::snprintf(name, sizeof name, "%016llx", static_cast<unsigned long long>(n));
    const fs::path path = fs::path(directory_) / "staging" / name;
    if (::mkdir(path.c_str(), 0700) == 0) return path.string();
    if (errno != EEXIST) {
      return resource_exhausted_error("the server cannot stage an upload (" + std::string(std::strerror(errno)) +
                                      "); try again later or ask the operator");
    }
  }
  return internal_error("cannot make a staging directory for an upload");
}

StagingDirectory::~StagingDirectory() {
  std::error_code ec;
  if (!path_.empty()) fs::remove_all(path_, ec);
}

Result<VolumeRecord> RigStore::volume(const std::string& id) {
  if (!is_hex_id(id)) return invalid_argument_error("a volume id is 64 lowercase hex digits");
  POSEWARP_ASSIGN_OR_RETURN(std::optional<VolumeRecord> row, index_->volume(id));
  if (!row) return not_found_error("no volume " + id + " in the store; upload it first");
  row->path = (fs::path(directory_) / "volumes" / (id + row->extension)).string();
  return *row;
}

Status RigStore::put_rig(RigRecord record, std::string_view bytes) {
  if (!is_hex_id(record.id)) return invalid_argument_error("a rig id is 64 lowercase hex digits");
  std::lock_guard<std::mutex> lock(write_mutex_);
  POSEWARP_RETURN_IF_ERROR(check_quota(bytes.size()));
  const fs::path file = fs::path(directory_) / "rigs" / (record.id + ".rig");
  POSEWARP_ASSIGN_OR_RETURN(AtomicFile out, AtomicFile::create(file.string(), "rig file"));
  if (options_.pause_in_rig_write_s > 0.0) {
    const size_t half = bytes.size() / 2;
    POSEWARP_RETURN_IF_ERROR(out.write(bytes.substr(0, half)));
    std::fprintf(stderr, "posewarp-server: test hook: pausing %.1f s inside a rig write\n",
                 options_.pause_in_rig_write_s);
    std::fflush(stderr);
    std::this_thread::sleep_for(std::chrono::duration<double>(options_.pause_in_rig_write_s));
    POSEWARP_RETURN_IF_ERROR(out.write(bytes.substr(half)));
  } else {
    POSEWARP_RETURN_IF_ERROR(out.write(bytes));
  }
  POSEWARP_RETURN_IF_ERROR(out.commit());  // durable before the row names it
  record.size_bytes = bytes.size();
  record.created = record.last_used = iso_now();
  return index_->put_rig(record);
}

Status RigStore::rewrite_rig(RigRecord record, std::string_view bytes) {
  if (!is_hex_id(record.id)) return invalid_argument_error("a rig id is 64 lowercase hex digits");
  std::lock_guard<std::mutex> lock(write_mutex_);
  if (bytes.size() > record.size_bytes) POSEWARP_RETURN_IF_ERROR(check_quota(bytes.size() - record.size_bytes));
  const fs::path file = fs::path(directory_) / "rigs" / (record.id + ".rig");
  POSEWARP_RETURN_IF_ERROR(write_file_atomically(file.string(), bytes, "rig file"));
  record.size_bytes = bytes.size();
  return index_->put_rig(record);
}

Result<RigRecord> RigStore::rig(const std::string& id) {
  if (!is_hex_id(id)) return invalid_argument_error("a rig id is 64 lowercase hex digits");
  POSEWARP_ASSIGN_OR_RETURN(std::optional<RigRecord> row, index_->rig(id));
  if (!row) return not_found_error("no rig " + id + " in the store; build or upload it first (ListRigs shows them)");
  row->path = (fs::path(directory_) / "rigs" / (id + ".rig")).string();
  return *row;
}

Result<std::vector<RigRecord>> RigStore::rigs(const std::string& after, int limit) {
  POSEWARP_ASSIGN_OR_RETURN(std::vector<RigRecord> rows, index_->rigs(after, limit));
  for (RigRecord& r : rows) r.path = (fs::path(directory_) / "rigs" / (r.id + ".rig")).string();
  return rows;
}

void RigStore::touch_rig(const std::string& id) {
  const auto now = std::chrono::steady_clock::now();
  {
    std::lock_guard<std::mutex> lock(touch_mutex_);
    auto [it, first] = touched_.try_emplace(id, now);
    if (!first && now - it->second < std::chrono::minutes(1)) return;
    it->second = now;
  }
  (void)index_->touch_rig(id, iso_now());
}

Status RigStore::delete_rig(const std::string& id) {
  POSEWARP_ASSIGN_OR_RETURN(const RigRecord row, rig(id));
  std::lock_guard<std::mutex> lock(write_mutex_);
  std::error_code ec;
  fs::remove(row.path, ec);
  if (ec) return internal_error("cannot remove rig " + id + " from the store: " + ec.message());
  return index_->delete_rig(id);
}

Status RigStore::quarantine_rig(const std::string& id, const std::string& reason) {
  if (!is_hex_id(id)) return invalid_argument_error("a rig id is 64 lowercase hex digits");
  const fs::path from = fs::path(directory_) / "rigs" / (id + ".rig");
  const fs::path to = fs::path(directory_) / "quarantine" / (id + ".rig");
  std::error_code ec;
  fs::rename(from, to, ec);
  if (ec) return internal_error("cannot quarantine rig " + id + ": " + ec.message());
  (void)write_file_atomically(to.string() + ".why", reason + "\n", "quarantine note");
  return index_->delete_rig(id);
}

}  // namespace posewarp::server
