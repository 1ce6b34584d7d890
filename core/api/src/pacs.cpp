// api::Pacs over the pacs stage's DICOMweb client.
#include "posewarp/api/pacs.h"

#include "posewarp/pacs/dicomweb.h"

namespace posewarp::api {

struct Pacs::Client {
  pacs::DicomWebClient client;
};

Pacs::Pacs(DicomWebOptions options)
    : client_(std::make_unique<const Client>(Client{pacs::DicomWebClient(std::move(options))})) {}
Pacs::~Pacs() = default;
Pacs::Pacs(Pacs&&) noexcept = default;
Pacs& Pacs::operator=(Pacs&&) noexcept = default;

Result<std::vector<DicomWebRecord>> Pacs::search_studies(const std::string& query) const {
  return client_->client.search_studies(query);
}

Result<std::vector<DicomWebRecord>> Pacs::search_series(const std::string& study_uid) const {
  return client_->client.search_series(study_uid);
}

Result<std::vector<std::string>> Pacs::retrieve_series(const std::string& study_uid, const std::string& series_uid,
                                                       const std::string& directory) const {
  return client_->client.retrieve_series(study_uid, series_uid, directory);
}

Status Pacs::store(const std::vector<std::string>& instances, const std::string& study_uid) const {
  return client_->client.store(instances, study_uid);
}

Status Pacs::store_files(const std::vector<std::string>& paths) const {
  return client_->client.store_files(paths);
}

}  // namespace posewarp::api
