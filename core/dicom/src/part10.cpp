// Part 10 bytes through DCMTK's buffer streams.
#include "part10.h"

#include <dcmtk/dcmdata/dcistrmb.h>
#include <dcmtk/dcmdata/dcostrmb.h>
#include <dcmtk/dcmdata/dcrledrg.h>
#include <dcmtk/dcmjpeg/djdecode.h>
#include <dcmtk/dcmjpls/djdecode.h>

#include <mutex>

#include "posewarp/dicom/ct_series.h"

namespace posewarp::dicom {

Result<std::unique_ptr<DcmFileFormat>> parse_part10(const std::string& bytes, const std::string& what) {
  auto file = std::make_unique<DcmFileFormat>();
  DcmInputBufferStream stream;
  stream.setBuffer(bytes.data(), static_cast<offile_off_t>(bytes.size()));
  stream.setEos();
  file->transferInit();
  const OFCondition read = file->read(stream);
  file->transferEnd();
  if (read.bad()) return data_loss_error(what + " is not a readable DICOM file: " + read.text());
  return file;
}

Result<std::string> encode_part10(DcmFileFormat& file, const std::string& what) {
  OFCondition ok = file.validateMetaInfo(EXS_LittleEndianExplicit);
  // The element length leaves out the preamble and meta header: room for them on top.
  const Uint32 length = file.calcElementLength(EXS_LittleEndianExplicit, EET_ExplicitLength);
  std::string bytes(static_cast<size_t>(length) + 4096, '\0');
  DcmOutputBufferStream out(bytes.data(), static_cast<offile_off_t>(bytes.size()));
  if (ok.good()) {
    file.transferInit();
    ok = file.write(out, EXS_LittleEndianExplicit, EET_ExplicitLength, nullptr);
    file.transferEnd();
  }
  if (ok.bad()) return internal_error("encoding " + what + " failed: " + ok.text());
  void* buffer = nullptr;
  offile_off_t used = 0;
  out.flushBuffer(buffer, used);
  bytes.resize(static_cast<size_t>(used));
  return bytes;
}

Status decode_pixel_data(DcmDataset& d, const std::string& what) {
  if (!DcmXfer(d.getOriginalXfer()).isEncapsulated()) return ok_status();
  static std::once_flag once;
  std::call_once(once, [] {
    quiet_dcmtk();
    DcmRLEDecoderRegistration::registerCodecs();
    DJDecoderRegistration::registerCodecs();
    DJLSDecoderRegistration::registerCodecs();
  });
  if (d.chooseRepresentation(EXS_LittleEndianExplicit, nullptr).bad() || !d.canWriteXfer(EXS_LittleEndianExplicit)) {
    return invalid_argument_error(what + " has pixel data in a transfer syntax posewarp cannot decode (" +
                                  std::string(DcmXfer(d.getOriginalXfer()).getXferName()) + ")");
  }
  return ok_status();
}

}  // namespace posewarp::dicom
