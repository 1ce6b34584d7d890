// Damaged and hostile inputs given to the real `posewarp` process: the documented exit code, a message that names
// the file and the problem, no hang, small time and memory, and no input changed.
#include <gtest/gtest.h>
#include <sys/stat.h>
#include <unistd.h>

#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <string>

#include "cli_run.h"

namespace posewarp::bad_input {
namespace {

TEST_F(BadInput, UsageErrorsExitWithTwoLikeOtherBadInput) {
  EXPECT_EQ(posewarp({"rig", "buidl"}).exit_code, 2);
  EXPECT_EQ(posewarp({"rig", "build", "--labels"}).exit_code, 2);
  EXPECT_EQ(posewarp({"pose", at("bar.rig"), "--method", "nope", "--pose", at("pose.json")}).exit_code, 2);
  EXPECT_EQ(posewarp({"--help"}).exit_code, 0);
  EXPECT_EQ(posewarp({"--version"}).exit_code, 0);
}

TEST_F(BadInput, OutputsOntoInputsAreRefusedAndTheInputsKept) {
  const std::string labels = file_text(at("labels.nii.gz"));
  const std::string pose = file_text(at("pose.json"));
  expect_refused(posewarp({"rig", "build", "--labels", at("labels.nii.gz"), "--label-map", at("label_map.json"), "-o",
                           at("labels.nii.gz")}),
                 2, "labels.nii.gz", "destroy the input");
  expect_refused(posewarp({"pose", at("bar.rig"), "--pose", at("pose.json"), "--report", at("pose.json")}), 2,
                 "pose.json", "destroy the input");
  fs::create_symlink(at("pose.json"), at("link_to_pose.json"));
  expect_refused(posewarp({"pose", at("bar.rig"), "--pose", at("pose.json"), "--report", at("link_to_pose.json")}), 2,
                 "pose.json", "destroy the input");
  expect_refused(posewarp({"convert", at("labels.nii.gz"), at("labels.nii.gz")}), 2, "labels.nii.gz",
                 "destroy the input");
  EXPECT_EQ(file_text(at("labels.nii.gz")), labels);
  EXPECT_EQ(file_text(at("pose.json")), pose);
}

TEST_F(BadInput, DirectoriesFifosAndDevicesAreNamedAndNeverBlock) {
  fs::create_directories(at("a_directory.rig"));
  expect_refused(posewarp({"rig", "info", at("a_directory.rig")}), 2, "a_directory.rig", "is a directory");
  ASSERT_EQ(::mkfifo(at("fifo.json").c_str(), 0600), 0);
  expect_refused(posewarp({"pose", at("bar.rig"), "--pose", at("fifo.json")}), 2, "fifo.json", "FIFO");
  fs::create_symlink("/dev/zero", at("zero.rig"));
  expect_refused(posewarp({"rig", "info", at("zero.rig")}), 2, "zero.rig", "device");
  expect_refused(posewarp({"pose", at("bar.rig"), "--pose", "/dev/zero"}), 2, "/dev/zero", "device");
  expect_refused(posewarp({"rig", "info", at("missing.rig")}), 2, "missing.rig", "no such file");
}

// `posewarp rig upgrade`: a rig from the last release gains what this version keeps (its sections), the same again
// has nothing to add and is left as it is, and a directory as the output or a damaged rig is refused.
TEST_F(BadInput, RigUpgradeCompletesAnOlderRigAndRefusesBadFiles) {
  fs::copy_file(std::string(POSEWARP_SOURCE_DIR) + "/tests/data/rig_format_1/bar.rig", at("old.rig"),
                fs::copy_options::overwrite_existing);
  const CliRun upgraded = posewarp({"rig", "upgrade", at("old.rig"), "-o", at("upgraded.rig")});
  EXPECT_EQ(upgraded.exit_code, 0) << upgraded.err;
  const std::string old_bytes = file_text(at("old.rig")), new_bytes = file_text(at("upgraded.rig"));
  for (const char* section : {"OWNR", "REGN", "SUBS", "SKIN"}) {
    EXPECT_EQ(old_bytes.find(section), std::string::npos) << section;
    EXPECT_NE(new_bytes.find(section), std::string::npos) << section;
  }
  const fs::file_time_type written = fs::last_write_time(at("upgraded.rig"));
  const CliRun again = posewarp({"rig", "upgrade", at("upgraded.rig")});
  EXPECT_EQ(again.exit_code, 0) << again.err;
  EXPECT_EQ(fs::last_write_time(at("upgraded.rig")), written);  // nothing to add: not written again
  EXPECT_EQ(posewarp({"pose", at("upgraded.rig"), "--pose", at("pose.json")}).exit_code, 0);
  fs::create_directories(at("out_dir.rig"));
  expect_refused(posewarp({"rig", "upgrade", at("upgraded.rig"), "-o", at("out_dir.rig")}), 2, "out_dir.rig",
                 "is a directory");
  const std::string bytes = file_text(at("upgraded.rig"));
  std::ofstream(at("cut.rig"), std::ios::binary) << bytes.substr(0, bytes.size() / 3);
  const CliRun cut = posewarp({"rig", "upgrade", at("cut.rig")});
  EXPECT_EQ(cut.exit_code, 2) << cut.err;
  EXPECT_EQ(file_text(at("cut.rig")).size(), bytes.size() / 3);  // left as it was
}

TEST_F(BadInput, DamagedFilesExitWithTwo) {
  // A truncated rig (DATA_LOSS is bad input: copy the file again).
  const std::string rig = file_text(at("bar.rig"));
  std::ofstream(at("truncated.rig"), std::ios::binary) << rig.substr(0, rig.size() / 2);
  const CliRun truncated = posewarp({"rig", "info", at("truncated.rig")});
  EXPECT_EQ(truncated.exit_code, 2) << truncated.err;
  EXPECT_NE(truncated.err.find("truncated.rig"), std::string::npos) << truncated.err;
  // A NIfTI whose sform holds a NaN (ITK would abort in its SVD).
  std::string nifti;
  {
    const CliRun converted = posewarp({"--quiet", "convert", at("labels.nii.gz"), at("plain.nii")});
    ASSERT_EQ(converted.exit_code, 0) << converted.err;
    nifti = file_text(at("plain.nii"));
  }
  const float nan = std::nanf("");
  std::memcpy(nifti.data() + 280, &nan, sizeof nan);
  std::ofstream(at("nan_sform.nii"), std::ios::binary) << nifti;
  expect_refused(posewarp({"info", at("nan_sform.nii")}), 2, "nan_sform.nii", "srow_x");
}

TEST_F(BadInput, HostileJsonAndParametersAreRefusedQuickly) {
  {
    std::ofstream deep(at("deep.json"));
    deep << "{\"joints\": " << std::string(1000000, '[') << std::string(1000000, ']') << "}";
  }
  expect_refused(posewarp({"pose", at("bar.rig"), "--pose", at("deep.json")}), 2, "deep.json", "levels deep");
  std::ofstream(at("far_contacts.json")) << R"({"contact_distance_mm": 1e6})";
  expect_refused(posewarp({"rig", "build", "--labels", at("labels.nii.gz"), "--label-map", at("label_map.json"),
                           "--rig-spec", at("far_contacts.json"), "-o", at("far.rig")}),
                 2, "far_contacts.json", "contact_distance_mm");
}

TEST_F(BadInput, PartialFilesOfDeadWritersAreCleanedUp) {
  // A writer killed mid-write leaves its partial file; pid 2^22 - 1 is beyond Linux's default pid_max.
  const fs::path stale = dir_ / ".posewarp-partial-4194303-old.rig";
  std::ofstream(stale) << "half a rig";
  const fs::path live = dir_ / (".posewarp-partial-" + std::to_string(::getpid()) + "-mine.rig");
  std::ofstream(live) << "being written";
  EXPECT_EQ(posewarp({"rig", "info", at("bar.rig")}).exit_code, 0);
  EXPECT_FALSE(fs::exists(stale));
  EXPECT_TRUE(fs::exists(live));  // its writer is alive
  fs::remove(live);
}

TEST_F(BadInput, WritesIntoAMissingDirectoryNameItAndExitTwo) {
  const CliRun run = posewarp({"rig", "build", "--labels", at("labels.nii.gz"), "--label-map", at("label_map.json"),
                               "-o", at("no/such/dir/bar.rig")});
  EXPECT_EQ(run.exit_code, 2) << run.err;
  EXPECT_NE(run.err.find("no/such/dir"), std::string::npos) << run.err;
  EXPECT_NE(run.err.find("does not exist"), std::string::npos) << run.err;
  EXPECT_EQ(run.err.find("skeleton"), std::string::npos) << run.err;  // refused before any stage ran
  const CliRun pose = posewarp({"pose", at("bar.rig"), "--pose", at("pose.json"), "--labels-out", at("nowhere/l.nii.gz")});
  EXPECT_EQ(pose.exit_code, 2) << pose.err;
  EXPECT_NE(pose.err.find("nowhere"), std::string::npos) << pose.err;
}

// posewarp compare: one pose with several methods, side by side, and its JSON; bad method lists are usage errors.
TEST_F(BadInput, CompareWritesEachMethodsReportAndRefusesBadMethodLists) {
  const CliRun run = posewarp({"compare", at("bar.rig"), "--pose", at("pose.json"), "--methods", "cor,fem", "--json",
                               at("compare.json")});
  ASSERT_EQ(run.exit_code, 0) << run.err;
  const std::string json = file_text(at("compare.json"));
  EXPECT_NE(json.find("\"format\": \"posewarp.compare\""), std::string::npos) << json.substr(0, 400);
  EXPECT_NE(json.find("\"method\": \"cor\""), std::string::npos);
  EXPECT_NE(json.find("\"method\": \"fem\""), std::string::npos);
  EXPECT_NE(json.find("\"moved_joints\""), std::string::npos);
  EXPECT_NE(json.find("\"skin_inside_tissue\""), std::string::npos);
  expect_refused(posewarp({"compare", at("bar.rig"), "--pose", at("pose.json"), "--methods", "cor"}), 2, "--methods",
                 "two to four");
  expect_refused(posewarp({"compare", at("bar.rig"), "--pose", at("pose.json"), "--methods", "cor,cor"}), 2, "cor",
                 "twice");
  expect_refused(posewarp({"compare", at("bar.rig"), "--pose", at("pose.json"), "--methods", "cor,nope"}), 2, "nope",
                 "lbs, dqs, cor or fem");
}

}  // namespace
}  // namespace posewarp::bad_input
