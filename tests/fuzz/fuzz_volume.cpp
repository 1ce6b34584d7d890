// Volume files through the same path the CLI takes (header checks, then ITK): any bytes give a volume or an error,
// never a crash, a hang or an allocation beyond the header's checked size. The first byte picks the format (the
// extension ITK dispatches on); the rest is the file. Seeds: tests/fuzz/corpus/volume, each a format byte followed
// by a small NIfTI, NRRD or MetaImage file.
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <string>

#include "posewarp/io/volume_io.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const char* const kExtensions[] = {".nii", ".nii.gz", ".nrrd", ".mha"};
  if (size < 1) return 0;
  const std::string extension = kExtensions[data[0] % 4];
  const std::string path = "/tmp/posewarp-fuzz-volume-" + std::to_string(::getpid()) + extension;
  std::FILE* file = std::fopen(path.c_str(), "wb");
  if (file == nullptr) return 0;
  std::fwrite(data + 1, 1, size - 1, file);
  std::fclose(file);
  posewarp::io::ReadOptions options;
  options.max_voxels = int64_t{1} << 22;  // 16 MB of labels: large enough for every seed, small for the fuzzer
  (void)posewarp::io::read_label_volume(path, options);
  (void)posewarp::io::read_intensity_volume(path, options);
  std::remove(path.c_str());
  return 0;
}
