// StoreIndex on SQLite: one connection in WAL mode with synchronous=FULL (a committed row survives a power cut),
// serialized by a mutex; every statement is prepared with bound parameters.
#include <sqlite3.h>

#include <mutex>

#include "store.h"

namespace posewarp::server {
namespace {

const SchemaDialect kDialect{"INTEGER", "REAL", "INTEGER NOT NULL"};

// One prepared statement, finalized on scope exit.
class Statement {
 public:
  Statement(sqlite3* db, const char* sql) : db_(db) { ok_ = sqlite3_prepare_v2(db, sql, -1, &stmt_, nullptr) == SQLITE_OK; }
  ~Statement() { sqlite3_finalize(stmt_); }
  Statement(const Statement&) = delete;
  Statement& operator=(const Statement&) = delete;

  Statement& bind(int i, const std::string& text) {
    sqlite3_bind_text(stmt_, i, text.data(), static_cast<int>(text.size()), SQLITE_TRANSIENT);
    return *this;
  }
  Statement& bind(int i, int64_t value) {
    sqlite3_bind_int64(stmt_, i, value);
    return *this;
  }
  Statement& bind(int i, double value) {
    sqlite3_bind_double(stmt_, i, value);
    return *this;
  }
  // SQLITE_ROW, SQLITE_DONE or an error code.
  int step() { return ok_ ? sqlite3_step(stmt_) : SQLITE_ERROR; }
  std::string text(int column) const {
    const auto* p = reinterpret_cast<const char*>(sqlite3_column_text(stmt_, column));
    return p == nullptr ? std::string() : std::string(p, static_cast<size_t>(sqlite3_column_bytes(stmt_, column)));
  }
  int64_t integer(int column) const { return sqlite3_column_int64(stmt_, column); }
  double real(int column) const { return sqlite3_column_double(stmt_, column); }
  Status error(const std::string& doing) const {
    return internal_error("the store's index failed while " + doing + ": " + sqlite3_errmsg(db_) +
                          " (check the store's disk; the server's log has more)");
  }

 private:
  sqlite3* db_;
  sqlite3_stmt* stmt_ = nullptr;
  bool ok_ = false;
};

VolumeRecord volume_row(const Statement& s) {
  return {s.text(0), s.text(1), s.text(2), static_cast<uint64_t>(s.integer(3)), s.text(4), ""};
}

RigRecord rig_row(const Statement& s) {
  return {s.text(0), s.text(1), s.text(2), s.text(3), static_cast<uint64_t>(s.integer(4)),
          s.real(5), s.text(6), s.text(7), ""};
}

OperationRecord operation_row(const Statement& s) {
  return {s.text(0), s.text(1), s.text(2), s.text(3), s.text(4), s.text(5),
          static_cast<int>(s.integer(6)), s.text(7), s.real(8), s.text(9)};
}

constexpr const char* kRigColumns =
    "SELECT id, name, labels_volume_id, ct_volume_id, size_bytes, build_seconds, created, last_used FROM rigs ";
constexpr const char* kOperationColumns =
    "SELECT id, state, name, labels_volume_id, ct_volume_id, rig_id, error_code, error_message, elapsed_s, created "
    "FROM operations ";

class SqliteIndex final : public StoreIndex {
 public:
  explicit SqliteIndex(sqlite3* db) : db_(db) {}
  ~SqliteIndex() override { sqlite3_close(db_); }

  Status exec(const char* sql, const std::string& doing) {
    char* message = nullptr;
    if (sqlite3_exec(db_, sql, nullptr, nullptr, &message) != SQLITE_OK) {
      const std::string text = message == nullptr ? "unknown error" : message;
      sqlite3_free(message);
      return internal_error("the store's index failed while " + doing + ": " + text);
    }
    return ok_status();
  }

  Status put_volume(const VolumeRecord& v) override {
    std::lock_guard<std::mutex> lock(mutex_);
    Statement s(db_, "INSERT OR REPLACE INTO volumes VALUES (?, ?, ?, ?, ?)");
    s.bind(1, v.id).bind(2, v.kind).bind(3, v.extension).bind(4, static_cast<int64_t>(v.size_bytes)).bind(5, v.created);
    return s.step() == SQLITE_DONE ? ok_status() : s.error("recording a volume");
  }
  Result<std::optional<VolumeRecord>> volume(const std::string& id) override {
    std::lock_guard<std::mutex> lock(mutex_);
    Statement s(db_, "SELECT id, kind, extension, size_bytes, created FROM volumes WHERE id = ?");
    s.bind(1, id);
    const int rc = s.step();
    if (rc == SQLITE_ROW) return std::optional<VolumeRecord>(volume_row(s));
    if (rc == SQLITE_DONE) return std::optional<VolumeRecord>();
    return s.error("looking up a volume");
  }
  Result<std::vector<VolumeRecord>> volumes() override {
    std::lock_guard<std::mutex> lock(mutex_);
    Statement s(db_, "SELECT id, kind, extension, size_bytes, created FROM volumes ORDER BY id");
    std::vector<VolumeRecord> rows;
    int rc;
    while ((rc = s.step()) == SQLITE_ROW) rows.push_back(volume_row(s));
    if (rc != SQLITE_DONE) return s.error("listing volumes");
    return rows;
  }
  Status delete_volume(const std::string& id) override { return delete_from("volumes", id); }

  Status put_rig(const RigRecord& r) override {
    std::lock_guard<std::mutex> lock(mutex_);
    Statement s(db_, "INSERT OR REPLACE INTO rigs VALUES (?, ?, ?, ?, ?, ?, ?, ?)");
    s.bind(1, r.id).bind(2, r.name).bind(3, r.labels_volume_id).bind(4, r.ct_volume_id);
    s.bind(5, static_cast<int64_t>(r.size_bytes)).bind(6, r.build_seconds).bind(7, r.created).bind(8, r.last_used);
    return s.step() == SQLITE_DONE ? ok_status() : s.error("recording a rig");
  }
  Result<std::optional<RigRecord>> rig(const std::string& id) override {
    std::lock_guard<std::mutex> lock(mutex_);
    Statement s(db_, (std::string(kRigColumns) + "WHERE id = ?").c_str());
    s.bind(1, id);
    const int rc = s.step();
    if (rc == SQLITE_ROW) return std::optional<RigRecord>(rig_row(s));
    if (rc == SQLITE_DONE) return std::optional<RigRecord>();
    return s.error("looking up a rig");
  }
  Result<std::vector<RigRecord>> rigs(const std::string& after, int limit) override {
    std::lock_guard<std::mutex> lock(mutex_);
    Statement s(db_, (std::string(kRigColumns) + "WHERE id > ? ORDER BY id LIMIT ?").c_str());
    s.bind(1, after).bind(2, static_cast<int64_t>(limit));
    std::vector<RigRecord> rows;
    int rc;
    while ((rc = s.step()) == SQLITE_ROW) rows.push_back(rig_row(s));
    if (rc != SQLITE_DONE) return s.error("listing rigs");
    return rows;
  }
  Status touch_rig(const std::string& id, const std::string& when) override {
    std::lock_guard<std::mutex> lock(mutex_);
    Statement s(db_, "UPDATE rigs SET last_used = ? WHERE id = ?");
    s.bind(1, when).bind(2, id);
    return s.step() == SQLITE_DONE ? ok_status() : s.error("noting a rig's use");
  }
  Status delete_rig(const std::string& id) override { return delete_from("rigs", id); }

  Status put_operation(const OperationRecord& o) override {
    std::lock_guard<std::mutex> lock(mutex_);
    // seq orders operations by creation; an update keeps the row's first seq.
    Statement s(db_,
                "INSERT INTO operations VALUES (?, (SELECT COALESCE(MAX(seq), 0) + 1 FROM operations), ?, ?, ?, ?, ?, "
                "?, ?, ?, ?) ON CONFLICT(id) DO UPDATE SET state = excluded.state, rig_id = excluded.rig_id, "
                "error_code = excluded.error_code, error_message = excluded.error_message, "
                "elapsed_s = excluded.elapsed_s");
    s.bind(1, o.id).bind(2, o.state).bind(3, o.name).bind(4, o.labels_volume_id).bind(5, o.ct_volume_id);
    s.bind(6, o.rig_id).bind(7, static_cast<int64_t>(o.error_code)).bind(8, o.error_message).bind(9, o.elapsed_s);
    s.bind(10, o.created);
    return s.step() == SQLITE_DONE ? ok_status() : s.error("recording an operation");
  }
  Result<std::optional<OperationRecord>> operation(const std::string& id) override {
    std::lock_guard<std::mutex> lock(mutex_);
    Statement s(db_, (std::string(kOperationColumns) + "WHERE id = ?").c_str());
    s.bind(1, id);
    const int rc = s.step();
    if (rc == SQLITE_ROW) return std::optional<OperationRecord>(operation_row(s));
    if (rc == SQLITE_DONE) return std::optional<OperationRecord>();
    return s.error("looking up an operation");
  }
  Result<std::vector<OperationRecord>> operations(const std::string& before_id, int limit) override {
    std::lock_guard<std::mutex> lock(mutex_);
    Statement s(db_, (std::string(kOperationColumns) +
                      "WHERE seq < COALESCE((SELECT seq FROM operations WHERE id = ?), 9223372036854775807) "
                      "ORDER BY seq DESC LIMIT ?")
                         .c_str());
    s.bind(1, before_id).bind(2, static_cast<int64_t>(limit));
    std::vector<OperationRecord> rows;
    int rc;
    while ((rc = s.step()) == SQLITE_ROW) rows.push_back(operation_row(s));
    if (rc != SQLITE_DONE) return s.error("listing operations");
    return rows;
  }
  Result<int> fail_unfinished_operations(int error_code, const std::string& message) override {
    std::lock_guard<std::mutex> lock(mutex_);
    Statement s(db_, "UPDATE operations SET state = 'FAILED', error_code = ?, error_message = ? "
                     "WHERE state IN ('QUEUED', 'RUNNING')");
    s.bind(1, static_cast<int64_t>(error_code)).bind(2, message);
    if (s.step() != SQLITE_DONE) return s.error("marking interrupted builds");
    return sqlite3_changes(db_);
  }

  Result<uint64_t> total_bytes() override {
    std::lock_guard<std::mutex> lock(mutex_);
    Statement s(db_, "SELECT (SELECT COALESCE(SUM(size_bytes), 0) FROM volumes) + "
                     "(SELECT COALESCE(SUM(size_bytes), 0) FROM rigs)");
    if (s.step() != SQLITE_ROW) return s.error("summing the store's size");
    return static_cast<uint64_t>(s.integer(0));
  }

 private:
  Status delete_from(const std::string& table, const std::string& id) {
    std::lock_guard<std::mutex> lock(mutex_);
    Statement s(db_, ("DELETE FROM " + table + " WHERE id = ?").c_str());
    s.bind(1, id);
    return s.step() == SQLITE_DONE ? ok_status() : s.error("removing a row of " + table);
  }

  sqlite3* db_;
  std::mutex mutex_;
};

}  // namespace

Result<std::unique_ptr<StoreIndex>> open_sqlite_index(const std::string& path) {
  sqlite3* db = nullptr;
  if (sqlite3_open_v2(path.c_str(), &db, SQLITE_OPEN_READWRITE | SQLITE_OPEN_CREATE | SQLITE_OPEN_FULLMUTEX,
                      nullptr) != SQLITE_OK) {
    const std::string message = db == nullptr ? "out of memory" : sqlite3_errmsg(db);
    sqlite3_close(db);
    return failed_precondition_error("cannot open the store's index '" + path + "': " + message +
                                     " (check the store directory's permissions and disk)");
  }
  sqlite3_busy_timeout(db, 10000);
  auto index = std::make_unique<SqliteIndex>(db);
  POSEWARP_RETURN_IF_ERROR(index->exec("PRAGMA journal_mode=WAL; PRAGMA synchronous=FULL;", "opening"));
  POSEWARP_RETURN_IF_ERROR(index->exec(index_schema(kDialect).c_str(), "creating its tables"));
  if (Status s = index->exec("SELECT count(*) FROM rigs", "checking its integrity"); !s.ok()) {
    return data_loss_error(s.message() + "; the index '" + path + "' is damaged (move it aside: the server rebuilds "
                           "it from the rig files at the next start)");
  }
  return std::unique_ptr<StoreIndex>(std::move(index));
}

}  // namespace posewarp::server
