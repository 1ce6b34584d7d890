// posewarp batch, run as a process: rows of a JSON and a CSV manifest (files and a DICOM series with its SEG), a
// failing row recorded while the others finish, a rig built once per study, the summary, a rerun that skips what is
// done, and a batch killed in the middle that a rerun completes without redoing finished rows.
#include <fcntl.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>
#include <nlohmann/json.hpp>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <thread>

#include "../support/logged_run.h"
#include "posewarp/api/dicom.h"
#include "posewarp/api/files.h"

namespace posewarp {
namespace {

namespace fs = std::filesystem;
using testing_support::run;
using testing_support::text;
using testing_support::lines_of;

class Batch : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("posewarp-batch-" + std::to_string(::getpid()) + "-" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    sample_ = std::string(POSEWARP_SOURCE_DIR) + "/data/totalsegmentator_example";
    poses_ = std::string(POSEWARP_SOURCE_DIR) + "/data/poses";
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
  std::string sample_, poses_;
};

TEST_F(Batch, RowsRunInParallelAFailureIsRecordedAndARerunSkipsWhatIsDone) {
  const fs::path log = dir_ / "log.txt";
  ASSERT_EQ(run({POSEWARP_CLI, "dicom", "export", "--ct", sample_ + "/ct.nii.gz", "--labels",
                 sample_ + "/seg_total.nii.gz", "-o", (dir_ / "study").string()},
                log),
            0)
      << text(log);
  const nlohmann::json manifest{
      {"format", "posewarp.batch"},
      {"version", 1},
      {"defaults", {{"labels", sample_ + "/seg_total.nii.gz"}, {"ct", sample_ + "/ct.nii.gz"}}},
      {"rows",
       {{{"id", "cor"}, {"pose", poses_ + "/sample_hip_flexion.json"}, {"out_dir", "out/cor"}},
        {{"id", "dqs"}, {"pose", poses_ + "/sample_hip_flexion.json"}, {"method", "dqs"}, {"out_dir", "out/dqs"}},
        {{"id", "wrong-joint"}, {"pose", poses_ + "/knee_bent.json"}, {"out_dir", "out/wrong"}},
        // The pose that matches another scan's labels (here the study's own: the pose found is rest), and a
        // standard posture.
        {{"id", "match"}, {"match", sample_ + "/seg_total.nii.gz"}, {"out_dir", "out/match"}},
        {{"id", "straight"}, {"standard", "limbs-straight"}, {"out_dir", "out/straight"}},
        {{"id", "from-dicom"},
         {"labels", ""},
         {"ct", ""},
         {"dicom_ct", "study/ct"},
         {"dicom_seg", "study/seg.dcm"},
         {"pose", poses_ + "/sample_hip_flexion.json"},
         {"out_dir", "out/dicom"}}}}};
  std::ofstream(dir_ / "batch.json") << manifest.dump(2);
  EXPECT_EQ(run({POSEWARP_CLI, "batch", (dir_ / "batch.json").string(), "--jobs", "2"}, log) >> 8, 1) << text(log);
  const std::string said = text(log);
  EXPECT_NE(said.find("row 'wrong-joint' failed"), std::string::npos) << said;
  // Two studies (the files, and the DICOM series): two rig builds for four rows.
  size_t builds = 0;
  for (size_t at = said.find("building the rig"); at != std::string::npos; at = said.find("building the rig", at + 1))
    ++builds;
  EXPECT_EQ(builds, 2u) << said;
  EXPECT_NE(said.find("5 done, 1 failed"), std::string::npos) << said;
  // The summary: each row's status, outputs and figures; the study's rig paid for once.
  const nlohmann::json summary = nlohmann::json::parse(text(dir_ / "batch.summary.json"));
  std::map<std::string, nlohmann::json> by_id;
  for (const auto& row : summary["rows"]) by_id[row["id"]] = row;
  EXPECT_EQ(by_id["cor"]["status"], "done");
  EXPECT_EQ(by_id["dqs"]["status"], "done");
  EXPECT_EQ(by_id["from-dicom"]["status"], "done");
  EXPECT_EQ(by_id["wrong-joint"]["status"], "failed");
  EXPECT_NE(by_id["wrong-joint"]["error"].get<std::string>().find("knee_left"), std::string::npos);
  EXPECT_TRUE(by_id["cor"]["report"].contains("inverted_tets"));
  const double rig_cor = by_id["cor"]["seconds"]["rig"], rig_dqs = by_id["dqs"]["seconds"]["rig"];
  EXPECT_TRUE((rig_cor > 0) != (rig_dqs > 0)) << "one of the two rows of the study builds its rig";
  EXPECT_EQ(lines_of(dir_ / "batch.summary.csv"), 7u);
  EXPECT_EQ(std::distance(fs::directory_iterator(dir_ / "batch.rigs"), fs::directory_iterator()), 2);  // two studies
  // The outputs: volumes and a report per row; the DICOM row also a derived series and SEG of its study.
  for (const char* out : {"out/cor", "out/dqs", "out/dicom"}) {
    for (const char* file : {"labels.nii.gz", "ct.nii.gz", "report.json"})
      EXPECT_TRUE(fs::exists(dir_ / out / file)) << out << "/" << file;
  }
  EXPECT_FALSE(fs::exists(dir_ / "out/wrong"));
  // A match row writes the pose found and its match report beside the volumes, on the target's grid; a standard
  // posture's row the pose.
  const nlohmann::json found = nlohmann::json::parse(text(dir_ / "out/match/pose.json"));
  EXPECT_NEAR(found["joints"]["hip_left"]["angles_deg"]["flexion"].get<double>(), 0.0, 1.0) << found.dump();
  const nlohmann::json fit = nlohmann::json::parse(text(dir_ / "out/match/match.json"));
  EXPECT_EQ(fit["format"], "posewarp.match");
  Result<api::VolumeHeader> posed = api::read_header((dir_ / "out/match/labels.nii.gz").string());
  Result<api::VolumeHeader> target = api::read_header(sample_ + "/seg_total.nii.gz");
  ASSERT_TRUE(posed.ok() && target.ok());
  EXPECT_EQ(posed->geometry.size, target->geometry.size);
  EXPECT_TRUE(nlohmann::json::parse(text(dir_ / "out/straight/pose.json"))["joints"].contains("hip_right"));
  EXPECT_FALSE(fs::exists(dir_ / "out/straight/match.json"));
  Result<api::CtSeries> derived = api::read_ct_directory((dir_ / "out/dicom/dicom/ct").string());
  Result<api::CtSeries> source = api::read_ct_directory((dir_ / "study/ct").string());
  ASSERT_TRUE(derived.ok() && source.ok()) << derived.status().to_string();
  EXPECT_EQ(derived->info.study_instance_uid, source->info.study_instance_uid);
  EXPECT_TRUE(fs::exists(dir_ / "out/dicom/dicom/seg.dcm"));
  // A rerun skips the five finished rows and tries the failed one again.
  EXPECT_EQ(lines_of(dir_ / "batch.state.jsonl"), 5u);
  EXPECT_EQ(run({POSEWARP_CLI, "batch", (dir_ / "batch.json").string()}, log) >> 8, 1);
  EXPECT_NE(text(log).find("5 done before (skipped)"), std::string::npos) << text(log);
  EXPECT_EQ(lines_of(dir_ / "batch.state.jsonl"), 5u);
  // The skipped rows' outputs are those the run that did them recorded.
  const nlohmann::json rerun = nlohmann::json::parse(text(dir_ / "batch.summary.json"));
  for (const auto& row : rerun["rows"]) {
    if (row["id"] == "wrong-joint") continue;
    EXPECT_EQ(row["status"], "skipped") << row.dump();
    EXPECT_EQ(row["outputs"], by_id[row["id"]]["outputs"]) << row.dump();
  }
}

TEST_F(Batch, ACsvManifestKilledInTheMiddleIsCompletedByARerun) {
  const fs::path log = dir_ / "log.txt";
  std::ofstream csv(dir_ / "rows.csv");
  csv << "id,labels,ct,pose,method,out_dir\n";
  for (const char* method : {"cor", "dqs", "lbs"}) {
    csv << method << "," << sample_ << "/seg_total.nii.gz," << sample_ << "/ct.nii.gz," << poses_
        << "/sample_hip_flexion.json," << method << ",out/" << method << "\n";
  }
  csv.close();
  // Killed (SIGKILL) once the first row is recorded.
  const pid_t batch = ::fork();
  if (batch == 0) {
    const int null = ::open("/dev/null", O_WRONLY);
    ::dup2(null, 1);
    ::dup2(null, 2);
    ::execl(POSEWARP_CLI, POSEWARP_CLI, "batch", (dir_ / "rows.csv").c_str(), "--jobs", "1",
            static_cast<char*>(nullptr));
    ::_exit(127);
  }
  const fs::path state = dir_ / "rows.state.jsonl";
  for (int i = 0; i < 1200 && lines_of(state) < 1; ++i) std::this_thread::sleep_for(std::chrono::milliseconds(50));
  ::kill(batch, SIGKILL);
  ::waitpid(batch, nullptr, 0);
  const size_t finished = lines_of(state);
  ASSERT_GE(finished, 1u) << "no row finished before the kill";
  ASSERT_LT(finished, 3u) << "the batch ended before it could be killed";
  // What was not finished left no output that looks finished (at most a .partial directory).
  size_t whole = 0;
  for (const char* method : {"cor", "dqs", "lbs"}) whole += fs::exists(dir_ / "out" / method / "report.json");
  EXPECT_EQ(whole, finished);
  ASSERT_EQ(run({POSEWARP_CLI, "batch", (dir_ / "rows.csv").string(), "--jobs", "2"}, log), 0) << text(log);
  EXPECT_NE(text(log).find(std::to_string(finished) + " done before (skipped)"), std::string::npos) << text(log);
  EXPECT_EQ(lines_of(state), 3u);  // each row recorded once
  for (const char* method : {"cor", "dqs", "lbs"})
    EXPECT_TRUE(fs::exists(dir_ / "out" / method / "report.json")) << method;
  // The killed row's partial directory went with the rerun's first write beside it (its writer is dead).
  for (const auto& entry : fs::directory_iterator(dir_ / "out")) {
    EXPECT_NE(entry.path().filename().string().rfind(".posewarp-partial-", 0), 0u) << entry.path();
  }
}

TEST_F(Batch, BadManifestsAreRefusedBeforeAnyWork) {
  const fs::path log = dir_ / "log.txt";
  std::ofstream(dir_ / "empty.json") << R"({"rows": []})";
  EXPECT_EQ(run({POSEWARP_CLI, "batch", (dir_ / "empty.json").string()}, log) >> 8, 2);
  EXPECT_NE(text(log).find("has no rows"), std::string::npos) << text(log);
  std::ofstream(dir_ / "two.json")
      << R"({"rows": [{"labels": "a.nii.gz", "dicom_ct": "d", "dicom_seg": "s.dcm", "pose": "p.json", "out_dir": "o"}]})";
  EXPECT_EQ(run({POSEWARP_CLI, "batch", (dir_ / "two.json").string()}, log) >> 8, 2);
  EXPECT_NE(text(log).find("give one input"), std::string::npos) << text(log);
  std::ofstream(dir_ / "both.json")
      << R"({"rows": [{"labels": "a.nii.gz", "pose": "p.json", "match": "b.nii.gz", "out_dir": "o"}]})";
  EXPECT_EQ(run({POSEWARP_CLI, "batch", (dir_ / "both.json").string()}, log) >> 8, 2);
  EXPECT_NE(text(log).find("give one of pose, animation, match"), std::string::npos) << text(log);
  std::ofstream(dir_ / "field.csv") << "id,labels,colour\nx,a.nii.gz,red\n";
  EXPECT_EQ(run({POSEWARP_CLI, "batch", (dir_ / "field.csv").string()}, log) >> 8, 2);
  EXPECT_NE(text(log).find("unknown field 'colour'"), std::string::npos) << text(log);
  std::ofstream(dir_ / "pacs.json") << R"({"rows": [{"pacs_study": "2.25.1", "pose": "p.json", "to_pacs": true}]})";
  EXPECT_EQ(run({POSEWARP_CLI, "batch", (dir_ / "pacs.json").string()}, log) >> 8, 2);
  EXPECT_NE(text(log).find("--pacs URL"), std::string::npos) << text(log);
}

}  // namespace
}  // namespace posewarp
