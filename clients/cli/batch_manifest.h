// A batch's rows: what one row asks (a study from files, a DICOM directory or the PACS, a pose or an animation, a
// method, where its results go), read from a JSON or CSV manifest and checked, and the keys a rerun recognizes
// a row and its study by.
#pragma once

#include <nlohmann/json.hpp>

#include <string>
#include <vector>

#include "posewarp/api/support.h"

namespace posewarp::cli {

// One row: where the study comes from, what to do, where the results go.
struct Row {
  std::string id;
  std::string labels, ct, label_map, preset = "totalsegmentator";  // files
  std::string dicom_ct, dicom_seg;                                 // a DICOM series directory and its SEG
  std::string pacs_study, ct_series, seg_series;                   // a study in the PACS
  std::string pose, animation;
  // Or the pose found: `match` another scan's labels (a label file, named as the study's), or a `standard` posture.
  std::string match, standard;
  std::string method = "cor";
  std::string out_dir;
  bool to_pacs = false;
  std::string study_key() const {
    return nlohmann::json{{"labels", labels},         {"ct", ct},
                {"label_map", label_map},   {"preset", preset},
                {"dicom_ct", dicom_ct},     {"dicom_seg", dicom_seg},
                {"pacs_study", pacs_study}, {"ct_series", ct_series},
                {"seg_series", seg_series}}
        .dump();
  }
};

// The rows of a manifest: a JSON array of objects or a CSV file with a header line (the columns as Row's fields),
// paths relative to the manifest's folder; each row checked (check_row). INVALID_ARGUMENT naming the row and field.
Result<std::vector<Row>> read_manifest(const std::string& path);
// One source, a pose, an animation, a match or a standard posture, a known method, somewhere for the results; `where`
// names the row.
Status check_row(const Row& row, const std::string& where);
// A field of the summary's CSV, quoted when it must be.
std::string csv_field(const std::string& value);
// What a study's rig depends on: its inputs and their files' sizes and times (the rig cache's key).
std::string study_content_key(const Row& row);
// The row's pose or animation file, hashed (its name when it cannot be read); a match's target by its size and time;
// a standard posture by its name.
std::string pose_hash(const Row& row);
// A row done: its study's content, its pose, its method, and where its result goes. A rerun skips a row whose key the
// state file holds.
std::string row_key(const Row& row);

}  // namespace posewarp::cli
