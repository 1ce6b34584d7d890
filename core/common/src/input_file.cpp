// Regular-file checks and bounded whole-file reads for the readers.
#include "posewarp/common/input_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <signal.h>

#include <cerrno>
#include <cstring>
#include <filesystem>

namespace posewarp {
namespace {

std::string quoted(const std::string& path) { return "'" + path + "'"; }

}  // namespace

Status check_input_file(const std::string& path, std::string_view kind) {
  struct stat info {};
  if (::stat(path.c_str(), &info) != 0) {
    const int error = errno;
    if (error == ENOENT || error == ENOTDIR) {
      return not_found_error("cannot open " + std::string(kind) + " " + quoted(path) + ": no such file");
    }
    if (error == EACCES) {
      return permission_denied_error("cannot open " + std::string(kind) + " " + quoted(path) +
                                     ": permission denied (check the file's permissions)");
    }
    return invalid_argument_error("cannot open " + std::string(kind) + " " + quoted(path) + ": " + std::strerror(error));
  }
  const char* what = S_ISDIR(info.st_mode)    ? "a directory"
                     : S_ISFIFO(info.st_mode) ? "a FIFO (named pipe)"
                     : S_ISSOCK(info.st_mode) ? "a socket"
                     : S_ISCHR(info.st_mode)  ? "a character device"
                     : S_ISBLK(info.st_mode)  ? "a block device"
                     : S_ISREG(info.st_mode)  ? nullptr
                                              : "not a regular file";
  if (what) {
    return invalid_argument_error(quoted(path) + " is " + what + "; a " + std::string(kind) +
                                  " must be a regular file (check the path)");
  }
  if (::access(path.c_str(), R_OK) != 0) {
    return permission_denied_error("cannot read " + std::string(kind) + " " + quoted(path) +
                                   ": permission denied (check the file's permissions)");
  }
  return ok_status();
}

Result<std::string> read_text_input(const std::string& path, std::string_view kind, int64_t max_bytes) {
  POSEWARP_RETURN_IF_ERROR(check_input_file(path, kind));
  const int fd = ::open(path.c_str(), O_RDONLY | O_NONBLOCK | O_CLOEXEC);
  if (fd < 0) {
    return not_found_error("cannot open " + std::string(kind) + " " + quoted(path) + ": " + std::strerror(errno));
  }
  struct stat info {};
  if (::fstat(fd, &info) != 0 || !S_ISREG(info.st_mode)) {
    ::close(fd);
    return invalid_argument_error(quoted(path) + " is not a regular file; a " + std::string(kind) +
                                  " must be a regular file (check the path)");
  }
  if (info.st_size > max_bytes) {
    ::close(fd);
    return invalid_argument_error(std::string(kind) + " " + quoted(path) + " is " + std::to_string(info.st_size) +
                                  " bytes, over the limit of " + std::to_string(max_bytes) + " for a " +
                                  std::string(kind) + "; is it the right file?");
  }
  std::string text;
  text.resize(static_cast<size_t>(info.st_size));
  size_t done = 0;
  while (done < text.size()) {
    const ssize_t n = ::read(fd, text.data() + done, text.size() - done);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) break;
    done += static_cast<size_t>(n);
  }
  // A file that grew while being read is cut at the size fstat saw; one that shrank is an error.
  ::close(fd);
  if (done != text.size()) {
    return data_loss_error("could not read all of " + std::string(kind) + " " + quoted(path) + " (" +
                           std::to_string(done) + " of " + std::to_string(text.size()) + " bytes)");
  }
  return text;
}

Status check_json_depth(std::string_view json_text, const std::string& what, int max_depth) {
  int depth = 0;
  bool in_string = false, escaped = false;
  for (const char c : json_text) {
    if (in_string) {
      if (escaped) {
        escaped = false;
      } else if (c == '\\') {
        escaped = true;
      } else if (c == '"') {
        in_string = false;
      }
      continue;
    }
    if (c == '"') {
      in_string = true;
    } else if (c == '[' || c == '{') {
      if (++depth > max_depth) {
        return invalid_argument_error(what + " nests arrays or objects more than " + std::to_string(max_depth) +
                                      " levels deep; it is not a posewarp file (or is damaged)");
      }
    } else if (c == ']' || c == '}') {
      --depth;
    }
  }
  return ok_status();
}

}  // namespace posewarp

namespace posewarp {
namespace {

constexpr std::string_view kPartialPrefix = ".posewarp-partial-";

}  // namespace

std::string partial_file_name(const std::string& target_name) {
  return std::string(kPartialPrefix) + std::to_string(::getpid()) + "-" + target_name;
}

int remove_stale_partial_files(const std::string& directory) {
  namespace fs = std::filesystem;
  std::error_code ec;
  int removed = 0;
  for (fs::directory_iterator it(directory.empty() ? "." : directory, ec), end; !ec && it != end; it.increment(ec)) {
    const std::string name = it->path().filename().string();
    if (name.compare(0, kPartialPrefix.size(), kPartialPrefix) != 0) continue;
    const size_t dash = name.find('-', kPartialPrefix.size());
    if (dash == std::string::npos || dash == kPartialPrefix.size()) continue;
    long pid = 0;
    try {
      pid = std::stol(name.substr(kPartialPrefix.size(), dash - kPartialPrefix.size()));
    } catch (const std::exception&) {
      continue;
    }
    if (pid <= 0 || (::kill(static_cast<pid_t>(pid), 0) == 0 || errno != ESRCH)) continue;  // alive, or not ours to judge
    std::error_code removing;
    if (fs::remove_all(it->path(), removing) > 0) ++removed;  // a file, or an AtomicDirectory's partial directory
  }
  return removed;
}

}  // namespace posewarp
