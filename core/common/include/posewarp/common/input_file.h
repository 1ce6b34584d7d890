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

// Deepest nesting of JSON arrays and objects accepted: posewarp's own formats need 6; a hostile file nested a million
// levels deep would otherwise exhaust the stack when a message prints part of it.
inline constexpr int kMaxJsonDepth = 64;

// INVALID_ARGUMENT naming `what` when `json_text` nests arrays or objects deeper than `max_depth` (strings skipped;
// a scan, no parse).
Status check_json_depth(std::string_view json_text, const std::string& what, int max_depth = kMaxJsonDepth);

// Partial files of the atomic writers: ".posewarp-partial-<pid>-<name>" beside the target, renamed over it once
// complete. A process killed while writing leaves one behind; the pid says whether its writer is still alive.
std::string partial_file_name(const std::string& target_name);

// Removes the partial files in `directory` whose writing process no longer exists (a crash, kill -9); returns how
// many. Files of live processes and anything else are left alone; errors are ignored (it is housekeeping).
int remove_stale_partial_files(const std::string& directory);

}  // namespace posewarp
