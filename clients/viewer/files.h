// What posewarp-view writes on the user's machine: the posed volumes, surfaces, report and pose of a Pose call,
// in the CLI's formats, each file written beside its name and renamed into place (never half-written).
#pragma once

#include <string>

#include "viewer_client.h"

namespace posewarp::view {

// Writes the directory `dir` (which must not exist; made whole through DIR.partial): labels.nii.gz and ct.nii.gz
// (the server's NIfTI bytes), report.json, pose.json and surfaces/NAME.vtp; false with a message naming what could
// not be written.
bool save_posed(const PosedVolumes& posed, const std::string& dir, std::string* error);

// Writes `text` to `path` through a partial file, flushed to disk and renamed; false with a message.
bool write_file(const std::string& path, const std::string& text, std::string* error);

}  // namespace posewarp::view
