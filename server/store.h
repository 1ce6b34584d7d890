// The store: uploaded volumes and built rigs as content-addressed files under one directory, and an index of them
// (and of build operations) behind StoreIndex: SQLite for one machine; PostgreSQL for replicas that share the
// directory (builds claimed with leases, deletions announced to every replica). Every file
// is written through AtomicFile and its index row commits only after the file is durable, so a crash leaves either a
// whole file with or without its row (reconciled at the next open) or nothing. Ids are checked to be hex of the
// expected length before they name a file: no path ever comes from a client.
#pragma once

#include <cstdint>
#include <chrono>
#include <functional>
#include <map>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <vector>

#include "posewarp/api/files.h"

namespace posewarp::server {

struct VolumeRecord {
  std::string id;         // SHA-256 of the file
  std::string kind;       // "labels" or "intensity"
  std::string extension;  // ".nii.gz", ".nii", ".nrrd", ".mha"
  uint64_t size_bytes = 0;
  std::string created;    // ISO 8601, UTC
  std::string path;       // in the store (filled by RigStore, not kept in the index)
};

struct RigRecord {
  std::string id;
  std::string name;
  std::string labels_volume_id;  // empty for an uploaded rig
  std::string ct_volume_id;
  uint64_t size_bytes = 0;
  double build_seconds = 0.0;
  std::string created;
  std::string last_used;
  std::string path;
};

// A build as the index keeps it: enough to answer GetOperation after a restart. Progress within a stage lives in the
// server's memory only.
struct OperationRecord {
  std::string id;
  std::string state;  // QUEUED, RUNNING, SUCCEEDED, FAILED, CANCELLED
  std::string name;
  std::string labels_volume_id;
  std::string ct_volume_id;
  std::string rig_id;
  int error_code = 0;  // a gRPC status code
  std::string error_message;
  double elapsed_s = 0.0;
  std::string created;
  std::string owner;  // the replica running it (a shared index)
  int lease_s = 0;    // while QUEUED or RUNNING: the owner renews it; past it, the build is over (a shared index)
};

// The index: rows of volumes, rigs and operations. Implementations serialize their own access (thread-safe).
class StoreIndex {
 public:
  virtual ~StoreIndex() = default;
  virtual Status put_volume(const VolumeRecord& volume) = 0;
  virtual Result<std::optional<VolumeRecord>> volume(const std::string& id) = 0;
  virtual Result<std::vector<VolumeRecord>> volumes() = 0;
  virtual Status delete_volume(const std::string& id) = 0;

  virtual Status put_rig(const RigRecord& rig) = 0;
  virtual Result<std::optional<RigRecord>> rig(const std::string& id) = 0;
  // Rigs with ids after `after`, in id order, at most `limit`.
  virtual Result<std::vector<RigRecord>> rigs(const std::string& after, int limit) = 0;
  virtual Status touch_rig(const std::string& id, const std::string& when) = 0;
  virtual Status delete_rig(const std::string& id) = 0;

  virtual Status put_operation(const OperationRecord& operation) = 0;
  virtual Result<std::optional<OperationRecord>> operation(const std::string& id) = 0;
  // Newest first, created before `before` (empty: all), at most `limit`.
  virtual Result<std::vector<OperationRecord>> operations(const std::string& before_id, int limit) = 0;
  // Operations left QUEUED or RUNNING by a server that stopped: marked FAILED with `message`; returns how many.
  virtual Result<int> fail_unfinished_operations(int error_code, const std::string& message) = 0;

  // Bytes of every volume and rig file the index holds (for the store's quota).
  virtual Result<uint64_t> total_bytes() = 0;

  // Several replicas share this index (and the store's directory). The rest matter only then; one server alone
  // needs no claims or leases (it runs each build once itself, and its unfinished builds are failed at its start).
  virtual bool shared() const { return false; }
  // Builds QUEUED or RUNNING whose lease ran out (their replica stopped): marked FAILED; returns how many.
  virtual Result<int> fail_expired_operations(int /*error_code*/, const std::string& /*message*/) { return 0; }
  // `owner`'s live operations and build claims leased for `lease_s` more seconds.
  virtual Status renew_operations(const std::string& /*owner*/, int /*lease_s*/) { return ok_status(); }
  // True when `owner` now holds the build of `rig_id` (free, its lease ran out, or owner's already): two replicas
  // asked for the same build build it once; the other waits for the rig.
  virtual Result<bool> claim_build(const std::string& /*rig_id*/, const std::string& /*owner*/, int /*lease_s*/) {
    return true;
  }
  virtual Status release_build(const std::string& /*rig_id*/, const std::string& /*owner*/) { return ok_status(); }
  // Rigs deleted by any replica, as they are (`deleted`, on a thread of the index's); `resync` after notifications
  // may have been missed (a lost connection), to check what the caller holds.
  virtual void watch_deleted_rigs(std::function<void(const std::string&)> /*deleted*/,
                                  std::function<void()> /*resync*/) {}
};

// The index's tables, one schema for every index: only the column types each database names its own way differ,
// and a shared index also keeps who runs each build until when (its leases and claims).
struct SchemaDialect {
  const char* big_integer;  // a 64-bit integer column
  const char* real;         // a double column
  const char* sequence;     // operations.seq: increasing with each build queued
  bool shared = false;      // several replicas: operations.owner and lease_until, the build_claims table
};
std::string index_schema(const SchemaDialect& dialect);

// SQLite (WAL, synchronous=FULL) at `path`, created with its schema when missing.
Result<std::unique_ptr<StoreIndex>> open_sqlite_index(const std::string& path);
// PostgreSQL at `conninfo` (a libpq connection string or postgresql:// URL), its tables created when missing.
// UNIMPLEMENTED in a server built without libpqxx.
Result<std::unique_ptr<StoreIndex>> open_postgres_index(const std::string& conninfo);

struct StoreOptions {
  uint64_t quota_bytes = 0;  // volumes and rigs together; 0: no quota
  std::string database;      // a PostgreSQL index shared by replicas; empty: SQLite beside the files
  // Test hook: seconds to pause half-way through writing a rig file (a crash test kills the server there).
  double pause_in_rig_write_s = 0.0;
};

class RigStore {
 public:
  // Opens (creating) the store's directories and index, then reconciles them: partial files of dead writers are
  // removed; builds left running are marked failed; rows whose file is gone are dropped; rig files without a row
  // (a crash between the file and its row) are checked and adopted, or quarantined when they fail their checksums;
  // volume files without a row (an upload whose client never got an answer) are removed. `log` gets a line for
  // each repair.
  static Result<std::unique_ptr<RigStore>> open(const std::string& directory, const StoreOptions& options,
                                                const std::function<void(const std::string&)>& log);

  // Stores a checked upload under its id; the same bytes again are stored once. RESOURCE_EXHAUSTED over the quota.
  Result<VolumeRecord> put_volume(const std::string& id, const std::string& extension, const std::string& kind,
                                  std::string_view bytes);
  // The same for a checked upload already on disk in a staging directory: flushed, then renamed into place.
  Result<VolumeRecord> put_volume_file(const std::string& id, const std::string& extension, const std::string& kind,
                                       const std::string& staged_path);
  // A new, empty directory of its own under staging/ (mode 0700) for one upload: whatever a file there names
  // beside itself, it finds nothing but its own bytes. The caller removes it (StagingDirectory does).
  Result<std::string> make_staging_directory();
  Result<VolumeRecord> volume(const std::string& id);

  // The rig file, then its row. `record.id` names it; size and created are filled in.
  Status put_rig(RigRecord record, std::string_view bytes);
  // A stored rig's file written again with `bytes` (the same rig, completed by a newer version), its row keeping its
  // name, volumes and dates with the new size. Only what the file grows by counts against the quota.
  Status rewrite_rig(RigRecord record, std::string_view bytes);
  Result<RigRecord> rig(const std::string& id);
  Result<std::vector<RigRecord>> rigs(const std::string& after, int limit);
  // Notes a rig's use in the index at most once a minute per rig: a pose's hot path pays no index write.
  void touch_rig(const std::string& id);
  // The file first, then the row (a crash between leaves a row without a file, which the next open drops).
  Status delete_rig(const std::string& id);
  // A rig file that failed its checks: moved to quarantine/ (kept for a person to look at), its row dropped.
  Status quarantine_rig(const std::string& id, const std::string& reason);

  StoreIndex& index() { return *index_; }
  const std::string& directory() const { return directory_; }

 private:
  RigStore(std::string directory, StoreOptions options, std::unique_ptr<StoreIndex> index)
      : directory_(std::move(directory)), options_(options), index_(std::move(index)) {}
  Status reconcile(const std::function<void(const std::string&)>& log);
  Status reconcile_rigs(const std::function<void(const std::string&)>& log);
  Status reconcile_volumes(const std::function<void(const std::string&)>& log);
  Status check_quota(uint64_t more_bytes);

  std::string directory_;
  StoreOptions options_;
  std::unique_ptr<StoreIndex> index_;
  std::mutex write_mutex_;  // quota check and write of one upload or rig at a time
  std::mutex touch_mutex_;
  std::map<std::string, std::chrono::steady_clock::time_point> touched_;  // last index write of last_used per rig
};

// One upload's staging directory, removed with everything in it when this goes out of scope.
class StagingDirectory {
 public:
  explicit StagingDirectory(std::string path) : path_(std::move(path)) {}
  StagingDirectory(const StagingDirectory&) = delete;
  StagingDirectory& operator=(const StagingDirectory&) = delete;
  ~StagingDirectory();
  const std::string& path() const { return path_; }

 private:
  std::string path_;
};

// Now, as ISO 8601 UTC ("2026-11-25T10:00:00Z").
std::string iso_now();

}  // namespace posewarp::server
