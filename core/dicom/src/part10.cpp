// Part 10 bytes through DCMTK's buffer streams.
#include "part10.h"

#include <dcmtk/dcmdata/dcistrmb.h>
#include <dcmtk/dcmdata/dcostrmb.h>
#include <dcmtk/dcmdata/dcrledrg.h>
#include <dcmtk/dcmjpeg/djdecode.h>
#include <dcmtk/dcmjpls/djdecode.h>

#include <cstdio>
#include <mutex>
#include <vector>

#include "posewarp/dicom/ct_series.h"

namespace posewarp::dicom {
namespace {

uint16_t u16(const std::string& b, size_t p) {
  return static_cast<uint16_t>(static_cast<uint8_t>(b[p]) | static_cast<uint8_t>(b[p + 1]) << 8);
}
uint32_t u32(const std::string& b, size_t p) {
  return static_cast<uint32_t>(u16(b, p)) | static_cast<uint32_t>(u16(b, p + 2)) << 16;
}

// Explicit VRs whose length field is 4 bytes (after 2 reserved ones): all but the 2-byte ones below. DCMTK reads a
// VR it does not know with a 4-byte length too.
bool long_length(const char* vr) {
  static const char* const kShort[] = {"AE", "AS", "AT", "CS", "DA", "DS", "DT", "FL", "FD", "IS", "LO",
                                       "LT", "PN", "SH", "SL", "SS", "ST", "TM", "UI", "UL", "US"};
  for (const char* v : kShort) {
    if (vr[0] == v[0] && vr[1] == v[1]) return false;
  }
  return true;
}

// Where a walk over nested elements is: inside a sequence or an item (walked), or inside encapsulated pixel data
// (whose items are fragments, skipped); `end` is where a defined length ends it (npos: at its delimiter).
struct Nesting {
  bool fragments = false;
  size_t end = std::string::npos;
};

// The elements from `p` on in little-endian `explicit_vr` encoding: an error naming the first whose declared length
// runs past the bytes. DCMTK allocates a value's declared length before reading it, so a damaged length field (up to
// 4 GB) would otherwise cost that much memory before the read fails.
Status check_lengths(const std::string& b, size_t p, bool explicit_vr, const std::string& what) {
  std::vector<Nesting> open;
  const auto too_long = [&](uint16_t group, uint16_t element, uint32_t length) {
    char tag[16];
    std::snprintf(tag, sizeof tag, "(%04X,%04X)", group, element);
    return data_loss_error(what + " is not a readable DICOM file: element " + tag + " declares " +
                           std::to_string(length) + " bytes where " + std::to_string(b.size() - p) +
                           " remain (damaged or cut short)");
  };
  while (p + 8 <= b.size()) {
    while (!open.empty() && open.back().end != std::string::npos && p >= open.back().end) open.pop_back();
    const uint16_t group = u16(b, p), element = u16(b, p + 2);
    if (group == 0xFFFE) {  // item and delimiters: a 4-byte length, never a VR
      const uint32_t length = u32(b, p + 4);
      p += 8;
      if (element == 0xE0DD) {  // sequence delimiter: the innermost undefined-length sequence or pixel data ends
        while (!open.empty() && open.back().end != std::string::npos) open.pop_back();
        if (!open.empty()) open.pop_back();
        continue;
      }
      if (element != 0xE000 || length == 0xFFFFFFFF) continue;  // an item delimiter, or an item walked into
      if (length > b.size() - p) return too_long(group, element, length);
      if (!open.empty() && open.back().fragments) {
        p += length;  // a fragment of encapsulated pixel data: bytes
      } else {
        open.push_back({false, p + length});
      }
      continue;
    }
    uint32_t length = 0;
    bool sequence = false;
    if (explicit_vr) {
      const char vr[2] = {b[p + 4], b[p + 5]};
      sequence = vr[0] == 'S' && vr[1] == 'Q';
      if (long_length(vr)) {
        if (p + 12 > b.size()) break;
        length = u32(b, p + 8);
        p += 12;
      } else {
        length = u16(b, p + 6);
        p += 8;
      }
    } else {
      length = u32(b, p + 4);
      sequence = DcmTag(group, element).getEVR() == EVR_SQ;
      p += 8;
    }
    if (length == 0xFFFFFFFF) {  // a sequence, or encapsulated pixel data, up to its delimiter
      open.push_back({!sequence && !(group == 0xFFFE), std::string::npos});
      continue;
    }
    if (length > b.size() - p) return too_long(group, element, length);
    if (sequence) {
      open.push_back({false, p + length});  // its items are walked
    } else {
      p += length;
    }
  }
  return ok_status();
}

// Whether the element at `p` is in explicit VR: its tag followed by a VR that DICOM defines (DCMTK's own guess).
bool names_a_vr(const std::string& b, size_t p) {
  if (b.size() < p + 6) return false;
  const char vr[3] = {b[p + 4], b[p + 5], '\0'};
  return DcmVR(vr).isStandard();
}

// The lengths of a Part 10 file's meta header (explicit little endian) and of its dataset where it is little endian
// and not deflated (what DICOM stores in practice; DCMTK alone reads the rest). Bytes without the "DICM" preamble are
// a bare dataset, explicit when its first element names a VR.
Status check_part10_lengths(const std::string& b, const std::string& what) {
  if (b.size() >= 132 && b.compare(128, 4, "DICM") == 0) {
    size_t p = 132;
    std::string syntax;
    while (p + 8 <= b.size() && u16(b, p) == 0x0002) {
      const char vr[2] = {b[p + 4], b[p + 5]};
      const bool is_long = long_length(vr);
      if (is_long && p + 12 > b.size()) break;
      const uint32_t length = is_long ? u32(b, p + 8) : u16(b, p + 6);
      const size_t value = p + (is_long ? 12 : 8);
      if (length > b.size() - value) {
        return data_loss_error(what +
                               " is not a readable DICOM file: its meta header declares more bytes than it has "
                               "(damaged or cut short)");
      }
      if (u16(b, p + 2) == 0x0010) syntax = b.substr(value, length);
      p = value + length;
    }
    while (!syntax.empty() && (syntax.back() == '\0' || syntax.back() == ' ')) syntax.pop_back();
    if (syntax == "1.2.840.10008.1.2.2" || syntax == "1.2.840.10008.1.2.1.99") return ok_status();
    // Without a transfer syntax DCMTK guesses the encoding from the first element, as for a bare dataset.
    return check_lengths(b, p, syntax.empty() ? names_a_vr(b, p) : syntax != "1.2.840.10008.1.2", what);
  }
  return check_lengths(b, 0, names_a_vr(b, 0), what);
}

}  // namespace

Result<std::unique_ptr<DcmFileFormat>> parse_part10(const std::string& bytes, const std::string& what) {
  POSEWARP_RETURN_IF_ERROR(check_part10_lengths(bytes, what));
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
