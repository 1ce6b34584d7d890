// Status mapping: code for code, paths out.
#include "status_map.h"

namespace posewarp::server {

std::string without_path(std::string message, const std::string& path, const std::string& name) {
  if (path.empty()) return message;
  for (size_t at = message.find(path); at != std::string::npos; at = message.find(path, at + name.size())) {
    message.replace(at, path.size(), name);
  }
  return message;
}

grpc::Status to_grpc(const Status& status, const std::string& store_directory) {
  if (status.ok()) return grpc::Status::OK;
  std::string message = status.message();
  message = without_path(std::move(message), store_directory + "/volumes/", "volume ");
  message = without_path(std::move(message), store_directory + "/rigs/", "rig ");
  message = without_path(std::move(message), store_directory, "the store");
  return {static_cast<grpc::StatusCode>(status.code()), message};
}

}  // namespace posewarp::server
