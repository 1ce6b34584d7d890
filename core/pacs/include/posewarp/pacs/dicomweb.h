// A DICOMweb client (libcurl) for PACS-side work: QIDO-RS search, WADO-RS retrieval of a series (multipart/related
// application/dicom, streamed to disk part by part) and STOW-RS storage, with basic auth or a bearer token, TLS
// verification on by default, timeouts, and retries with backoff on connection errors and 5xx answers.
#pragma once

#include <cstdint>
#include <map>
#include <string>
#include <vector>

#include "posewarp/common/dicomweb.h"
#include "posewarp/common/result.h"

namespace posewarp::pacs {

// How to reach the PACS and what one study record holds (posewarp/common/dicomweb.h).
using posewarp::DicomWebOptions;
using posewarp::DicomWebRecord;

class DicomWebClient {
 public:
  explicit DicomWebClient(DicomWebOptions options);

  // QIDO-RS: /studies?query, /studies/{study}/series?query (query: "Modality=CT&StudyDate=20250101-", as QIDO-RS
  // takes it).
  Result<std::vector<DicomWebRecord>> search_studies(const std::string& query) const;
  Result<std::vector<DicomWebRecord>> search_series(const std::string& study_uid, const std::string& query = "") const;
  // WADO-RS: every instance of a series, each written to `directory` as NNNNNN.dcm (the answer streams to a file
  // and is split there, never held whole in memory); the paths written.
  Result<std::vector<std::string>> retrieve_series(const std::string& study_uid, const std::string& series_uid,
                                                   const std::string& directory) const;
  // STOW-RS: instances (Part 10 bytes) stored in one request (to /studies/{study} when a study is given).
  Status store(const std::vector<std::string>& instances, const std::string& study_uid = "") const;
  // The same from files, read as the request goes (a series of any size is never held in memory).
  Status store_files(const std::vector<std::string>& paths, const std::string& study_uid = "") const;

  // A request body sent piece by piece: text, bytes the caller keeps alive, or a file read in blocks.
  struct BodyPiece {
    std::string text;
    const std::string* bytes = nullptr;
    std::string path;
    uint64_t file_size = 0;
    uint64_t size() const { return !path.empty() ? file_size : bytes != nullptr ? bytes->size() : text.size(); }
  };

 private:
  struct Response {
    long status = 0;
    std::string body, content_type;
  };
  // One request with retries; `body` (optional) is sent (a POST), `body_file` (optional) receives the answer's body
  // instead of Response::body.
  Result<Response> request(const std::string& method, const std::string& url, const std::vector<std::string>& headers,
                           const std::vector<BodyPiece>* body, const std::string& body_file = "") const;
  // STOW-RS of parts (each an instance), framed as multipart/related.
  Status stow(std::vector<BodyPiece> parts, const std::string& study_uid) const;
  Result<std::vector<DicomWebRecord>> search(const std::string& path, const std::string& query) const;
  DicomWebOptions options_;
};

// The parts of a multipart body held in `file` (boundary from its Content-Type), written to `directory` as
// NNNNNN.dcm; streamed in blocks. Exposed for tests.
Result<std::vector<std::string>> split_multipart_file(const std::string& file, const std::string& content_type,
                                                      const std::string& directory);

}  // namespace posewarp::pacs
