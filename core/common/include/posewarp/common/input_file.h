// Files a reader is handed: only regular files are opened (a directory, a FIFO or a device gets a message instead of
// a hang or a read until memory runs out), and small text inputs are read whole within a size limit.
#pragma once

#include <cstdint>
#include <string>
#include <string_view>

#include "posewarp/common/result.h"

namespace posewarp {

// OK for a readable regular file (symbolic links followed). NOT_FOUND when nothing is there; INVALID_ARGUMENT for a
// directory, FIFO, socket or device, naming what it is; PERMISSION_DENIED when it cannot be read. `kind` names what
// was expected in the message ("pose", "rig file").
Status check_input_file(const std::string& path, std::string_view kind);

// Largest text input (pose, label map, rig spec, BVH map) read whole: far above any real one.
inline constexpr int64_t kMaxTextFileBytes = int64_t{64} << 20;

// The whole file after check_input_file; INVALID_ARGUMENT when it is larger than `max_bytes`.
Result<std::string> read_text_input(const std::string& path, std::string_view kind,
                                    int64_t max_bytes = kMaxTextFileBytes);

}  // namespace posewarp
