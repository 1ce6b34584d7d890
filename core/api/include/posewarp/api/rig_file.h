// The rig artifact: one versioned, sectioned, checksummed binary file that loads without parsing text arrays.
//
// Layout (little endian):
//   magic "POSEWARP" | u32 format_version | u32 reserved
//   sections: u32 tag (four ASCII chars) | u32 flags | u64 payload_bytes | u64 payload_checksum | payload
//   final section "END!" with an empty payload whose checksum field holds the content hash.
// Unknown sections are skipped (and kept), so old readers survive new writers; a file whose format_version is
// newer than this reader's major version is refused with a message to upgrade.
#pragma once

#include <string>
#include <string_view>

#include "posewarp/api/rig.h"
#include "posewarp/common/progress.h"

namespace posewarp::api {

// 2: volumes stored in their source's type, in chunks that inflate in parallel (format 1 is still read).
constexpr uint32_t kRigFormatVersion = 2;

// Writes to a temporary file beside `path`, flushes it to disk (fsync) and renames it into place.
Status save_rig(const Rig& rig, const std::string& path);

// Reads and verifies every section's checksum. DATA_LOSS for a truncated or corrupt file, FAILED_PRECONDITION for
// a file from a newer format, INVALID_ARGUMENT for a file that is not a rig.
Result<Rig> load_rig(const std::string& path);

// load_rig, and the content hash the file's end marker holds, which the read has checked against the sections (what
// content_hash gives for a rig this format writes, without encoding every section again: a second on a 20M-voxel
// rig). For a rig of format 1 it is the hash of the sections as that file holds them.
Result<Rig> load_rig(const std::string& path, std::string& stored_content_hash);

// Adds to `rig` what this version keeps in a rig file and an older rig lacks, made from the rest of the rig: the
// engine's tables (sections OWNR, REGN, SUBS) and the mesh's skin vertices (SKIN). What the rig holds is kept as it
// is (its mesh, weights and volumes). Returns whether anything was added; FAILED_PRECONDITION for a rig without its
// label volume (one from before rigs held their volumes: rebuild it).
Result<bool> complete_rig(Rig& rig, const ProgressHooks& hooks = {});

// What complete_rig would add to `rig`, for a person ("the mesh's skin vertices (SKIN)"); empty when it lacks nothing.
std::string missing_from_rig(const Rig& rig);

// The same artifact in memory: what save_rig writes and load_rig reads, for a store or a network stream that
// holds rigs without files. `where` names the source in messages (a quoted path, "uploaded rig 3f2a...").
std::string rig_to_bytes(const Rig& rig);
Result<Rig> rig_from_bytes(std::string_view bytes, const std::string& where);

// Hash of the rig's content sections (geometry, label map, skeleton, mesh, weights, centres, parameters); excludes
// provenance (timings), so two builds of the same inputs with the same parameters in the mesher's sequential mode
// have the same content hash.
std::string content_hash(const Rig& rig);

}  // namespace posewarp::api
