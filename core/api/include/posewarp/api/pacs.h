// The PACS through DICOMweb (QIDO-RS search, WADO-RS retrieve, STOW-RS store), as the batch uses it.
#pragma once

#include <memory>
#include <string>
#include <vector>

#include "posewarp/common/dicomweb.h"
#include "posewarp/common/result.h"

namespace posewarp::api {

using posewarp::DicomWebOptions;
using posewarp::DicomWebRecord;

class Pacs {
 public:
  explicit Pacs(DicomWebOptions options);
  ~Pacs();
  Pacs(Pacs&&) noexcept;
  Pacs& operator=(Pacs&&) noexcept;

  // QIDO-RS: the studies a query ("PatientID=7") finds, and a study's series.
  Result<std::vector<DicomWebRecord>> search_studies(const std::string& query) const;
  Result<std::vector<DicomWebRecord>> search_series(const std::string& study_uid) const;
  // WADO-RS: a series' instances written into `directory`; their paths.
  Result<std::vector<std::string>> retrieve_series(const std::string& study_uid, const std::string& series_uid,
                                                   const std::string& directory) const;
  // STOW-RS: instances (paths of DICOM files) stored, into `study_uid` when given.
  Status store(const std::vector<std::string>& instances, const std::string& study_uid = "") const;
  Status store_files(const std::vector<std::string>& paths) const;

 private:
  struct Client;  // the pacs stage's DicomWebClient (pacs.cpp)
  std::unique_ptr<const Client> client_;
};

}  // namespace posewarp::api
