// posewarp batch --server against the real server process: a DICOM study (a CT series and its SEG) and the same
// sample as files, each uploaded once and rigged on the server, its rows posed there; the results are the voxels the
// local engine gives on the server's own rig, the DICOM row's derived series belongs to the source study, and a
// rerun finds the volumes and rigs on the server instead of sending and building them again.
#include <gtest/gtest.h>
#include <unistd.h>

#include <nlohmann/json.hpp>

#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <string>

#include "../support/logged_run.h"
#include "posewarp/api/dicom.h"
#include "posewarp/api/files.h"
#include "server_process.h"

namespace posewarp {
namespace {

namespace fs = std::filesystem;
using testing_support::lines_of;
using testing_support::text;

// Rig ids by name, from `posewarp rig list --server`.
std::map<std::string, std::string> rigs_on(const std::string& server, const fs::path& log) {
  std::map<std::string, std::string> rigs;
  if (testing_support::run({POSEWARP_CLI, "-q", "rig", "list", "--server", server}, log) != 0) return rigs;
  std::istringstream lines(text(log));
  for (std::string id, name, rest; lines >> id >> name && std::getline(lines, rest);) rigs[name] = id;
  return rigs;
}

// The voxels of two volume files agree (the files themselves may be compressed differently).
template <typename Read>
void expect_same_voxels(const fs::path& a, const fs::path& b, Read read) {
  auto va = read(a.string());
  auto vb = read(b.string());
  ASSERT_TRUE(va.ok() && vb.ok()) << a << " " << b;
  ASSERT_EQ(va->geometry().size, vb->geometry().size) << a;
  EXPECT_TRUE(std::equal(va->data(), va->data() + va->voxel_count(), vb->data())) << a << " differs from " << b;
}

TEST(BatchThroughServer, StudiesAreRiggedOnTheServerAndPosedThereAsLocally) {
  const fs::path dir = fs::temp_directory_path() / ("posewarp-batch-server-" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  const std::string sample = std::string(POSEWARP_SOURCE_DIR) + "/data/totalsegmentator_example";
  const std::string pose = std::string(POSEWARP_SOURCE_DIR) + "/data/poses/sample_hip_flexion.json";
  const fs::path log = dir / "log.txt";
  ASSERT_EQ(testing_support::run({POSEWARP_CLI, "dicom", "export", "--ct", sample + "/ct.nii.gz", "--labels",
                                  sample + "/seg_total.nii.gz", "-o", (dir / "study").string()},
                                 log),
            0)
      << text(log);
  const nlohmann::json manifest{{"format", "posewarp.batch"},
                                {"version", 1},
                                {"rows",
                                 {{{"id", "dicom-cor"},
                                   {"dicom_ct", "study/ct"},
                                   {"dicom_seg", "study/seg.dcm"},
                                   {"pose", pose},
                                   {"out_dir", "out/dicom-cor"}},
                                  {{"id", "dicom-dqs"},
                                   {"dicom_ct", "study/ct"},
                                   {"dicom_seg", "study/seg.dcm"},
                                   {"pose", pose},
                                   {"method", "dqs"},
                                   {"out_dir", "out/dicom-dqs"}},
                                  {{"id", "files-cor"},
                                   {"labels", sample + "/seg_total.nii.gz"},
                                   {"ct", sample + "/ct.nii.gz"},
                                   {"pose", pose},
                                   {"out_dir", "out/files-cor"}},
                                  {{"id", "files-match"},
                                   {"labels", sample + "/seg_total.nii.gz"},
                                   {"ct", sample + "/ct.nii.gz"},
                                   {"match", sample + "/seg_total.nii.gz"},
                                   {"out_dir", "out/files-match"}}}}};
  std::ofstream(dir / "batch.json") << manifest.dump(2);

  testing_server::ServerProcess server(dir / "store");
  ASSERT_GT(server.port(), 0);
  const std::string address = server.address();
  ASSERT_EQ(testing_support::run(
                {POSEWARP_CLI, "batch", (dir / "batch.json").string(), "--jobs", "2", "--server", address}, log),
            0)
      << text(log) << server.log();
  const std::string said = text(log);
  EXPECT_NE(said.find("4 done, 0 failed"), std::string::npos) << said;
  EXPECT_FALSE(fs::exists(dir / "batch.rigs")) << "the server keeps the rigs, not the batch";

  // Two studies, two rigs on the server: the DICOM study's (named by its series) and the files'.
  const std::map<std::string, std::string> rigs = rigs_on(address, dir / "list.txt");
  ASSERT_EQ(rigs.size(), 2u) << text(dir / "list.txt");
  ASSERT_TRUE(rigs.count("seg_total.nii.gz")) << text(dir / "list.txt");
  std::string dicom_rig;
  for (const auto& [name, id] : rigs) {
    if (name != "seg_total.nii.gz") dicom_rig = id;
  }

  // Each row's voxels are what the local engine gives on the server's rig.
  const auto local_pose = [&](const std::string& rig_id, const std::string& method, const fs::path& out) {
    fs::create_directories(out);
    return testing_support::run(
        {POSEWARP_CLI, "-q", "pose", (dir / "store" / "rigs" / (rig_id + ".rig")).string(), "--pose", pose, "--method",
         method, "--labels-out", (out / "labels.nii.gz").string(), "--ct-out", (out / "ct.nii.gz").string()},
        log);
  };
  const auto read_labels = [](const std::string& p) { return api::read_label_volume(p); };
  const auto read_ct = [](const std::string& p) { return api::read_intensity_volume(p); };
  for (const auto& [row, rig, method] :
       {std::tuple{"files-cor", rigs.at("seg_total.nii.gz"), "cor"}, std::tuple{"dicom-cor", dicom_rig, "cor"},
        std::tuple{"dicom-dqs", dicom_rig, "dqs"}}) {
    SCOPED_TRACE(row);
    const fs::path local = dir / "local" / row;
    ASSERT_EQ(local_pose(rig, method, local), 0) << text(log);
    expect_same_voxels(dir / "out" / row / "labels.nii.gz", local / "labels.nii.gz", read_labels);
    expect_same_voxels(dir / "out" / row / "ct.nii.gz", local / "ct.nii.gz", read_ct);
    const nlohmann::json report = nlohmann::json::parse(text(dir / "out" / row / "report.json"), nullptr, false);
    EXPECT_EQ(report.value("format", ""), "posewarp.quality_report");
  }
  // The match row: matched on the server (MatchPosture) and posed there onto the target's grid, as the local match
  // on the server's rig poses it.
  {
    const fs::path local = dir / "local" / "files-match";
    fs::create_directories(local);
    ASSERT_EQ(
        testing_support::run(
            {POSEWARP_CLI, "-q", "match", (dir / "store" / "rigs" / (rigs.at("seg_total.nii.gz") + ".rig")).string(),
             "--target-labels", sample + "/seg_total.nii.gz", "-o", (local / "pose.json").string(), "--labels-out",
             (local / "labels.nii.gz").string(), "--ct-out", (local / "ct.nii.gz").string()},
            log),
        0)
        << text(log);
    expect_same_voxels(dir / "out/files-match/labels.nii.gz", local / "labels.nii.gz", read_labels);
    expect_same_voxels(dir / "out/files-match/ct.nii.gz", local / "ct.nii.gz", read_ct);
    EXPECT_EQ(text(dir / "out/files-match/pose.json"), text(local / "pose.json"));
    EXPECT_TRUE(fs::exists(dir / "out/files-match/match.json"));
  }
  // The summary carries the server's report figures.
  const nlohmann::json summary = nlohmann::json::parse(text(dir / "batch.summary.json"));
  for (const auto& row : summary["rows"]) {
    EXPECT_EQ(row["status"], "done") << row.dump();
    EXPECT_TRUE(row["report"]["inverted_tets"].is_number()) << row.dump();
  }
  // The DICOM rows wrote a derived series and a SEG of the source study.
  Result<api::CtSeries> derived = api::read_ct_directory((dir / "out/dicom-cor/dicom/ct").string());
  Result<api::CtSeries> source = api::read_ct_directory((dir / "study/ct").string());
  ASSERT_TRUE(derived.ok() && source.ok()) << derived.status().to_string();
  EXPECT_EQ(derived->info.study_instance_uid, source->info.study_instance_uid);
  EXPECT_NE(derived->info.series_instance_uid, source->info.series_instance_uid);
  EXPECT_TRUE(fs::exists(dir / "out/dicom-cor/dicom/seg.dcm"));

  // Run again from scratch (no state file): the volumes are on the server already and the rigs are found, not built.
  fs::remove(dir / "batch.state.jsonl");
  ASSERT_EQ(testing_support::run({POSEWARP_CLI, "batch", (dir / "batch.json").string(), "--server", address}, log), 0)
      << text(log);
  const std::string again = text(log);
  EXPECT_NE(again.find("labels.nii.gz is on the server already"), std::string::npos) << again;
  EXPECT_NE(again.find("seg_total.nii.gz is on the server already"), std::string::npos) << again;
  EXPECT_EQ(again.find("uploaded "), std::string::npos) << again;
  EXPECT_EQ(rigs_on(address, dir / "list.txt").size(), 2u);
  EXPECT_EQ(lines_of(dir / "batch.state.jsonl"), 4u);

  // pose --server --dicom-out files the derived series in --dicom-source's study: a series of another grid (the bar
  // phantom's) is refused before anything is posed or written.
  ASSERT_EQ(testing_support::run({POSEWARP_CLI, "-q", "phantom", "bar", "-o", (dir / "bar").string()}, log), 0);
  ASSERT_EQ(testing_support::run({POSEWARP_CLI, "-q", "dicom", "export", "--ct", (dir / "bar/ct.nii.gz").string(),
                                  "--labels", (dir / "bar/labels.nii.gz").string(), "--label-map",
                                  (dir / "bar/label_map.json").string(), "-o", (dir / "bar-dicom").string()},
                                 log),
            0)
      << text(log);
  EXPECT_EQ(testing_support::run({POSEWARP_CLI, "pose", "--server", address, dicom_rig, "--pose", pose, "--dicom-out",
                                  (dir / "foreign").string(), "--dicom-source", (dir / "bar-dicom/ct").string()},
                                 log) >>
                8,
            2);
  EXPECT_NE(text(log).find("is not the CT series the rig was built from"), std::string::npos) << text(log);
  EXPECT_FALSE(fs::exists(dir / "foreign"));
  // The right series is taken.
  EXPECT_EQ(testing_support::run({POSEWARP_CLI, "-q", "pose", "--server", address, dicom_rig, "--pose", pose,
                                  "--dicom-out", (dir / "own").string(), "--dicom-source", (dir / "study/ct").string()},
                                 log),
            0)
      << text(log);
  EXPECT_TRUE(fs::exists(dir / "own/seg.dcm"));

  // An unreachable server fails every row with a message that names it; the batch says so in its exit code.
  fs::remove(dir / "batch.state.jsonl");
  EXPECT_EQ(
      testing_support::run(
          {POSEWARP_CLI, "batch", (dir / "batch.json").string(), "--server", "127.0.0.1:1", "--retries", "0"}, log) >>
          8,
      1);
  EXPECT_NE(text(log).find("cannot reach posewarp-server at 127.0.0.1:1"), std::string::npos) << text(log);
  EXPECT_EQ(server.stop(), 0);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace posewarp
