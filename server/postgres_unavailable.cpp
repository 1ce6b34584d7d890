// A server built without libpqxx: one machine, SQLite only.
#include "store.h"

namespace posewarp::server {

Result<std::unique_ptr<StoreIndex>> open_postgres_index(const std::string&) {
  return unimplemented_error("this posewarp-server was built without PostgreSQL (libpqxx-dev); --database needs it");
}

}  // namespace posewarp::server
