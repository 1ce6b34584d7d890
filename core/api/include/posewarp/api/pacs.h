// The PACS through DICOMweb (QIDO-RS search, WADO-RS retrieve, STOW-RS store), as the batch uses it.
#pragma once

#include "posewarp/pacs/dicomweb.h"

namespace posewarp::api {

using pacs::DicomWebClient;
using pacs::DicomWebOptions;
using pacs::DicomWebRecord;

}  // namespace posewarp::api
