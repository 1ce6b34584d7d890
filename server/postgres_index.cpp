// StoreIndex on PostgreSQL (libpqxx), for replicas that share one store: the same rows as the SQLite index, plus
// build claims and operation leases (a replica that dies stops renewing them, and another takes its builds over or
// marks them failed), and deleted rigs announced with NOTIFY so that every replica drops them from its cache.
// One connection for queries (serialized by a mutex, reconnected when it breaks) and one that LISTENs; while the
// database is down, calls answer UNAVAILABLE and the replica recovers on its own when it is back.
#include <pqxx/pqxx>

#include <atomic>
#include <chrono>
#include <mutex>
#include <thread>

#include "store.h"

namespace posewarp::server {
namespace {

const SchemaDialect kDialect{"BIGINT", "DOUBLE PRECISION", "BIGSERIAL", true};

constexpr const char* kChannel = "posewarp_rig_deleted";
constexpr const char* kRigColumns =
    "SELECT id, name, labels_volume_id, ct_volume_id, size_bytes, build_seconds, created, last_used FROM rigs ";
constexpr const char* kOperationColumns =
    "SELECT id, state, name, labels_volume_id, ct_volume_id, rig_id, error_code, error_message, elapsed_s, created "
    "FROM operations ";

bool live(const std::string& state) {
  return state == "QUEUED" || state == "RUNNING";
}

VolumeRecord volume_row(const pqxx::row& r) {
  return {r[0].as<std::string>(), r[1].as<std::string>(), r[2].as<std::string>(),
          r[3].as<uint64_t>(),    r[4].as<std::string>(), ""};
}

RigRecord rig_row(const pqxx::row& r) {
  return {r[0].as<std::string>(), r[1].as<std::string>(), r[2].as<std::string>(),
          r[3].as<std::string>(), r[4].as<uint64_t>(),    r[5].as<double>(),
          r[6].as<std::string>(), r[7].as<std::string>(), ""};
}

OperationRecord operation_row(const pqxx::row& r) {
  OperationRecord o;
  o.id = r[0].as<std::string>();
  o.state = r[1].as<std::string>();
  o.name = r[2].as<std::string>();
  o.labels_volume_id = r[3].as<std::string>();
  o.ct_volume_id = r[4].as<std::string>();
  o.rig_id = r[5].as<std::string>();
  o.error_code = r[6].as<int>();
  o.error_message = r[7].as<std::string>();
  o.elapsed_s = r[8].as<double>();
  o.created = r[9].as<std::string>();
  return o;
}

// Deleted rigs, as NOTIFY delivers them to the listening connection.
class DeletedRigs final : public pqxx::notification_receiver {
 public:
  DeletedRigs(pqxx::connection_base& connection, std::function<void(const std::string&)> callback)
      : pqxx::notification_receiver(connection, kChannel), callback_(std::move(callback)) {}
  void operator()(const std::string& payload, int) override { callback_(payload); }

 private:
  std::function<void(const std::string&)> callback_;
};

class PostgresIndex final : public StoreIndex {
 public:
  explicit PostgresIndex(std::string conninfo) : conninfo_(std::move(conninfo)) {}
  ~PostgresIndex() override {
    stop_ = true;
    if (listener_.joinable()) listener_.join();
  }

  // Connects and creates the tables (once, under an advisory lock: replicas may start together).
  Status open() {
    return run("creating its tables", [](pqxx::work& w) {
      w.exec("SELECT pg_advisory_xact_lock(7243901)");
      w.exec(index_schema(kDialect));
    });
  }

  bool shared() const override { return true; }

  Status put_volume(const VolumeRecord& v) override {
    return run("recording a volume", [&](pqxx::work& w) {
      w.exec_params(
          "INSERT INTO volumes VALUES ($1, $2, $3, $4, $5) ON CONFLICT (id) DO UPDATE SET kind = $2, "
          "extension = $3, size_bytes = $4",
          v.id, v.kind, v.extension, static_cast<int64_t>(v.size_bytes), v.created);
    });
  }
  Result<std::optional<VolumeRecord>> volume(const std::string& id) override {
    std::optional<VolumeRecord> found;
    POSEWARP_RETURN_IF_ERROR(run("looking up a volume", [&](pqxx::work& w) {
      const pqxx::result r =
          w.exec_params("SELECT id, kind, extension, size_bytes, created FROM volumes WHERE id = $1", id);
      if (!r.empty()) found = volume_row(r[0]);
    }));
    return found;
  }
  Result<std::vector<VolumeRecord>> volumes() override {
    std::vector<VolumeRecord> rows;
    POSEWARP_RETURN_IF_ERROR(run("listing volumes", [&](pqxx::work& w) {
      for (const pqxx::row& r : w.exec("SELECT id, kind, extension, size_bytes, created FROM volumes ORDER BY id")) {
        rows.push_back(volume_row(r));
      }
    }));
    return rows;
  }
  Status delete_volume(const std::string& id) override {
    return run("removing a volume's row",
               [&](pqxx::work& w) { w.exec_params("DELETE FROM volumes WHERE id = $1", id); });
  }

  Status put_rig(const RigRecord& r) override {
    return run("recording a rig", [&](pqxx::work& w) {
      w.exec_params(
          "INSERT INTO rigs VALUES ($1, $2, $3, $4, $5, $6, $7, $8) ON CONFLICT (id) DO UPDATE SET "
          "name = $2, labels_volume_id = $3, ct_volume_id = $4, size_bytes = $5, build_seconds = $6",
          r.id, r.name, r.labels_volume_id, r.ct_volume_id, static_cast<int64_t>(r.size_bytes), r.build_seconds,
          r.created, r.last_used);
    });
  }
  Result<std::optional<RigRecord>> rig(const std::string& id) override {
    std::optional<RigRecord> found;
    POSEWARP_RETURN_IF_ERROR(run("looking up a rig", [&](pqxx::work& w) {
      const pqxx::result r = w.exec_params(std::string(kRigColumns) + "WHERE id = $1", id);
      if (!r.empty()) found = rig_row(r[0]);
    }));
    return found;
  }
  Result<std::vector<RigRecord>> rigs(const std::string& after, int limit) override {
    std::vector<RigRecord> rows;
    POSEWARP_RETURN_IF_ERROR(run("listing rigs", [&](pqxx::work& w) {
      for (const pqxx::row& r :
           w.exec_params(std::string(kRigColumns) + "WHERE id > $1 ORDER BY id LIMIT $2", after, limit)) {
        rows.push_back(rig_row(r));
      }
    }));
    return rows;
  }
  Status touch_rig(const std::string& id, const std::string& when) override {
    return run("noting a rig's use",
               [&](pqxx::work& w) { w.exec_params("UPDATE rigs SET last_used = $1 WHERE id = $2", when, id); });
  }
  Status delete_rig(const std::string& id) override {
    // The row and the announcement commit together: every replica hears of a deletion that happened.
    return run("removing a rig's row", [&](pqxx::work& w) {
      w.exec_params("DELETE FROM rigs WHERE id = $1", id);
      w.exec_params("SELECT pg_notify($1, $2)", std::string(kChannel), id);
    });
  }

  Status put_operation(const OperationRecord& o) override {
    return run("recording an operation", [&](pqxx::work& w) {
      const bool leased = live(o.state) && o.lease_s > 0;
      w.exec_params(
          "INSERT INTO operations (id, state, name, labels_volume_id, ct_volume_id, rig_id, error_code, "
          "error_message, elapsed_s, created, owner, lease_until) VALUES ($1, $2, $3, $4, $5, $6, $7, $8, $9, $10, "
          "$11, CASE WHEN $12 THEN now() + make_interval(secs => $13) END) ON CONFLICT (id) DO UPDATE SET "
          "state = excluded.state, rig_id = excluded.rig_id, error_code = excluded.error_code, "
          "error_message = excluded.error_message, elapsed_s = excluded.elapsed_s, owner = excluded.owner, "
          "lease_until = excluded.lease_until",
          o.id, o.state, o.name, o.labels_volume_id, o.ct_volume_id, o.rig_id, o.error_code, o.error_message,
          o.elapsed_s, o.created, o.owner, leased, static_cast<double>(o.lease_s));
    });
  }
  Result<std::optional<OperationRecord>> operation(const std::string& id) override {
    std::optional<OperationRecord> found;
    POSEWARP_RETURN_IF_ERROR(run("looking up an operation", [&](pqxx::work& w) {
      const pqxx::result r = w.exec_params(std::string(kOperationColumns) + "WHERE id = $1", id);
      if (!r.empty()) found = operation_row(r[0]);
    }));
    return found;
  }
  Result<std::vector<OperationRecord>> operations(const std::string& before_id, int limit) override {
    std::vector<OperationRecord> rows;
    POSEWARP_RETURN_IF_ERROR(run("listing operations", [&](pqxx::work& w) {
      for (const pqxx::row& r :
           w.exec_params(std::string(kOperationColumns) +
                             "WHERE seq < COALESCE((SELECT seq FROM operations WHERE id = $1), 9223372036854775807) "
                             "ORDER BY seq DESC LIMIT $2",
                         before_id, limit)) {
        rows.push_back(operation_row(r));
      }
    }));
    return rows;
  }
  // Other replicas' builds may be running: only those whose lease has run out are over.
  Result<int> fail_unfinished_operations(int error_code, const std::string& message) override {
    return fail_expired_operations(error_code, message);
  }
  Result<int> fail_expired_operations(int error_code, const std::string& message) override {
    int changed = 0;
    POSEWARP_RETURN_IF_ERROR(run("marking builds whose replica stopped", [&](pqxx::work& w) {
      changed =
          static_cast<int>(w.exec_params("UPDATE operations SET state = 'FAILED', error_code = $1, error_message = $2, "
                                         "lease_until = NULL WHERE state IN ('QUEUED', 'RUNNING') AND "
                                         "(lease_until IS NULL OR lease_until < now())",
                                         error_code, message)
                               .affected_rows());
    }));
    return changed;
  }
  Status renew_operations(const std::string& owner, int lease_s) override {
    return run("renewing this replica's leases", [&](pqxx::work& w) {
      w.exec_params(
          "UPDATE operations SET lease_until = now() + make_interval(secs => $2) WHERE owner = $1 AND "
          "state IN ('QUEUED', 'RUNNING')",
          owner, static_cast<double>(lease_s));
      w.exec_params("UPDATE build_claims SET lease_until = now() + make_interval(secs => $2) WHERE owner = $1", owner,
                    static_cast<double>(lease_s));
    });
  }

  Result<bool> claim_build(const std::string& rig_id, const std::string& owner, int lease_s) override {
    bool mine = false;
    POSEWARP_RETURN_IF_ERROR(run("claiming a build", [&](pqxx::work& w) {
      const pqxx::result r = w.exec_params(
          "INSERT INTO build_claims VALUES ($1, $2, now() + make_interval(secs => $3)) ON CONFLICT (rig_id) DO "
          "UPDATE SET owner = excluded.owner, lease_until = excluded.lease_until WHERE build_claims.owner = "
          "excluded.owner OR build_claims.lease_until < now() RETURNING owner",
          rig_id, owner, static_cast<double>(lease_s));
      mine = !r.empty();
    }));
    return mine;
  }
  Status release_build(const std::string& rig_id, const std::string& owner) override {
    return run("releasing a build's claim", [&](pqxx::work& w) {
      w.exec_params("DELETE FROM build_claims WHERE rig_id = $1 AND owner = $2", rig_id, owner);
    });
  }

  Result<uint64_t> total_bytes() override {
    uint64_t total = 0;
    POSEWARP_RETURN_IF_ERROR(run("summing the store's size", [&](pqxx::work& w) {
      total = w.exec(
                   "SELECT (SELECT COALESCE(SUM(size_bytes), 0) FROM volumes) + "
                   "(SELECT COALESCE(SUM(size_bytes), 0) FROM rigs)")[0][0]
                  .as<uint64_t>();
    }));
    return total;
  }

  // A thread of its own LISTENs; after a lost connection it reconnects and calls `resync` (notifications sent
  // meanwhile were missed: the caller checks what it holds).
  void watch_deleted_rigs(std::function<void(const std::string&)> deleted, std::function<void()> resync) override {
    listener_ = std::thread([this, deleted = std::move(deleted), resync = std::move(resync)] {
      bool first = true;
      while (!stop_) {
        try {
          pqxx::connection connection(conninfo_);
          DeletedRigs receiver(connection, deleted);
          if (!first) resync();
          first = false;
          while (!stop_) connection.await_notification(0, 250000);
        } catch (const std::exception&) {
          for (int i = 0; i < 10 && !stop_; ++i) std::this_thread::sleep_for(std::chrono::milliseconds(100));
        }
      }
    });
  }

 private:
  // One transaction on the query connection (made or remade as needed): UNAVAILABLE while the database cannot be
  // reached, INTERNAL for an SQL error.
  template <typename Body>
  Status run(const std::string& doing, Body&& body) {
    std::lock_guard<std::mutex> lock(mutex_);
    for (int attempt = 0; attempt < 2; ++attempt) {
      try {
        if (!connection_ || !connection_->is_open()) connection_ = std::make_unique<pqxx::connection>(conninfo_);
        pqxx::work w(*connection_);
        body(w);
        w.commit();
        return ok_status();
      } catch (const pqxx::broken_connection& error) {
        connection_.reset();  // a restarted database: one fresh connection is tried at once
        if (attempt == 1) {
          return unavailable_error("the store's database cannot be reached while " + doing + " (" +
                                   first_line(error.what()) + "); try again shortly");
        }
      } catch (const pqxx::in_doubt_error& error) {
        connection_.reset();
        return unavailable_error("the store's database went away while " + doing + "; try again shortly");
      } catch (const std::exception& error) {
        return internal_error("the store's index failed while " + doing + ": " + first_line(error.what()));
      }
    }
    return unavailable_error("the store's database cannot be reached while " + doing);
  }

  static std::string first_line(const std::string& text) {
    const size_t end = text.find('\n');
    return end == std::string::npos ? text : text.substr(0, end);
  }

  std::string conninfo_;
  std::mutex mutex_;
  std::unique_ptr<pqxx::connection> connection_;
  std::thread listener_;
  std::atomic<bool> stop_{false};
};

}  // namespace

Result<std::unique_ptr<StoreIndex>> open_postgres_index(const std::string& conninfo) {
  auto index = std::make_unique<PostgresIndex>(conninfo);
  if (Status s = index->open(); !s.ok()) {
    return Status(s.code(), s.message() +
                                " (the database is --database; its password goes in PGPASSFILE or "
                                "~/.pgpass, never on the command line)");
  }
  return std::unique_ptr<StoreIndex>(std::move(index));
}

}  // namespace posewarp::server
