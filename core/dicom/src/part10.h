// DICOM Part 10 bytes in and out through DCMTK, for the dicom stage's readers and writers.
#pragma once

#include <dcmtk/config/osconfig.h>  // before any other DCMTK header
#include <dcmtk/dcmdata/dcfilefo.h>

#include <memory>
#include <string>

#include "posewarp/common/result.h"

namespace posewarp::dicom {

// Parses Part 10 bytes; DATA_LOSS naming `what` when DCMTK cannot read them.
Result<std::unique_ptr<DcmFileFormat>> parse_part10(const std::string& bytes, const std::string& what);
// A file as Part 10 bytes, explicit little-endian; INTERNAL naming `what` when DCMTK cannot write it.
Result<std::string> encode_part10(DcmFileFormat& file, const std::string& what);
// Compressed pixel data of `d` (RLE, JPEG, JPEG-LS) decoded in place to explicit little-endian; nothing for
// uncompressed data; INVALID_ARGUMENT naming `what` for a transfer syntax DCMTK cannot decode.
Status decode_pixel_data(DcmDataset& d, const std::string& what);

}  // namespace posewarp::dicom
