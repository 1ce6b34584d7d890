// The DICOM tests' way to change a written object: Part 10 bytes parsed, a dataset edited, bytes again.
#pragma once

#include <dcmtk/config/osconfig.h>
#include <dcmtk/dcmdata/dcfilefo.h>
#include <dcmtk/dcmdata/dcistrmb.h>
#include <dcmtk/dcmdata/dcostrmb.h>
#include <gtest/gtest.h>

#include <functional>
#include <string>

namespace posewarp::dicom {

// `file` as Part 10 bytes (explicit little endian).
inline std::string part10_bytes(DcmFileFormat& file, size_t capacity) {
  std::string out(capacity, '\0');
  DcmOutputBufferStream stream(out.data(), static_cast<offile_off_t>(out.size()));
  file.transferInit();
  EXPECT_TRUE(file.write(stream, EXS_LittleEndianExplicit, EET_ExplicitLength, nullptr).good());
  file.transferEnd();
  void* buffer = nullptr;
  offile_off_t used = 0;
  stream.flushBuffer(buffer, used);
  out.resize(static_cast<size_t>(used));
  return out;
}

// Parses Part 10 bytes, lets `edit` change the dataset, and encodes it again.
inline std::string edited(const std::string& bytes, const std::function<void(DcmDataset&)>& edit) {
  DcmFileFormat file;
  DcmInputBufferStream in;
  in.setBuffer(bytes.data(), static_cast<offile_off_t>(bytes.size()));
  in.setEos();
  file.transferInit();
  EXPECT_TRUE(file.read(in).good());
  file.transferEnd();
  edit(*file.getDataset());
  return part10_bytes(file, bytes.size() + 65536);
}

}  // namespace posewarp::dicom
