// The harness of the bad-input tests: the real `posewarp` process run on a bar phantom's files, with its exit code,
// stderr, wall time and peak memory (getrusage of the child).
#pragma once

#include <gtest/gtest.h>
#include <sys/resource.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <vector>

namespace posewarp::bad_input {

namespace fs = std::filesystem;

struct CliRun {
  int exit_code = -1;
  std::string err;
  double seconds = 0.0;
  long max_rss_kb = 0;
};

// Runs posewarp with `args` (stdout to /dev/null, stderr captured), killed after 60 s.
inline CliRun posewarp(const std::vector<std::string>& args) {
  const fs::path err_file = fs::temp_directory_path() / ("posewarp-it-err-" + std::to_string(::getpid()));
  const auto start = std::chrono::steady_clock::now();
  const pid_t child = ::fork();
  if (child == 0) {
    std::vector<char*> argv{const_cast<char*>(POSEWARP_CLI)};
    for (const std::string& a : args) argv.push_back(const_cast<char*>(a.c_str()));
    argv.push_back(nullptr);
    if (!std::freopen("/dev/null", "w", stdout) || !std::freopen(err_file.c_str(), "w", stderr)) ::_exit(127);
    ::alarm(60);
    ::execv(POSEWARP_CLI, argv.data());
    ::_exit(127);
  }
  CliRun run;
  int status = 0;
  struct rusage usage {};
  ::wait4(child, &status, 0, &usage);
  run.seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  run.exit_code = WIFEXITED(status) ? WEXITSTATUS(status) : 128 + WTERMSIG(status);
  run.max_rss_kb = usage.ru_maxrss;
  std::ifstream in(err_file);
  run.err.assign(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  fs::remove(err_file);
  return run;
}

inline std::string file_text(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

// A bar phantom, its rig and a pose, once for every test.
class BadInput : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = fs::temp_directory_path() / ("posewarp-it-" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    ASSERT_EQ(posewarp({"--quiet", "phantom", "bar", "-o", dir_.string()}).exit_code, 0);
    const CliRun built = posewarp({"--quiet", "rig", "build", "--labels", (dir_ / "labels.nii.gz").string(), "--label-map",
                                (dir_ / "label_map.json").string(), "-o", (dir_ / "bar.rig").string()});
    ASSERT_EQ(built.exit_code, 0) << built.err;
    fs::copy_file(fs::path(POSEWARP_SOURCE_DIR) / "data/poses/bar_bend_90.json", dir_ / "pose.json");
  }
  static void TearDownTestSuite() { fs::remove_all(dir_); }

  static std::string at(const std::string& name) { return (dir_ / name).string(); }

  // The failure every bad input must give: `code`, a message naming `names` and saying `says`, quickly and small.
  static void expect_refused(const CliRun& run, int code, const std::string& names, const std::string& says) {
    EXPECT_EQ(run.exit_code, code) << run.err;
    EXPECT_NE(run.err.find(names), std::string::npos) << run.err;
    EXPECT_NE(run.err.find(says), std::string::npos) << run.err;
    EXPECT_LT(run.seconds, 30.0);            // generous: a refusal is milliseconds, a hang is forever
    EXPECT_LT(run.max_rss_kb, 1024 * 1024);  // under 1 GB
  }

  static inline fs::path dir_;
};

}  // namespace posewarp::bad_input
