// The PACS options the commands that talk DICOMweb share (batch, dicom store): where, who, and how to trust it.
#pragma once

#include <CLI/CLI.hpp>

#include <string>

#include "posewarp/api/files.h"
#include "posewarp/api/pacs.h"

namespace posewarp::cli {

struct PacsOptions {
  std::string url, user, password_file, token_file, ca;
  bool insecure = false;
};

inline void add_pacs_options(CLI::App* cmd, PacsOptions& o) {
  cmd->add_option("--pacs", o.url, "The PACS's DICOMweb root, e.g. http://host:8042/dicom-web");
  cmd->add_option("--pacs-user", o.user, "HTTP basic auth user");
  cmd->add_option("--pacs-password-file", o.password_file, "File holding the password (never on the command line)");
  cmd->add_option("--pacs-token-file", o.token_file, "File holding a bearer token instead");
  cmd->add_option("--pacs-ca", o.ca, "CA certificate bundle of an HTTPS PACS");
  cmd->add_flag("--pacs-insecure", o.insecure, "Do not verify the PACS's TLS certificate (a test PACS only)");
}

// The client's options, the secrets read from their files (first line).
inline Result<api::DicomWebOptions> dicomweb_options(const PacsOptions& o) {
  if (o.url.empty()) return invalid_argument_error("give --pacs URL (the PACS's DICOMweb root)");
  api::DicomWebOptions options;
  options.base_url = o.url;
  options.username = o.user;
  options.verify_tls = !o.insecure;
  options.ca_file = o.ca;
  for (auto [file, field] : {std::pair{&o.password_file, &options.password}, {&o.token_file, &options.bearer_token}}) {
    if (file->empty()) continue;
    POSEWARP_ASSIGN_OR_RETURN(std::string secret, api::read_text_input(*file, "secret file", 1 << 16));
    secret = secret.substr(0, secret.find_first_of("\r\n"));
    *field = secret;
  }
  return options;
}

}  // namespace posewarp::cli
