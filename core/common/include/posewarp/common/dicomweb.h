// How to reach a PACS over DICOMweb, and one record of a search's answer: data the pacs stage and the api share.
#pragma once

#include <map>
#include <string>

namespace posewarp {

struct DicomWebOptions {
  std::string base_url;            // e.g. http://127.0.0.1:8042/dicom-web (no trailing slash needed)
  std::string username, password;  // HTTP basic auth, when given
  std::string bearer_token;        // Authorization: Bearer ..., when given
  bool verify_tls = true;          // off only for a test PACS with a self-signed certificate
  std::string ca_file;             // a CA bundle of one's own
  int connect_timeout_s = 10;
  int timeout_s = 120;  // a transfer slower than 1 kB/s for this long ends (a large one that moves does not)
  int retries = 3;      // on connection errors and 5xx: waits 0.5, 1, 2 s ... (RetryPolicy)
};

// One QIDO-RS result: its attributes by keyword (StudyInstanceUID, SeriesInstanceUID, Modality, ...), first values
// as text.
using DicomWebRecord = std::map<std::string, std::string>;

}  // namespace posewarp
