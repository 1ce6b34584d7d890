// DICOM objects as a PACS sends them, through posewarp's readers: any bytes give a CT, a segmentation or an error,
// never a crash, a hang or an allocation beyond what the bytes hold. The first byte picks the reader: a CT (one
// instance: a single-frame slice or an Enhanced CT), or a SEG (binary, fractional or label map) read onto the grid of
// the seeds' CT (8 x 6 x 4 voxels of 1 mm at the origin, axes along LPS). Seeds: tests/fuzz/corpus/dicom
// (tests/fuzz/make_dicom_seeds.sh), each a reader byte followed by a small Part 10 file.
#include <cstddef>
#include <cstdint>
#include <string>

#include "posewarp/dicom/ct_series.h"
#include "posewarp/dicom/segmentation.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  if (size < 1) return 0;
  const std::string bytes(reinterpret_cast<const char*>(data) + 1, size - 1);
  if (data[0] % 2 == 0) {
    (void)posewarp::dicom::read_ct_series({bytes});
  } else {
    posewarp::ImageGeometry grid;
    grid.size = {8, 6, 4};
    (void)posewarp::dicom::read_segmentation(bytes, grid);
  }
  return 0;
}
