// DICOMweb over libcurl: QIDO-RS, WADO-RS (streamed to disk) and STOW-RS, with retries.
#include "posewarp/common/json.h"
#include "posewarp/common/retry.h"
#include "posewarp/pacs/dicomweb.h"

#include <curl/curl.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <mutex>
#include <random>
#include <thread>

namespace posewarp::pacs {
namespace fs = std::filesystem;
namespace {

void global_init() {
  static std::once_flag once;
  std::call_once(once, [] { curl_global_init(CURL_GLOBAL_DEFAULT); });
}

size_t to_string(char* data, size_t size, size_t count, void* out) {
  static_cast<std::string*>(out)->append(data, size * count);
  return size * count;
}

size_t to_file(char* data, size_t size, size_t count, void* out) {
  return std::fwrite(data, size, count, static_cast<FILE*>(out)) * size;
}

// The keywords of the attributes a search answers with (the rest keep their tag, e.g. "00200011").
const std::map<std::string, std::string>& keywords() {
  static const std::map<std::string, std::string> table{{"0020000D", "StudyInstanceUID"},
                                                        {"0020000E", "SeriesInstanceUID"},
                                                        {"00080060", "Modality"},
                                                        {"00080020", "StudyDate"},
                                                        {"00080030", "StudyTime"},
                                                        {"00100020", "PatientID"},
                                                        {"00100010", "PatientName"},
                                                        {"00081030", "StudyDescription"},
                                                        {"0008103E", "SeriesDescription"},
                                                        {"00200011", "SeriesNumber"},
                                                        {"00201209", "NumberOfSeriesRelatedInstances"},
                                                        {"00201208", "NumberOfStudyRelatedInstances"},
                                                        {"00080050", "AccessionNumber"},
                                                        {"00080016", "SOPClassUID"},
                                                        {"00080018", "SOPInstanceUID"},
                                                        {"00080061", "ModalitiesInStudy"}};
  return table;
}

std::string first_value(const nlohmann::json& attribute) {
  if (!attribute.is_object() || !attribute.contains("Value") || !attribute["Value"].is_array() ||
      attribute["Value"].empty()) {
    return "";
  }
  const nlohmann::json& v = attribute["Value"][0];
  if (v.is_string()) return v.get<std::string>();
  if (v.is_number_integer()) return std::to_string(v.get<int64_t>());
  if (v.is_number()) return std::to_string(v.get<double>());
  if (v.is_object() && v.contains("Alphabetic") && v["Alphabetic"].is_string())
    return v["Alphabetic"].get<std::string>();
  return "";
}

std::string boundary_of(const std::string& content_type) {
  const size_t at = content_type.find("boundary=");
  if (at == std::string::npos) return "";
  std::string b = content_type.substr(at + 9);
  if (!b.empty() && b.front() == '"') {
    const size_t end = b.find('"', 1);
    return end == std::string::npos ? "" : b.substr(1, end - 1);
  }
  const size_t end = b.find_first_of("; \t\r\n");
  return end == std::string::npos ? b : b.substr(0, end);
}

std::string new_boundary() {
  static std::mutex mutex;
  static std::mt19937_64 random(std::random_device{}());
  std::lock_guard<std::mutex> lock(mutex);
  char text[64];
  std::snprintf(text, sizeof text, "posewarp-%016llx", static_cast<unsigned long long>(random()));
  return text;
}

// Where a request body stands: the piece being sent and how much of it has gone.
struct BodyCursor {
  const std::vector<DicomWebClient::BodyPiece>* pieces = nullptr;
  size_t index = 0;
  uint64_t offset = 0;
  std::ifstream file;
  std::string failed;  // the file that could not be read as announced
};

size_t read_body(char* out, size_t size, size_t count, void* data) {
  BodyCursor& c = *static_cast<BodyCursor*>(data);
  const size_t room = size * count;
  size_t written = 0;
  while (written < room && c.index < c.pieces->size()) {
    const DicomWebClient::BodyPiece& piece = (*c.pieces)[c.index];
    const size_t n = static_cast<size_t>(std::min<uint64_t>(room - written, piece.size() - c.offset));
    if (!piece.path.empty()) {
      if (!c.file.is_open()) c.file.open(piece.path, std::ios::binary);
      c.file.read(out + written, static_cast<std::streamsize>(n));
      if (!c.file || static_cast<size_t>(c.file.gcount()) != n) {  // gone, unreadable, or shorter than announced
        c.failed = piece.path;
        return CURL_READFUNC_ABORT;
      }
    } else {
      const std::string& bytes = piece.bytes != nullptr ? *piece.bytes : piece.text;
      std::memcpy(out + written, bytes.data() + c.offset, n);
    }
    written += n;
    c.offset += n;
    if (c.offset == piece.size()) {
      ++c.index;
      c.offset = 0;
      if (c.file.is_open()) c.file.close();
    }
  }
  return written;
}

bool transient(CURLcode code) {
  switch (code) {
    case CURLE_COULDNT_CONNECT:
    case CURLE_OPERATION_TIMEDOUT:
    case CURLE_RECV_ERROR:
    case CURLE_SEND_ERROR:
    case CURLE_GOT_NOTHING:
    case CURLE_PARTIAL_FILE: return true;
    default: return false;
  }
}

}  // namespace

DicomWebClient::DicomWebClient(DicomWebOptions options) : options_(std::move(options)) {
  while (!options_.base_url.empty() && options_.base_url.back() == '/') options_.base_url.pop_back();
  global_init();
}

Result<DicomWebClient::Response> DicomWebClient::request(const std::string& method, const std::string& url,
                                                         const std::vector<std::string>& headers,
                                                         const std::vector<BodyPiece>* body,
                                                         const std::string& body_file) const {
  std::string last_error;
  const RetryPolicy retry{std::max(0, options_.retries)};
  for (int attempt = 0; attempt <= retry.retries; ++attempt) {
    if (attempt > 0) std::this_thread::sleep_for(retry.wait(attempt));
    std::unique_ptr<CURL, void (*)(CURL*)> curl(curl_easy_init(), curl_easy_cleanup);
    if (!curl) return internal_error("cannot start an HTTP request (libcurl)");
    struct curl_slist* list = nullptr;
    for (const std::string& h : headers) list = curl_slist_append(list, h.c_str());
    if (!options_.bearer_token.empty())
      list = curl_slist_append(list, ("Authorization: Bearer " + options_.bearer_token).c_str());
    std::unique_ptr<curl_slist, void (*)(curl_slist*)> header_list(list, curl_slist_free_all);
    CURL* c = curl.get();
    curl_easy_setopt(c, CURLOPT_URL, url.c_str());
    curl_easy_setopt(c, CURLOPT_HTTPHEADER, header_list.get());
    curl_easy_setopt(c, CURLOPT_NOSIGNAL, 1L);
    curl_easy_setopt(c, CURLOPT_CONNECTTIMEOUT, static_cast<long>(options_.connect_timeout_s));
    // A transfer that stalls (under 1 kB/s for timeout_s) ends; a large one that keeps moving is not cut off.
    curl_easy_setopt(c, CURLOPT_LOW_SPEED_LIMIT, 1024L);
    curl_easy_setopt(c, CURLOPT_LOW_SPEED_TIME, static_cast<long>(options_.timeout_s));
    curl_easy_setopt(c, CURLOPT_SSL_VERIFYPEER, options_.verify_tls ? 1L : 0L);
    curl_easy_setopt(c, CURLOPT_SSL_VERIFYHOST, options_.verify_tls ? 2L : 0L);
    if (!options_.ca_file.empty()) curl_easy_setopt(c, CURLOPT_CAINFO, options_.ca_file.c_str());
    if (!options_.username.empty()) {
      curl_easy_setopt(c, CURLOPT_HTTPAUTH, static_cast<long>(CURLAUTH_BASIC));
      curl_easy_setopt(c, CURLOPT_USERNAME, options_.username.c_str());
      curl_easy_setopt(c, CURLOPT_PASSWORD, options_.password.c_str());
    }
    BodyCursor cursor;  // from the start on every attempt
    const std::vector<BodyPiece> no_body;
    if (method == "POST") {
      if (body == nullptr) body = &no_body;
      uint64_t total = 0;
      for (const BodyPiece& piece : *body) total += piece.size();
      cursor.pieces = body;
      curl_easy_setopt(c, CURLOPT_POST, 1L);
      curl_easy_setopt(c, CURLOPT_READFUNCTION, read_body);
      curl_easy_setopt(c, CURLOPT_READDATA, &cursor);
      curl_easy_setopt(c, CURLOPT_POSTFIELDSIZE_LARGE, static_cast<curl_off_t>(total));
    }
    Response response;
    std::unique_ptr<FILE, int (*)(FILE*)> file(nullptr, std::fclose);
    if (!body_file.empty()) {
      file.reset(std::fopen(body_file.c_str(), "wb"));
      if (!file) return invalid_argument_error("cannot write '" + body_file + "' (is the directory writable?)");
      curl_easy_setopt(c, CURLOPT_WRITEFUNCTION, to_file);
      curl_easy_setopt(c, CURLOPT_WRITEDATA, file.get());
    } else {
      curl_easy_setopt(c, CURLOPT_WRITEFUNCTION, to_string);
      curl_easy_setopt(c, CURLOPT_WRITEDATA, &response.body);
    }
    const CURLcode code = curl_easy_perform(c);
    if (file && std::fflush(file.get()) != 0) return data_loss_error("cannot write '" + body_file + "' (disk full?)");
    if (code == CURLE_WRITE_ERROR) {
      return data_loss_error("cannot keep what the PACS sent in '" + body_file + "' (disk full?)");
    }
    if (code == CURLE_ABORTED_BY_CALLBACK && !cursor.failed.empty()) {
      return data_loss_error("'" + cursor.failed +
                             "' could not be read as it was sent (changed or removed meanwhile?)");
    }
    if (code != CURLE_OK) {
      last_error = std::string(curl_easy_strerror(code));
      if (transient(code)) continue;
      return unavailable_error("the PACS at " + options_.base_url + " did not answer: " + last_error);
    }
    curl_easy_getinfo(c, CURLINFO_RESPONSE_CODE, &response.status);
    char* type = nullptr;
    curl_easy_getinfo(c, CURLINFO_CONTENT_TYPE, &type);
    if (type != nullptr) response.content_type = type;
    if (response.status >= 500) {
      last_error = "HTTP " + std::to_string(response.status);
      continue;
    }
    if (response.status == 401 || response.status == 403) {
      return permission_denied_error("the PACS at " + options_.base_url + " refused the credentials (HTTP " +
                                     std::to_string(response.status) + "); check the user and password or token");
    }
    return response;
  }
  return unavailable_error("the PACS at " + options_.base_url + " failed " + std::to_string(options_.retries + 1) +
                           " times (" + last_error + "); is it running and reachable?");
}

Result<std::vector<DicomWebRecord>> DicomWebClient::search(const std::string& path, const std::string& query) const {
  const std::string url = options_.base_url + path + (query.empty() ? "" : "?" + query);
  POSEWARP_ASSIGN_OR_RETURN(const Response r, request("GET", url, {"Accept: application/dicom+json"}, nullptr));
  if (r.status == 204) return std::vector<DicomWebRecord>{};
  if (r.status != 200) {
    return invalid_argument_error("the PACS answered HTTP " + std::to_string(r.status) + " to the search " + path +
                                  (query.empty() ? "" : "?" + query));
  }
  const Result<nlohmann::json> parsed = parse_json<nlohmann::json>(r.body, "the PACS's search answer");
  if (!parsed.ok() || !parsed->is_array()) {
    return data_loss_error("the PACS's search answer is not a DICOM JSON array" +
                           (parsed.ok() ? std::string() : " (" + parsed.status().message() + ")"));
  }
  const nlohmann::json& doc = *parsed;
  std::vector<DicomWebRecord> records;
  for (const nlohmann::json& item : doc) {
    if (!item.is_object()) continue;
    DicomWebRecord record;
    for (const auto& [tag, attribute] : item.items()) {
      const auto known = keywords().find(tag);
      record[known == keywords().end() ? tag : known->second] = first_value(attribute);
    }
    records.push_back(std::move(record));
  }
  return records;
}

Result<std::vector<DicomWebRecord>> DicomWebClient::search_studies(const std::string& query) const {
  return search("/studies", query);
}

Result<std::vector<DicomWebRecord>> DicomWebClient::search_series(const std::string& study_uid,
                                                                  const std::string& query) const {
  return search("/studies/" + study_uid + "/series", query);
}

Result<std::vector<std::string>> DicomWebClient::retrieve_series(const std::string& study_uid,
                                                                 const std::string& series_uid,
                                                                 const std::string& directory) const {
  std::error_code ec;
  fs::create_directories(directory, ec);
  if (ec) return invalid_argument_error("cannot make the directory '" + directory + "': " + ec.message());
  const std::string body = (fs::path(directory) / ".wado-body.partial").string();
  const std::string url = options_.base_url + "/studies/" + study_uid + "/series/" + series_uid;
  Result<Response> r = request("GET", url, {"Accept: multipart/related; type=\"application/dicom\""}, nullptr, body);
  if (!r.ok()) {
    fs::remove(body, ec);
    return r.status();
  }
  if (r->status != 200) {
    fs::remove(body, ec);
    if (r->status == 404) return not_found_error("the PACS has no series " + series_uid + " in study " + study_uid);
    return invalid_argument_error("the PACS answered HTTP " + std::to_string(r->status) +
                                  " to the retrieval of series " + series_uid);
  }
  Result<std::vector<std::string>> parts = split_multipart_file(body, r->content_type, directory);
  fs::remove(body, ec);
  return parts;
}

Status DicomWebClient::store(const std::vector<std::string>& instances, const std::string& study_uid) const {
  std::vector<BodyPiece> parts(instances.size());
  for (size_t i = 0; i < instances.size(); ++i) parts[i].bytes = &instances[i];
  return stow(std::move(parts), study_uid);
}

Status DicomWebClient::store_files(const std::vector<std::string>& paths, const std::string& study_uid) const {
  std::vector<BodyPiece> parts(paths.size());
  for (size_t i = 0; i < paths.size(); ++i) {
    std::error_code ec;
    parts[i].path = paths[i];
    parts[i].file_size = fs::file_size(paths[i], ec);
    if (ec) return not_found_error("cannot read '" + paths[i] + "': " + ec.message());
  }
  return stow(std::move(parts), study_uid);
}

Status DicomWebClient::stow(std::vector<BodyPiece> parts, const std::string& study_uid) const {
  if (parts.empty()) return ok_status();
  const std::string boundary = new_boundary();
  std::vector<BodyPiece> body;
  body.reserve(2 * parts.size() + 1);
  for (size_t i = 0; i < parts.size(); ++i) {
    BodyPiece head;
    head.text = std::string(i == 0 ? "" : "\r\n") + "--" + boundary + "\r\nContent-Type: application/dicom\r\n\r\n";
    body.push_back(std::move(head));
    body.push_back(std::move(parts[i]));
  }
  BodyPiece tail;
  tail.text = "\r\n--" + boundary + "--\r\n";
  body.push_back(std::move(tail));
  const std::string url = options_.base_url + "/studies" + (study_uid.empty() ? "" : "/" + study_uid);
  POSEWARP_ASSIGN_OR_RETURN(
      const Response r,
      request("POST", url,
              {"Content-Type: multipart/related; type=\"application/dicom\"; boundary=" + boundary,
               "Accept: application/dicom+json", "Expect:"},  // no "100-continue" wait: the body goes at once
              &body));
  // 200: all stored; 202: some failed (FailedSOPSequence, 0008,1198); 409: none stored.
  const Result<nlohmann::json> doc = parse_json<nlohmann::json>(r.body, "the PACS's store answer");
  const bool failures = doc.ok() && doc->is_object() && doc->contains("00081198") &&
                        (*doc)["00081198"].contains("Value") && !(*doc)["00081198"]["Value"].empty();
  if (r.status == 200 && !failures) return ok_status();
  return invalid_argument_error("the PACS did not store every instance (HTTP " + std::to_string(r.status) + ")" +
                                (failures ? ": " + std::to_string((*doc)["00081198"]["Value"].size()) + " failed" : ""));
}

Result<std::vector<std::string>> split_multipart_file(const std::string& file, const std::string& content_type,
                                                      const std::string& directory) {
  const std::string boundary = boundary_of(content_type);
  if (boundary.empty()) {
    return data_loss_error("the PACS's answer is not multipart (Content-Type '" + content_type + "')");
  }
  std::ifstream in(file, std::ios::binary);
  if (!in) return data_loss_error("cannot read the PACS's answer from '" + file + "'");
  const std::string delimiter = "\r\n--" + boundary;
  // A leading "\r\n" makes the first boundary look like the others.
  std::string pending = "\r\n";
  std::vector<std::string> written;
  std::unique_ptr<std::ofstream> part;
  std::string part_path;
  enum class State { kPreamble, kAfterDelimiter, kHeaders, kBody } state = State::kPreamble;
  std::vector<char> block(1 << 20);
  bool eof = false, finished = false;
  const auto close_part = [&]() -> Status {
    if (!part) return ok_status();
    part->close();
    if (!*part) return data_loss_error("cannot write '" + part_path + "' (disk full?)");
    written.push_back(part_path);
    part.reset();
    return ok_status();
  };
  while (!finished) {
    if (!eof) {
      in.read(block.data(), static_cast<std::streamsize>(block.size()));
      pending.append(block.data(), static_cast<size_t>(in.gcount()));
      eof = in.gcount() == 0 || in.eof();
    }
    bool progressed = true;
    while (progressed && !finished) {
      progressed = false;
      if (state == State::kPreamble || state == State::kBody) {
        const size_t at = pending.find(delimiter);
        if (at == std::string::npos) {
          // Keep what could be the start of a delimiter; the rest belongs to the current part (or the preamble).
          const size_t keep = std::min(pending.size(), delimiter.size());
          if (state == State::kBody && pending.size() > keep)
            part->write(pending.data(), static_cast<std::streamsize>(pending.size() - keep));
          pending.erase(0, pending.size() - keep);
          break;
        }
        if (state == State::kBody) {
          part->write(pending.data(), static_cast<std::streamsize>(at));
          POSEWARP_RETURN_IF_ERROR(close_part());
        }
        pending.erase(0, at + delimiter.size());
        state = State::kAfterDelimiter;
        progressed = true;
      } else if (state == State::kAfterDelimiter) {
        if (pending.size() < 2) break;  // "--" closes, anything else starts a part's headers
        if (pending.compare(0, 2, "--") == 0) {
          finished = true;
          break;
        }
        state = State::kHeaders;
        progressed = true;
      } else {
        const size_t end = pending.find("\r\n\r\n");
        if (end == std::string::npos) break;
        pending.erase(0, end + 4);
        char name[32];
        std::snprintf(name, sizeof name, "%06zu.dcm", written.size() + 1);
        part_path = (fs::path(directory) / name).string();
        part = std::make_unique<std::ofstream>(part_path, std::ios::binary | std::ios::trunc);
        if (!*part) return invalid_argument_error("cannot write '" + part_path + "'");
        state = State::kBody;
        progressed = true;
      }
    }
    if (eof && !finished) {
      if (state != State::kPreamble) {
        part.reset();
        std::error_code ec;
        for (const std::string& p : written) fs::remove(p, ec);
        fs::remove(part_path, ec);
        return data_loss_error("the PACS's answer ended inside a part (a truncated transfer); try again");
      }
      break;
    }
  }
  if (written.empty()) return data_loss_error("the PACS's answer holds no DICOM parts (boundary " + boundary + ")");
  return written;
}

}  // namespace posewarp::pacs
