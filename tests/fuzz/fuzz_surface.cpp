// Surface mesh files (posewarp's own OBJ and PLY readers, VTK's STL and VTP readers): any bytes give a mesh or an
// error, never a crash. The first byte picks the format; the rest is the file. Seeds: tests/fuzz/corpus/surface,
// each a format byte followed by a small mesh in ASCII or binary form.
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <cstdio>
#include <string>

#include "posewarp/surface/surface_mesh.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  static const char* const kExtensions[] = {".obj", ".ply", ".stl", ".vtp"};
  if (size < 1) return 0;
  const std::string path = "/tmp/posewarp-fuzz-surface-" + std::to_string(::getpid()) + kExtensions[data[0] % 4];
  std::FILE* file = std::fopen(path.c_str(), "wb");
  if (file == nullptr) return 0;
  std::fwrite(data + 1, 1, size - 1, file);
  std::fclose(file);
  (void)posewarp::surface::read_surface(path);
  std::remove(path.c_str());
  return 0;
}
