// Files appear whole or not at all. Every writer in posewarp goes through AtomicFile: it writes a partial file beside
// the target (".posewarp-partial-<pid>-<n>-<name>", unique per process and call), flushes it to disk, renames it
// over the target and flushes the directory, so a crash, a kill -9 or a full disk never leaves a truncated file
// under the requested name. Partial files of dead writers are removed by the next write into the same directory.
#pragma once

#include <string>
#include <string_view>

#include "posewarp/common/result.h"

namespace posewarp {

class AtomicFile {
 public:
  // Creates the partial file. Errors name the file, its directory and the system's reason: NOT_FOUND for a missing
  // directory, PERMISSION_DENIED for one that cannot be written, INVALID_ARGUMENT otherwise (a path that is a
  // directory among them, named as such). `kind` names what is written in messages ("rig file", "report").
  static Result<AtomicFile> create(const std::string& path, std::string_view kind);
  // A file already written in full elsewhere on the target's file system (an upload staged before its name, the hash
  // of its content, was known), committed under `path` as if written through an AtomicFile: flushed, renamed, its
  // directory flushed. Removed unless commit() succeeds.
  static AtomicFile adopt(const std::string& written, const std::string& path, std::string_view kind);

  AtomicFile(AtomicFile&& other) noexcept;
  AtomicFile& operator=(AtomicFile&& other) = delete;
  AtomicFile(const AtomicFile&) = delete;
  AtomicFile& operator=(const AtomicFile&) = delete;
  // Removes the partial file unless commit() succeeded.
  ~AtomicFile();

  // Appends bytes.
  Status write(std::string_view bytes);
  // The partial file's path, for a library that writes by name (ITK, VTK); commit() then finds what it wrote.
  const std::string& partial_path() const { return partial_; }
  // Flushes the partial file to disk, renames it over the target and flushes the directory. An empty partial file
  // is an error (a library that failed without saying so).
  Status commit();

 private:
  AtomicFile(std::string path, std::string partial, std::string kind, int fd);

  std::string path_;
  std::string partial_;
  std::string kind_;
  int fd_ = -1;
  bool committed_ = false;
};

// A directory that appears whole or not at all (a batch row's outputs, a viewer's saved pose): its files are written
// into a partial directory beside the target (named as AtomicFile's partial files, so the next write into the same
// parent removes those of dead writers), then commit() flushes it and renames it over the target. Files written
// inside it need not be atomic themselves: nothing is under the target's name until commit().
class AtomicDirectory {
 public:
  enum class Existing { kRefuse, kReplace };
  // Creates the partial directory. The target's parent must exist; with Existing::kRefuse a target that exists is
  // ALREADY_EXISTS before any work.
  static Result<AtomicDirectory> create(const std::string& path, std::string_view kind, Existing existing);

  AtomicDirectory(AtomicDirectory&& other) noexcept;
  AtomicDirectory& operator=(AtomicDirectory&& other) = delete;
  AtomicDirectory(const AtomicDirectory&) = delete;
  AtomicDirectory& operator=(const AtomicDirectory&) = delete;
  // Removes the partial directory unless commit() succeeded.
  ~AtomicDirectory();

  // Where to write the directory's files.
  const std::string& partial_path() const { return partial_; }
  // Flushes the partial directory's files and itself, then puts it in place: renamed to the target, or, with
  // Existing::kReplace and a target there, exchanged with it in one step (the old one is then removed).
  Status commit();

 private:
  AtomicDirectory(std::string path, std::string partial, std::string kind, Existing existing);

  std::string path_;
  std::string partial_;
  std::string kind_;
  Existing existing_ = Existing::kRefuse;
  bool committed_ = false;
};

// The whole of `bytes` into `path`, atomically.
Status write_file_atomically(const std::string& path, std::string_view bytes, std::string_view kind);

}  // namespace posewarp
