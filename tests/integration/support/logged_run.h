// The DICOM integration tests' way of running the posewarp command: its output kept in a log file.
#pragma once

#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

namespace posewarp::testing_support {

// Runs `args` (each quoted), stdout and stderr into `log`; the shell's status.
inline int run(const std::vector<std::string>& args, const std::filesystem::path& log) {
  std::string command;
  for (const std::string& a : args) command += "'" + a + "' ";
  return std::system((command + "> '" + log.string() + "' 2>&1").c_str());
}

inline std::string text(const std::filesystem::path& path) {
  std::ifstream in(path);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// Non-empty lines of a file.
inline size_t lines_of(const std::filesystem::path& path) {
  std::ifstream in(path);
  size_t n = 0;
  for (std::string line; std::getline(in, line);) n += !line.empty();
  return n;
}

}  // namespace posewarp::testing_support
