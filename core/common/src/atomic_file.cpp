// AtomicFile: partial file, fsync, rename, fsync of the directory.
#include "posewarp/common/atomic_file.h"

#include <fcntl.h>
#include <sys/stat.h>
#include <unistd.h>

#include <atomic>
#include <cerrno>
#include <cstdio>  // renameat2
#include <cstring>
#include <filesystem>
#include <utility>

#include "posewarp/common/input_file.h"

namespace posewarp {
namespace {

namespace fs = std::filesystem;

std::string directory_of(const std::string& path) {
  const fs::path parent = fs::path(path).parent_path();
  return parent.empty() ? "." : parent.string();
}

std::string in_quotes(const std::string& text) { return "'" + text + "'"; }

// INVALID_ARGUMENT when `path` is a directory: the rename would fail with EISDIR after all the work.
Status refuse_directory(const std::string& path, std::string_view kind) {
  std::error_code ec;
  if (!fs::is_directory(path, ec)) return ok_status();
  return invalid_argument_error("cannot write " + std::string(kind) + " " + in_quotes(path) +
                                ": it is a directory; name a file to write (e.g. " +
                                in_quotes((fs::path(path) / "<name>").string()) + ")");
}

// The error of a partial file or directory that could not be made in `directory`: NOT_FOUND for a missing
// directory, PERMISSION_DENIED for one that cannot be written, INVALID_ARGUMENT otherwise.
Status creation_error(int error, const std::string& path, std::string_view kind, const std::string& directory) {
  const std::string message = "cannot write " + std::string(kind) + " " + in_quotes(path) + " in " +
                              in_quotes(directory) + ": " + std::strerror(error);
  if (error == ENOENT || error == ENOTDIR) return not_found_error(message + " (create the directory first)");
  if (error == EACCES || error == EPERM || error == EROFS) {
    return permission_denied_error(message + " (choose a directory you can write to)");
  }
  return invalid_argument_error(message);
}

// A file's or directory's contents (and, for a directory, its entries) on the disk.
void sync_to_disk(const std::string& path) {
  const int fd = ::open(path.c_str(), O_RDONLY | O_CLOEXEC);
  if (fd >= 0) {
    ::fsync(fd);
    ::close(fd);
  }
}

}  // namespace

AtomicFile::AtomicFile(std::string path, std::string partial, std::string kind, int fd)
    : path_(std::move(path)), partial_(std::move(partial)), kind_(std::move(kind)), fd_(fd) {}

AtomicFile::AtomicFile(AtomicFile&& other) noexcept
    : path_(std::move(other.path_)),
      partial_(std::move(other.partial_)),
      kind_(std::move(other.kind_)),
      fd_(std::exchange(other.fd_, -1)),
      committed_(std::exchange(other.committed_, true)) {}

AtomicFile::~AtomicFile() {
  if (fd_ >= 0) ::close(fd_);
  if (!committed_) ::unlink(partial_.c_str());
}

Result<AtomicFile> AtomicFile::create(const std::string& path, std::string_view kind) {
  static std::atomic<unsigned> counter{0};
  POSEWARP_RETURN_IF_ERROR(refuse_directory(path, kind));
  const std::string directory = directory_of(path);
  remove_stale_partial_files(directory);
  // The counter keeps two threads of one process (a server writing the same target twice) apart.
  const std::string partial =
      (fs::path(directory) / partial_file_name(std::to_string(counter.fetch_add(1)) + "-" +
                                               fs::path(path).filename().string()))
          .string();
  const int fd = ::open(partial.c_str(), O_WRONLY | O_CREAT | O_TRUNC | O_CLOEXEC, 0644);
  if (fd < 0) return creation_error(errno, path, kind, directory);
  return AtomicFile(path, partial, std::string(kind), fd);
}

AtomicFile AtomicFile::adopt(const std::string& written, const std::string& path, std::string_view kind) {
  return AtomicFile(path, written, std::string(kind), -1);
}

Status AtomicFile::write(std::string_view bytes) {
  size_t written = 0;
  while (written < bytes.size()) {
    const ssize_t n = ::write(fd_, bytes.data() + written, bytes.size() - written);
    if (n < 0 && errno == EINTR) continue;
    if (n <= 0) {
      const int error = errno;
      return resource_exhausted_error("writing " + kind_ + " " + in_quotes(path_) + " failed: " + std::strerror(error) +
                                      " (is the disk full?)");
    }
    written += static_cast<size_t>(n);
  }
  return ok_status();
}

Status AtomicFile::commit() {
  if (fd_ >= 0) {
    ::close(fd_);
    fd_ = -1;
  }
  // Reopened: a library may have replaced the partial file by name.
  const int fd = ::open(partial_.c_str(), O_RDONLY | O_CLOEXEC);
  struct stat st {};
  const bool flushed = fd >= 0 && ::fstat(fd, &st) == 0 && st.st_size > 0 && ::fsync(fd) == 0;
  const int error = errno;
  if (fd >= 0) ::close(fd);
  if (!flushed) {
    return internal_error("writing " + kind_ + " " + in_quotes(path_) + " failed: " +
                          (st.st_size == 0 && fd >= 0 ? std::string("nothing was written")
                                                      : std::string(std::strerror(error))) +
                          " (is the disk full?)");
  }
  if (::rename(partial_.c_str(), path_.c_str()) != 0) {
    const int rename_error = errno;
    if (rename_error == EISDIR || rename_error == ENOTEMPTY || rename_error == EEXIST) {
      POSEWARP_RETURN_IF_ERROR(refuse_directory(path_, kind_));  // made a directory since create()
    }
    return internal_error("could not move " + kind_ + " " + in_quotes(path_) + " into place: " +
                          std::strerror(rename_error));
  }
  committed_ = true;
  // The rename itself reaches the disk with the directory.
  sync_to_disk(directory_of(path_));
  return ok_status();
}

AtomicDirectory::AtomicDirectory(std::string path, std::string partial, std::string kind, Existing existing)
    : path_(std::move(path)), partial_(std::move(partial)), kind_(std::move(kind)), existing_(existing) {}

AtomicDirectory::AtomicDirectory(AtomicDirectory&& other) noexcept
    : path_(std::move(other.path_)),
      partial_(std::move(other.partial_)),
      kind_(std::move(other.kind_)),
      existing_(other.existing_),
      committed_(std::exchange(other.committed_, true)) {}

AtomicDirectory::~AtomicDirectory() {
  std::error_code ignored;
  if (!committed_) fs::remove_all(partial_, ignored);
}

Result<AtomicDirectory> AtomicDirectory::create(const std::string& path, std::string_view kind, Existing existing) {
  static std::atomic<unsigned> counter{0};
  const std::string target = fs::path(path).lexically_normal().string();
  const std::string name = fs::path(target).filename().string();
  if (name.empty() || name == "." || name == "..") {
    return invalid_argument_error("cannot write " + std::string(kind) + " " + in_quotes(path) +
                                  ": name a new directory (e.g. 'posed')");
  }
  std::error_code ec;
  if (existing == Existing::kRefuse && fs::exists(target, ec)) {
    return already_exists_error(in_quotes(path) + " exists already; choose a new directory for the " +
                                std::string(kind));
  }
  if (fs::exists(target, ec) && !fs::is_directory(target, ec)) {
    return invalid_argument_error("cannot write " + std::string(kind) + " " + in_quotes(path) +
                                  ": it is a file; name a directory");
  }
  const std::string parent = directory_of(target);
  remove_stale_partial_files(parent);
  const std::string partial =
      (fs::path(parent) / partial_file_name(std::to_string(counter.fetch_add(1)) + "-" + name)).string();
  if (::mkdir(partial.c_str(), 0755) != 0) return creation_error(errno, path, kind, parent);
  return AtomicDirectory(target, partial, std::string(kind), existing);
}

Status AtomicDirectory::commit() {
  // Every file and folder in it reaches the disk before the directory takes its name.
  std::error_code ec;
  for (fs::recursive_directory_iterator it(partial_, ec), end; !ec && it != end; it.increment(ec)) {
    sync_to_disk(it->path().string());
  }
  sync_to_disk(partial_);
  const bool there = fs::exists(path_, ec);
  if (there && existing_ == Existing::kRefuse) {
    return already_exists_error(in_quotes(path_) + " was made while the " + kind_ + " was written; choose a new directory");
  }
  if (there) {
    // One step: the new directory takes the name and the old one takes the partial name, then goes.
    if (::renameat2(AT_FDCWD, partial_.c_str(), AT_FDCWD, path_.c_str(), RENAME_EXCHANGE) != 0) {
      return internal_error("could not put " + kind_ + " " + in_quotes(path_) + " in place: " + std::strerror(errno));
    }
    committed_ = true;
    fs::remove_all(partial_, ec);
  } else {
    if (::rename(partial_.c_str(), path_.c_str()) != 0) {
      return internal_error("could not put " + kind_ + " " + in_quotes(path_) + " in place: " + std::strerror(errno));
    }
    committed_ = true;
  }
  sync_to_disk(directory_of(path_));
  return ok_status();
}

Status write_file_atomically(const std::string& path, std::string_view bytes, std::string_view kind) {
  POSEWARP_ASSIGN_OR_RETURN(AtomicFile file, AtomicFile::create(path, kind));
  POSEWARP_RETURN_IF_ERROR(file.write(bytes));
  return file.commit();
}

}  // namespace posewarp
