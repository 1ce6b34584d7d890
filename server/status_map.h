// The core's Status -> grpc::Status, in one place. The codes are numerically equal; messages lose every server
// path (store files are named by their id), so no client learns where the server keeps its data.
#pragma once

#include <grpcpp/support/status.h>

#include <string>

#include "posewarp/api/files.h"

namespace posewarp::server {

grpc::Status to_grpc(const Status& status, const std::string& store_directory);
// The message with every occurrence of `path` replaced by `name`.
std::string without_path(std::string message, const std::string& path, const std::string& name);

}  // namespace posewarp::server
