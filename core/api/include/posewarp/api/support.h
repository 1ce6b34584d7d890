// core/common's shared mechanisms, named through the facade for server/ and the CLI (which include posewarp/api
// only): files written whole, inputs read within limits, content ids, the strict JSON reader, the clients' retry
// policy, the stopwatch, the process's thread ceiling, and the voxel memory kept for the next pose.
#pragma once

#include "posewarp/common/atomic_file.h"
#include "posewarp/common/input_file.h"
#include "posewarp/common/json.h"
#include "posewarp/common/parallel.h"
#include "posewarp/common/progress.h"
#include "posewarp/common/result.h"
#include "posewarp/common/retry.h"
#include "posewarp/common/sha256.h"
#include "posewarp/common/stopwatch.h"
#include "posewarp/common/voxel_memory.h"

namespace posewarp::api {

// Files in general: inputs read whole within a limit, outputs (files and directories) written atomically, ids.
using posewarp::AtomicDirectory;
using posewarp::AtomicFile;
using posewarp::is_hex_id;
using posewarp::read_text_input;
using posewarp::remove_stale_partial_files;
using posewarp::Sha256;
using posewarp::sha256_hex;
using posewarp::write_file_atomically;

// Every JSON input read strictly (depth, keys given twice, numbers past a double).
using posewarp::parse_json;

// Waits between a client's tries; timings.
using posewarp::RetryPolicy;
using posewarp::StageTimer;
using posewarp::Stopwatch;

// The process-wide ceiling on worker threads, for programs that own the process (the CLI's --threads).
using posewarp::set_thread_count;

// How much of the last poses' freed outputs the process keeps for the next pose of the same size (a server's share
// of its memory ceiling), and for how long when no pose takes it.
using posewarp::set_voxel_memory_kept_limit;
using posewarp::trim_voxel_memory;
using posewarp::voxel_memory_kept;

}  // namespace posewarp::api
