// Helpers shared by the unit tests: scratch directories and small volumes with known content.
#pragma once

#include <gtest/gtest.h>
#include <unistd.h>

#include <array>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <string>

#include "posewarp/common/volume.h"

namespace posewarp::testing {

// A fresh directory under the system temp dir, removed at the end of the test.
class ScratchDir {
 public:
  ScratchDir() {
    const auto* info = ::testing::UnitTest::GetInstance()->current_test_info();
    std::string name = std::string("posewarp-") + (info ? info->test_suite_name() : "t") + "-" +
                       (info ? info->name() : "x") + "-" + std::to_string(::getpid());
    for (char& c : name) {
      if (c == '/') c = '_';
    }
    path_ = std::filesystem::temp_directory_path() / name;
    std::filesystem::remove_all(path_);
    std::filesystem::create_directories(path_);
  }
  ~ScratchDir() {
    std::error_code ec;
    std::filesystem::remove_all(path_, ec);
  }
  std::string file(const std::string& name) const { return (path_ / name).string(); }
  const std::filesystem::path& path() const { return path_; }

 private:
  std::filesystem::path path_;
};

// A rotation (about z by 30 degrees, then x by 20): no grid axis aligned with LPS, right-handed.
inline std::array<double, 9> oblique_direction() {
  const double a = 30.0 * M_PI / 180.0, b = 20.0 * M_PI / 180.0;
  const double rz[9] = {std::cos(a), -std::sin(a), 0, std::sin(a), std::cos(a), 0, 0, 0, 1};
  const double rx[9] = {1, 0, 0, 0, std::cos(b), -std::sin(b), 0, std::sin(b), std::cos(b)};
  std::array<double, 9> d{};
  for (int r = 0; r < 3; ++r)
    for (int c = 0; c < 3; ++c)
      for (int k = 0; k < 3; ++k) d[3 * r + c] += rx[3 * r + k] * rz[3 * k + c];
  return d;
}

inline ImageGeometry small_oblique_grid() {
  ImageGeometry g;
  g.size = {7, 6, 5};
  g.spacing = {0.75, 1.25, 2.5};
  g.origin = {-31.5, 12.25, 101.0};
  g.direction = oblique_direction();
  return g;
}

// Labels cycling through `values`, so every value appears and the pattern shows any axis swap.
inline LabelVolume patterned_labels(const ImageGeometry& g, const std::vector<Label>& values) {
  LabelVolume v(g, 0);
  for (int64_t n = 0; n < v.voxel_count(); ++n) v.data()[n] = values[static_cast<size_t>((n * 7 + n / 11) % values.size())];
  return v;
}

inline IntensityVolume patterned_intensities(const ImageGeometry& g, float lo, float hi, bool integral) {
  IntensityVolume v(g, 0.0f);
  for (int64_t n = 0; n < v.voxel_count(); ++n) {
    const double t = std::fmod(static_cast<double>(n) * 0.618034, 1.0);
    double value = lo + (hi - lo) * t;
    if (integral) value = std::round(value);
    v.data()[n] = static_cast<float>(value);
  }
  return v;
}

inline void expect_same_geometry(const ImageGeometry& a, const ImageGeometry& b, double tolerance = 1e-4) {
  for (int i = 0; i < 3; ++i) {
    EXPECT_EQ(a.size[i], b.size[i]) << "size axis " << i;
    EXPECT_NEAR(a.spacing[i], b.spacing[i], tolerance) << "spacing axis " << i;
    EXPECT_NEAR(a.origin[i], b.origin[i], tolerance) << "origin axis " << i;
  }
  for (int e = 0; e < 9; ++e) EXPECT_NEAR(a.direction[e], b.direction[e], tolerance) << "direction element " << e;
}

inline void write_bytes(const std::string& path, const std::string& bytes) {
  std::ofstream out(path, std::ios::binary | std::ios::trunc);
  out << bytes;
}

inline std::string read_bytes(const std::string& path) {
  std::ifstream in(path, std::ios::binary);
  return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
}

}  // namespace posewarp::testing
