// Part 10 bytes through DCMTK: read through a temporary file (lazily, so that lengths are checked), written to a
// buffer stream.
#include "part10.h"

#include <dcmtk/dcmdata/dcistrmf.h>
#include <dcmtk/dcmdata/dcostrmb.h>
#include <dcmtk/dcmdata/dcrledrg.h>
#include <dcmtk/dcmjpeg/djdecode.h>
#include <dcmtk/dcmjpls/djdecode.h>

#include <unistd.h>

#include <cstdlib>
#include <filesystem>
#include <mutex>

#include "posewarp/dicom/ct_series.h"

namespace posewarp::dicom {
namespace fs = std::filesystem;

namespace {

// Values longer than this are read lazily, from the file, after DCMTK has checked that the file holds them.
constexpr Uint32 kMaxEagerValue = 4096;

// A temporary file holding `bytes`, removed with the object.
class TemporaryCopy {
 public:
  static Result<std::unique_ptr<TemporaryCopy>> of(const std::string& bytes) {
    std::string path = (fs::temp_directory_path() / "posewarp-dicom-XXXXXX").string();
    const int fd = ::mkstemp(path.data());
    if (fd < 0) return internal_error("cannot make a temporary file in " + fs::temp_directory_path().string());
    auto copy = std::unique_ptr<TemporaryCopy>(new TemporaryCopy(path));
    size_t written = 0;
    while (written < bytes.size()) {
      const ssize_t n = ::write(fd, bytes.data() + written, bytes.size() - written);
      if (n <= 0) {
        ::close(fd);
        return internal_error("cannot write a temporary file in " + fs::temp_directory_path().string());
      }
      written += static_cast<size_t>(n);
    }
    ::close(fd);
    return copy;
  }
  ~TemporaryCopy() {
    std::error_code ignored;
    fs::remove(path_, ignored);
  }
  const std::string& path() const { return path_; }

 private:
  explicit TemporaryCopy(std::string path) : path_(std::move(path)) {}
  std::string path_;
};

}  // namespace

Result<std::unique_ptr<DcmFileFormat>> parse_part10(const std::string& bytes, const std::string& what) {
  // From memory DCMTK allocates an element's declared length before reading it: a damaged length field would cost
  // up to 4 GB. From a file it reads long values lazily and first checks that the file holds them; so the bytes are
  // read through a temporary copy, every value is loaded, and the copy goes.
  POSEWARP_ASSIGN_OR_RETURN(const std::unique_ptr<TemporaryCopy> copy, TemporaryCopy::of(bytes));
  auto file = std::make_unique<DcmFileFormat>();
  OFCondition read;
  {
    DcmInputFileStream stream(OFFilename(copy->path().c_str()));
    if (stream.status().bad()) return internal_error("cannot read back a temporary copy of " + what);
    file->transferInit();
    read = file->read(stream, EXS_Unknown, EGL_noChange, kMaxEagerValue);
    file->transferEnd();
  }
  if (read.good()) read = file->loadAllDataIntoMemory();
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
