// Real processes for scale-out tests and benchmarks: a PostgreSQL cluster of its own (initdb + pg_ctl from Debian's
// postgresql-15, in a temporary directory, on a free loopback port) and nginx with the repository's
// docker/nginx/posewarp.conf.template, its variables substituted as the nginx image's entrypoint does.
#pragma once

#include <pwd.h>
#include <signal.h>
#include <sys/stat.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "free_port.h"

namespace posewarp::testing_support {

namespace fs = std::filesystem;

inline std::string postgres_bin_dir() {
  for (const char* dir : {"/usr/lib/postgresql/15/bin", "/usr/lib/postgresql/16/bin", "/usr/lib/postgresql/14/bin"}) {
    if (fs::exists(fs::path(dir) / "initdb")) return dir;
  }
  return "";
}

inline std::string nginx_binary() {
  for (const char* path : {"/usr/sbin/nginx", "/usr/local/sbin/nginx"}) {
    if (fs::exists(path)) return path;
  }
  return "";
}

// A shell command's exit code (its output into `log`, appended).
inline int run_logged(const std::string& command, const fs::path& log) {
  const int status = std::system((command + " >>'" + log.string() + "' 2>&1").c_str());
  return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
}

// PostgreSQL's server refuses to run as root: a root test runs it as the postgres system user (Debian's package
// creates it), in a directory that user owns.
class PostgresCluster {
 public:
  explicit PostgresCluster(const fs::path& dir) : dir_(dir), data_(dir / "data"), port_(free_port()) {
    bin_ = postgres_bin_dir();
    if (bin_.empty()) {
      error_ = "PostgreSQL's initdb is not installed (Debian package postgresql-15; scripts/setup installs it)";
      return;
    }
    fs::create_directories(dir_);
    if (::geteuid() == 0) {
      const passwd* user = ::getpwnam("postgres");
      if (user == nullptr) {
        error_ = "running as root and there is no postgres user to run PostgreSQL as";
        return;
      }
      as_user_ = "runuser -u postgres -- ";
      if (::chown(dir_.c_str(), user->pw_uid, user->pw_gid) != 0) {
        error_ = "cannot hand " + dir_.string() + " to the postgres user";
        return;
      }
      // The temporary directory's parents must let that user through.
      for (fs::path p = dir_.parent_path(); !p.empty() && p != p.root_path(); p = p.parent_path()) {
        struct stat st {};
        if (::stat(p.c_str(), &st) == 0 && (st.st_mode & S_IXOTH) == 0) ::chmod(p.c_str(), st.st_mode | S_IXOTH);
      }
    }
    // Trust on loopback only (a throw-away cluster); the index's user is posewarp, its database posewarp.
    if (run_logged(
            as_user_ + bin_ + "/initdb -D '" + data_.string() + "' -U posewarp -A trust -E UTF8 --no-locale --no-sync",
            log()) != 0) {
      error_ = "initdb failed (see " + log().string() + ")";
      return;
    }
    std::ofstream(data_ / "postgresql.conf", std::ios::app)
        << "listen_addresses = '127.0.0.1'\nport = " << port_
        << "\nunix_socket_directories = ''\nfsync = off\nmax_connections = 60\n";  // TCP only
    if (!start()) return;
    if (run_logged(as_user_ + bin_ + "/createdb -h 127.0.0.1 -p " + std::to_string(port_) + " -U posewarp posewarp",
                   log()) != 0) {
      error_ = "createdb failed (see " + log().string() + ")";
    }
  }
  ~PostgresCluster() {
    if (running_) stop();
  }
  PostgresCluster(const PostgresCluster&) = delete;
  PostgresCluster& operator=(const PostgresCluster&) = delete;

  bool ok() const { return error_.empty(); }
  const std::string& error() const { return error_; }
  int port() const { return port_; }
  fs::path log() const { return dir_ / "postgres.log"; }
  std::string conninfo() const {
    return "host=127.0.0.1 port=" + std::to_string(port_) + " user=posewarp dbname=posewarp connect_timeout=3";
  }

  bool start() {
    if (run_logged(as_user_ + bin_ + "/pg_ctl -D '" + data_.string() + "' -l '" + (dir_ / "server.log").string() +
                       "' -w -t 60 start",
                   log()) != 0) {
      error_ = "pg_ctl start failed (see " + log().string() + " and " + (dir_ / "server.log").string() + ")";
      return false;
    }
    running_ = true;
    return true;
  }
  // Fast shutdown: open connections are cut, as when the database host restarts.
  bool stop() {
    running_ = false;
    return run_logged(as_user_ + bin_ + "/pg_ctl -D '" + data_.string() + "' -m fast -w -t 60 stop", log()) == 0;
  }
  // One SQL statement through psql; its output (tuples only, unaligned).
  std::string query(const std::string& sql) const {
    const std::string command = "psql -X -q -t -A -h 127.0.0.1 -p " + std::to_string(port_) +
                                " -U posewarp posewarp -c \"" + sql + "\" 2>/dev/null";
    std::string out;
    if (FILE* pipe = ::popen(command.c_str(), "r")) {
      char buffer[4096];
      for (size_t n; (n = std::fread(buffer, 1, sizeof buffer, pipe)) > 0;) out.append(buffer, n);
      ::pclose(pipe);
    }
    while (!out.empty() && (out.back() == '\n' || out.back() == ' ')) out.pop_back();
    return out;
  }

 private:
  fs::path dir_, data_;
  int port_;
  std::string bin_, as_user_, error_;
  bool running_ = false;
};

// nginx in front of replicas with the repository's config template. Replicas past the template's own count are not
// supported; fewer drop the template's other server lines.
class NginxProxy {
 public:
  NginxProxy(const fs::path& dir, const fs::path& source_dir, const std::vector<std::string>& replicas)
      : dir_(dir), port_(free_port()) {
    const std::string binary = nginx_binary();
    if (binary.empty()) {
      error_ = "nginx is not installed (Debian package nginx-core; scripts/setup installs it)";
      return;
    }
    std::ifstream in(source_dir / "docker/nginx/posewarp.conf.template");
    std::string text{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
    if (text.empty()) {
      error_ = "docker/nginx/posewarp.conf.template is missing";
      return;
    }
    substitute(text, "${POSEWARP_LISTEN}", "127.0.0.1:" + std::to_string(port_));
    std::istringstream lines(text);
    std::string conf, line;
    while (std::getline(lines, line)) {
      const size_t at = line.find("${POSEWARP_REPLICA_");
      if (at != std::string::npos) {
        const size_t n = static_cast<size_t>(std::atoi(line.c_str() + at + 19));
        if (n < 1 || n > replicas.size()) continue;
        substitute(line, "${POSEWARP_REPLICA_" + std::to_string(n) + "}", replicas[n - 1]);
      }
      conf += line + "\n";
    }
    fs::create_directories(dir_ / "temp");
    fs::permissions(dir_ / "temp", fs::perms::all);  // workers run as nobody when the test is root
    std::ofstream(dir_ / "posewarp.conf") << conf;
    const std::string temp = (dir_ / "temp").string();
    std::ofstream(dir_ / "nginx.conf") << "daemon off;\nworker_processes 2;\npid " << (dir_ / "nginx.pid").string()
                                       << ";\nerror_log " << (dir_ / "error.log").string()
                                       << " warn;\nevents { worker_connections 1024; }\nhttp {\n  access_log off;\n"
                                       << "  client_body_temp_path " << temp << "/body;\n  proxy_temp_path " << temp
                                       << "/proxy;\n  fastcgi_temp_path " << temp << "/fastcgi;\n  uwsgi_temp_path "
                                       << temp << "/uwsgi;\n  scgi_temp_path " << temp << "/scgi;\n  include "
                                       << (dir_ / "posewarp.conf").string() << ";\n}\n";
    if (run_logged(binary + " -t -p '" + dir_.string() + "' -c '" + (dir_ / "nginx.conf").string() + "'",
                   dir_ / "check.log") != 0) {
      error_ = "nginx refused the configuration (see " + (dir_ / "check.log").string() + ")";
      return;
    }
    pid_ = ::fork();
    if (pid_ == 0) {
      ::execl(binary.c_str(), "nginx", "-p", dir_.c_str(), "-c", (dir_ / "nginx.conf").c_str(),
              static_cast<char*>(nullptr));
      ::_exit(127);
    }
  }
  ~NginxProxy() {
    if (pid_ > 0) {
      ::kill(pid_, SIGTERM);
      ::waitpid(pid_, nullptr, 0);
    }
  }
  NginxProxy(const NginxProxy&) = delete;
  NginxProxy& operator=(const NginxProxy&) = delete;

  bool ok() const { return error_.empty() && pid_ > 0; }
  const std::string& error() const { return error_; }
  std::string address() const { return "127.0.0.1:" + std::to_string(port_); }
  std::string error_log() const {
    std::ifstream in(dir_ / "error.log");
    return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
  }

 private:
  static void substitute(std::string& text, const std::string& from, const std::string& to) {
    for (size_t at; (at = text.find(from)) != std::string::npos;) text.replace(at, from.size(), to);
  }

  fs::path dir_;
  int port_;
  pid_t pid_ = -1;
  std::string error_;
};

}  // namespace posewarp::testing_support
