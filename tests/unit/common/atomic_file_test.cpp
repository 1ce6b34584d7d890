#include "posewarp/common/atomic_file.h"

#include <gtest/gtest.h>

#include <filesystem>
#include <thread>
#include <vector>

#include "test_support.h"

namespace posewarp {
namespace {

using posewarp::testing::read_bytes;
using posewarp::testing::ScratchDir;
using posewarp::testing::write_bytes;

// Nothing but the targets in the directory: no partial file left behind.
std::vector<std::string> names_in(const std::filesystem::path& dir) {
  std::vector<std::string> names;
  for (const auto& entry : std::filesystem::directory_iterator(dir)) names.push_back(entry.path().filename().string());
  std::sort(names.begin(), names.end());
  return names;
}

TEST(AtomicFile, WritesTheWholeFileAndLeavesNoPartialFile) {
  ScratchDir dir;
  ASSERT_TRUE(write_file_atomically(dir.file("a.json"), "{\"x\": 1}\n", "report").ok());
  EXPECT_EQ(read_bytes(dir.file("a.json")), "{\"x\": 1}\n");
  ASSERT_TRUE(write_file_atomically(dir.file("a.json"), "{}\n", "report").ok());  // replaces
  EXPECT_EQ(read_bytes(dir.file("a.json")), "{}\n");
  EXPECT_EQ(names_in(dir.path()), std::vector<std::string>{"a.json"});
}

TEST(AtomicFile, AnAbandonedWriteLeavesTheOldFileAndNoPartialFile) {
  ScratchDir dir;
  write_bytes(dir.file("rig"), "old");
  {
    Result<AtomicFile> file = AtomicFile::create(dir.file("rig"), "rig file");
    ASSERT_TRUE(file.ok());
    ASSERT_TRUE(file->write("half of a new").ok());
    EXPECT_TRUE(std::filesystem::exists(file->partial_path()));
  }  // destroyed without commit: an error path
  EXPECT_EQ(read_bytes(dir.file("rig")), "old");
  EXPECT_EQ(names_in(dir.path()), std::vector<std::string>{"rig"});
}

TEST(AtomicFile, ALibraryThatWroteNothingIsAnErrorNotAnEmptyFile) {
  ScratchDir dir;
  write_bytes(dir.file("v.nii"), "old");
  Result<AtomicFile> file = AtomicFile::create(dir.file("v.nii"), "volume");
  ASSERT_TRUE(file.ok());
  const Status committed = file->commit();
  EXPECT_EQ(committed.code(), StatusCode::kInternal);
  EXPECT_NE(committed.message().find("nothing was written"), std::string::npos) << committed.to_string();
  EXPECT_EQ(read_bytes(dir.file("v.nii")), "old");
}

TEST(AtomicFile, AMissingDirectoryIsNamedWithTheSystemsReason) {
  ScratchDir dir;
  const Status status = write_file_atomically(dir.file("no/such/report.json"), "{}", "report");
  EXPECT_EQ(status.code(), StatusCode::kNotFound);
  EXPECT_NE(status.message().find("no/such"), std::string::npos) << status.to_string();
  EXPECT_NE(status.message().find("No such file or directory"), std::string::npos) << status.to_string();
}

// Renaming over a directory failed with EISDIR after all the work, as an INTERNAL error (exit 1 from the CLI).
TEST(AtomicFile, ADirectoryInThePlaceOfTheFileIsNamedBeforeWriting) {
  ScratchDir dir;
  std::filesystem::create_directories(dir.file("mesh.vtu"));
  const Status status = write_file_atomically(dir.file("mesh.vtu"), "<VTKFile/>", "mesh");
  EXPECT_EQ(status.code(), StatusCode::kInvalidArgument) << status.to_string();
  const std::string named = dir.file("mesh.vtu");
  EXPECT_NE(status.message().find(named + "': it is a directory"), std::string::npos) << status.to_string();
  EXPECT_EQ(names_in(dir.path()), std::vector<std::string>{"mesh.vtu"});
  EXPECT_TRUE(std::filesystem::is_empty(dir.file("mesh.vtu")));
}

TEST(AtomicFile, ThreadsWritingTheSameTargetNeverMixTheirBytes) {
  ScratchDir dir;
  std::vector<std::thread> threads;
  for (int t = 0; t < 8; ++t) {
    threads.emplace_back([&dir, t] {
      const std::string text(100000, static_cast<char>('a' + t));
      for (int i = 0; i < 10; ++i) EXPECT_TRUE(write_file_atomically(dir.file("shared"), text, "file").ok());
    });
  }
  for (std::thread& thread : threads) thread.join();
  const std::string last = read_bytes(dir.file("shared"));
  ASSERT_EQ(last.size(), 100000u);
  EXPECT_EQ(last, std::string(100000, last[0]));  // one writer's bytes, whole
  EXPECT_EQ(names_in(dir.path()), std::vector<std::string>{"shared"});
}

TEST(AtomicDirectory, AppearsWholeOnCommitAndNotAtAllWithout) {
  ScratchDir dir;
  const std::string target = dir.file("posed");
  {
    Result<AtomicDirectory> out = AtomicDirectory::create(target, "posed files", AtomicDirectory::Existing::kRefuse);
    ASSERT_TRUE(out.ok()) << out.status().to_string();
    write_bytes((std::filesystem::path(out->partial_path()) / "labels.nii").string(), "labels");
    EXPECT_FALSE(std::filesystem::exists(target));
  }  // abandoned: nothing under the name, no partial directory
  EXPECT_TRUE(names_in(dir.path()).empty());
  Result<AtomicDirectory> out = AtomicDirectory::create(target, "posed files", AtomicDirectory::Existing::kRefuse);
  ASSERT_TRUE(out.ok());
  write_bytes((std::filesystem::path(out->partial_path()) / "labels.nii").string(), "labels");
  ASSERT_TRUE(out->commit().ok());
  EXPECT_EQ(read_bytes(dir.file("posed/labels.nii")), "labels");
  EXPECT_EQ(names_in(dir.path()), std::vector<std::string>{"posed"});
}

TEST(AtomicDirectory, AnExistingTargetIsRefusedOrReplacedInOneStep) {
  ScratchDir dir;
  const std::string target = dir.file("row");
  std::filesystem::create_directory(target);
  write_bytes(dir.file("row/old.txt"), "old");
  const Result<AtomicDirectory> refused = AtomicDirectory::create(target, "outputs", AtomicDirectory::Existing::kRefuse);
  EXPECT_EQ(refused.status().code(), StatusCode::kAlreadyExists);
  Result<AtomicDirectory> out = AtomicDirectory::create(target, "outputs", AtomicDirectory::Existing::kReplace);
  ASSERT_TRUE(out.ok());
  write_bytes((std::filesystem::path(out->partial_path()) / "new.txt").string(), "new");
  ASSERT_TRUE(out->commit().ok());
  EXPECT_EQ(names_in(target), std::vector<std::string>{"new.txt"});
  EXPECT_EQ(names_in(dir.path()), std::vector<std::string>{"row"});  // the old one went with its partial name
}

TEST(AtomicDirectory, APartialDirectoryOfADeadWriterGoesWithTheNextWrite) {
  ScratchDir dir;
  // A writer killed midway: its pid (far above any pid_max) is not a live process.
  const std::filesystem::path stale = dir.path() / ".posewarp-partial-999999999-0-row";
  std::filesystem::create_directories(stale / "dicom");
  write_bytes((stale / "dicom" / "1.dcm").string(), "half");
  ASSERT_TRUE(write_file_atomically(dir.file("other.json"), "{}", "report").ok());
  EXPECT_EQ(names_in(dir.path()), std::vector<std::string>{"other.json"});
}

}  // namespace
}  // namespace posewarp
