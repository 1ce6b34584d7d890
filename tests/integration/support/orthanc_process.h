// A real Orthanc for tests and benchmarks: its own storage in a temporary directory, HTTP on a free loopback port,
// authentication on (user posewarp, password s3cret), the DICOMweb plugin under /dicom-web/; stopped with the object.
#pragma once

#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <string>
#include <thread>
#include <vector>

#include "free_port.h"
#include "posewarp/pacs/dicomweb.h"

namespace posewarp::testing_support {

namespace fs = std::filesystem;

constexpr const char* kOrthancDicomWebPlugin = "/usr/share/orthanc/plugins/libOrthancDicomWeb.so";

// Orthanc with its own storage, HTTP on a free loopback port, user posewarp / s3cret, DICOMweb under /dicom-web/.
class OrthancProcess {
 public:
  // `extra_json`: more members of the configuration object (e.g. "\"StableAge\": 1"); `plugins`: more plugins.
  explicit OrthancProcess(const fs::path& dir, const std::string& extra_json = "",
                          const std::vector<std::string>& plugins = {})
      : dir_(dir), port_(free_port()) {
    std::string plugin_list = std::string("\"") + kOrthancDicomWebPlugin + "\"";
    for (const std::string& p : plugins) plugin_list += ", \"" + p + "\"";
    fs::create_directories(dir / "storage");
    std::ofstream(dir / "orthanc.json") << R"({
      "Name": "posewarp-test", "StorageDirectory": ")"
                                        << (dir / "storage").string() << R"(",
      "IndexDirectory": ")" << (dir / "storage").string()
                                        << R"(",
      "HttpPort": )" << port_ << R"(, "DicomServerEnabled": false, "RemoteAccessAllowed": false,
      "AuthenticationEnabled": true, "RegisteredUsers": {"posewarp": "s3cret"},
      "Plugins": [)" << plugin_list << R"(], "DicomWeb": {"Enable": true, "Root": "/dicom-web/"})"
                                        << (extra_json.empty() ? "" : ", " + extra_json) << "}";
    pid_ = ::fork();
    if (pid_ == 0) {
      const std::string log = (dir / "orthanc.log").string();
      FILE* out = std::freopen(log.c_str(), "w", stdout);
      FILE* err = std::freopen(log.c_str(), "a", stderr);
      (void)out, (void)err;
      ::execlp("Orthanc", "Orthanc", (dir / "orthanc.json").c_str(), static_cast<char*>(nullptr));
      ::_exit(127);
    }
    // Ready when DICOMweb answers a search.
    pacs::DicomWebClient client(options());
    for (int i = 0; i < 150 && !ready_; ++i) {
      std::this_thread::sleep_for(std::chrono::milliseconds(200));
      ready_ = client.search_studies("").ok();
    }
  }
  ~OrthancProcess() {
    if (pid_ > 0) {
      ::kill(pid_, SIGTERM);
      int status = 0;
      for (int i = 0; i < 100 && ::waitpid(pid_, &status, WNOHANG) == 0; ++i)
        std::this_thread::sleep_for(std::chrono::milliseconds(100));
      if (::waitpid(pid_, &status, WNOHANG) == 0) {
        ::kill(pid_, SIGKILL);
        ::waitpid(pid_, &status, 0);
      }
    }
  }
  pacs::DicomWebOptions options(const std::string& password = "s3cret") const {
    pacs::DicomWebOptions o;
    o.base_url = "http://127.0.0.1:" + std::to_string(port_) + "/dicom-web";
    o.username = "posewarp";
    o.password = password;
    o.retries = 1;
    return o;
  }
  bool ready() const { return ready_; }
  int port() const { return port_; }
  const fs::path& directory() const { return dir_; }
  std::string log() const {
    std::ifstream in(dir_ / "orthanc.log");
    return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  }

 private:
  fs::path dir_;
  int port_ = 0;
  pid_t pid_ = -1;
  bool ready_ = false;
};

}  // namespace posewarp::testing_support
