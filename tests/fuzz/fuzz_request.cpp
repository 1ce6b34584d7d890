// Fuzzes the server's request decoding: arbitrary bytes as each request message the server takes from a client,
// through the same checks the handlers run before any work (server/requests.cpp). The first byte picks the message.
#include <cstddef>
#include <cstdint>

#include "requests.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  using namespace posewarp;
  if (size < 1) return 0;
  const int kind = data[0] % 6;
  const void* bytes = data + 1;
  const int length = static_cast<int>(size - 1);
  server::RequestLimits limits;
  switch (kind) {
    case 0: {
      v1::PoseRequest request;
      if (request.ParseFromArray(bytes, length)) (void)server::check_pose_request(request);
      break;
    }
    case 1: {
      v1::UploadVolumeHeader header;
      if (header.ParseFromArray(bytes, length)) (void)server::check_upload_header(header, limits);
      break;
    }
    case 2: {
      v1::UploadRigHeader header;
      if (header.ParseFromArray(bytes, length)) (void)server::check_rig_upload_header(header, limits);
      break;
    }
    case 3: {
      v1::BuildRigRequest request;
      if (request.ParseFromArray(bytes, length)) (void)server::check_build_request(request);
      break;
    }
    case 4: {
      v1::PreviewRequest request;
      if (request.ParseFromArray(bytes, length)) (void)server::check_preview_request(request);
      break;
    }
    default: {
      v1::MatchPostureRequest request;
      if (request.ParseFromArray(bytes, length)) (void)server::check_match_request(request);
      break;
    }
  }
  return 0;
}
