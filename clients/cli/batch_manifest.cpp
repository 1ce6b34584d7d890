// Manifests: rows from JSON or CSV, checked, and the keys a rerun recognizes them by.
#include "batch_manifest.h"

#include <filesystem>
#include <fstream>
#include <set>
#include <sstream>

namespace posewarp::cli {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

constexpr const char* kColumns[] = {"id",        "labels",     "ct",        "label_map",  "preset", "dicom_ct",
                                    "dicom_seg", "pacs_study", "ct_series", "seg_series", "pose",   "animation",
                                    "match",     "standard",   "method",    "out_dir",    "to_pacs"};

Status set_field(Row& row, const std::string& key, const std::string& value, const std::string& where) {
  std::string* fields[] = {&row.id,        &row.labels,     &row.ct,        &row.label_map,
                           &row.preset,    &row.dicom_ct,   &row.dicom_seg, &row.pacs_study,
                           &row.ct_series, &row.seg_series, &row.pose,      &row.animation,
                           &row.match,     &row.standard,   &row.method,    &row.out_dir};
  for (size_t i = 0; i < std::size(fields); ++i) {
    if (key == kColumns[i]) {
      // An empty value clears a default (a row of files in a manifest whose defaults name DICOM), except for the
      // method and the preset, which keep theirs.
      if (!value.empty() || (key != "method" && key != "preset")) *fields[i] = value;
      return ok_status();
    }
  }
  if (key == "to_pacs") {
    row.to_pacs = value == "true" || value == "1" || value == "yes";
    return ok_status();
  }
  return invalid_argument_error(
      where + ": unknown field '" + key +
      "'; a row has: id, labels, ct, label_map, preset, "
      "dicom_ct, dicom_seg, pacs_study, ct_series, seg_series, pose, animation, match, standard, "
      "method, "
      "out_dir, to_pacs");
}

// One CSV line's fields (double quotes around a field that holds commas; "" inside it is a quote).
std::vector<std::string> csv_fields(const std::string& line) {
  std::vector<std::string> out(1);
  bool quoted = false;
  for (size_t i = 0; i < line.size(); ++i) {
    const char c = line[i];
    if (quoted && c == '"' && i + 1 < line.size() && line[i + 1] == '"') {
      out.back() += '"';
      ++i;
    } else if (c == '"') {
      quoted = !quoted;
    } else if (c == ',' && !quoted) {
      out.emplace_back();
    } else if (c != '\r') {
      out.back() += c;
    }
  }
  return out;
}

// Paths in a manifest are relative to the manifest's directory.
void resolve(Row& row, const fs::path& base) {
  for (std::string* path : {&row.labels, &row.ct, &row.label_map, &row.dicom_ct, &row.dicom_seg, &row.pose,
                            &row.animation, &row.match, &row.out_dir}) {
    if (!path->empty() && fs::path(*path).is_relative()) *path = (base / *path).lexically_normal().string();
    while (path->size() > 1 && path->back() == '/') path->pop_back();
  }
}

// A file's size and modification time, which change when it is written again.
std::string file_stamp(const std::string& file) {
  std::error_code ec;
  return std::to_string(fs::file_size(file, ec)) + "@" +
         std::to_string(fs::last_write_time(file, ec).time_since_epoch().count());
}

}  // namespace

std::string csv_field(const std::string& value) {
  if (value.find_first_of(",\"\n") == std::string::npos) return value;
  std::string quoted = "\"";
  for (char c : value) quoted += c == '"' ? std::string("\"\"") : std::string(1, c);
  return quoted + "\"";
}

Status check_row(const Row& row, const std::string& where) {
  const int sources = (!row.labels.empty()) + (!row.dicom_seg.empty()) + (!row.pacs_study.empty());
  if (sources != 1) {
    return invalid_argument_error(where + ": give one input: labels (+ ct), dicom_ct + dicom_seg, or pacs_study");
  }
  if (!row.dicom_seg.empty() && row.dicom_ct.empty())
    return invalid_argument_error(where + ": dicom_seg needs dicom_ct");
  if ((!row.pose.empty()) + (!row.animation.empty()) + (!row.match.empty()) + (!row.standard.empty()) != 1) {
    return invalid_argument_error(where +
                                  ": give one of pose, animation, match (another scan's labels to match) or standard "
                                  "(a standard posture)");
  }
  if (row.method != "cor" && row.method != "dqs" && row.method != "lbs" && row.method != "fem") {
    return invalid_argument_error(where + ": method must be cor, dqs, lbs or fem, not '" + row.method + "'");
  }
  if (row.out_dir.empty() && !row.to_pacs) return invalid_argument_error(where + ": give out_dir, to_pacs or both");
  if (row.to_pacs && !row.labels.empty()) {
    return invalid_argument_error(where +
                                  ": to_pacs stores a derived series into the study it came from; a row "
                                  "from files has none (export it with posewarp dicom export first)");
  }
  return ok_status();
}

Result<std::vector<Row>> read_manifest(const std::string& path) {
  POSEWARP_ASSIGN_OR_RETURN(const std::string text, api::read_text_input(path, "batch manifest"));
  const fs::path base = fs::path(path).parent_path();
  std::vector<Row> rows;
  const size_t first = text.find_first_not_of(" \t\r\n");
  const bool is_json = fs::path(path).extension() == ".json" || (first != std::string::npos && text[first] == '{');
  if (is_json) {
    POSEWARP_ASSIGN_OR_RETURN(const json doc, parse_json<json>(text, "manifest '" + path + "'"));
    if (!doc.is_object() || !doc.contains("rows") || !doc["rows"].is_array()) {
      return invalid_argument_error("manifest '" + path +
                                    "' is not JSON with \"rows\": [...] (or a CSV with a header)");
    }
    const json defaults = doc.value("defaults", json::object());
    for (size_t i = 0; i < doc["rows"].size(); ++i) {
      const std::string where = "manifest '" + path + "' row " + std::to_string(i + 1);
      Row row;
      for (const json* source : {&defaults, &doc["rows"][i]}) {
        if (!source->is_object()) return invalid_argument_error(where + " is not an object");
        for (const auto& [key, value] : source->items()) {
          const std::string v = value.is_string()    ? value.get<std::string>()
                                : value.is_boolean() ? (value.get<bool>() ? "true" : "false")
                                                     : value.dump();
          POSEWARP_RETURN_IF_ERROR(set_field(row, key, v, where));
        }
      }
      rows.push_back(row);
    }
  } else {
    std::istringstream lines(text);
    std::string line;
    std::vector<std::string> header;
    for (int number = 1; std::getline(lines, line); ++number) {
      if (line.find_first_not_of(" \t\r") == std::string::npos || line[0] == '#') continue;
      if (header.empty()) {
        header = csv_fields(line);
        continue;
      }
      const std::vector<std::string> fields = csv_fields(line);
      const std::string where = "manifest '" + path + "' line " + std::to_string(number);
      if (fields.size() > header.size()) return invalid_argument_error(where + " has more fields than the header");
      Row row;
      for (size_t i = 0; i < fields.size(); ++i) POSEWARP_RETURN_IF_ERROR(set_field(row, header[i], fields[i], where));
      rows.push_back(row);
    }
  }
  std::set<std::string> ids, outs;
  for (size_t i = 0; i < rows.size(); ++i) {
    Row& row = rows[i];
    if (row.id.empty()) row.id = "row" + std::to_string(i + 1);
    if (!ids.insert(row.id).second)
      return invalid_argument_error("manifest '" + path + "': two rows are called '" + row.id + "'");
    resolve(row, base);
    POSEWARP_RETURN_IF_ERROR(check_row(row, "manifest '" + path + "' row '" + row.id + "'"));
    if (!row.out_dir.empty() && !outs.insert(row.out_dir).second) {
      return invalid_argument_error("manifest '" + path + "': two rows write to '" + row.out_dir +
                                    "'; give each its own out_dir");
    }
  }
  if (rows.empty()) return invalid_argument_error("manifest '" + path + "' has no rows");
  return rows;
}

std::string study_content_key(const Row& row) {
  nlohmann::json key{{"study", row.study_key()}, {"version", POSEWARP_VERSION}};
  std::vector<std::string> files{row.labels, row.ct, row.dicom_seg, row.label_map};
  std::error_code ec;
  if (!row.dicom_ct.empty() && fs::is_directory(row.dicom_ct, ec)) {
    for (const auto& entry : fs::directory_iterator(row.dicom_ct, ec)) files.push_back(entry.path().string());
  }
  for (const std::string& file : files) {
    if (file.empty() || !fs::is_regular_file(file, ec)) continue;
    key[file] = file_stamp(file);
  }
  return api::sha256_hex(key.dump());
}

std::string pose_hash(const Row& row) {
  if (!row.standard.empty()) return "standard " + row.standard;
  if (!row.match.empty()) return "match " + row.match + " " + file_stamp(row.match);
  const std::string& file = row.pose.empty() ? row.animation : row.pose;
  Result<std::string> text = api::read_text_input(file, "pose");
  return text.ok() ? api::sha256_hex(*text) : file;
}

std::string row_key(const Row& row) {
  return api::sha256_hex(nlohmann::json{
      {"study", study_content_key(row)},
      {"pose", pose_hash(row)},
      {"method", row.method},
      {"out_dir", row.out_dir},
      {"to_pacs",
       row.to_pacs}}.dump());
}

}  // namespace posewarp::cli
