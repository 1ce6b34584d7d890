// posewarp match as a user runs it, on the real sample: a rig built from it, the sample posed with known angles at
// both hips and a known root motion (labels only, on the sample's grid), and the match finding those angles and
// that motion back from the posed labels alone, with each bone of more than 5 ml on its target (Dice at least 0.9),
// and the rig posed by what was found on the target's grid holding the target's labels.
#include <gtest/gtest.h>
#include <unistd.h>

#include <nlohmann/json.hpp>

#include <filesystem>
#include <fstream>

#include "../support/logged_run.h"
#include "posewarp/api/files.h"

namespace posewarp {
namespace {

namespace fs = std::filesystem;
using testing_support::run;
using testing_support::text;

TEST(MatchCli, FindsTheAnglesOfAPoseOfTheSampleFromItsLabels) {
  const fs::path dir = fs::temp_directory_path() / ("posewarp-match-" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  const std::string sample = std::string(POSEWARP_SOURCE_DIR) + "/data/totalsegmentator_example";
  const fs::path log = dir / "log.txt";
  ASSERT_EQ(run({POSEWARP_CLI, "-q", "rig", "build", "--labels", sample + "/seg_total.nii.gz", "--ct",
                 sample + "/ct.nii.gz", "-o", (dir / "sample.rig").string()},
                log),
            0)
      << text(log);
  std::ofstream(dir / "truth.json") << R"({"format": "posewarp.pose", "version": 1, "name": "truth",
    "root": {"translation_mm": [4, -3, 5], "rotation": {"axis_angle": {"axis": [0, 0, 1], "degrees": 4}}},
    "joints": {"hip_left": {"angles_deg": {"flexion": 25, "abduction": 10}},
               "hip_right": {"angles_deg": {"flexion": -10, "abduction": 12}}}})";
  ASSERT_EQ(run({POSEWARP_CLI, "-q", "pose", (dir / "sample.rig").string(), "--pose", (dir / "truth.json").string(),
                 "--labels-out", (dir / "target.nii.gz").string(), "--ct-out", (dir / "target_ct.nii.gz").string()},
                log),
            0)
      << text(log);
  ASSERT_EQ(
      run({POSEWARP_CLI, "match", (dir / "sample.rig").string(), "--target-labels", (dir / "target.nii.gz").string(),
           "-o", (dir / "found.json").string(), "--report", (dir / "report.json").string()},
          log),
      0)
      << text(log);
  EXPECT_NE(text(log).find("hip_left"), std::string::npos) << text(log);
  const nlohmann::json found = nlohmann::json::parse(text(dir / "found.json"));
  const nlohmann::json& joints = found["joints"];
  EXPECT_NEAR(joints["hip_left"]["angles_deg"]["flexion"].get<double>(), 25.0, 2.0) << found.dump(1);
  EXPECT_NEAR(joints["hip_left"]["angles_deg"]["abduction"].get<double>(), 10.0, 2.0) << found.dump(1);
  EXPECT_NEAR(joints["hip_right"]["angles_deg"]["flexion"].get<double>(), -10.0, 2.0) << found.dump(1);
  EXPECT_NEAR(joints["hip_right"]["angles_deg"]["abduction"].get<double>(), 12.0, 2.0) << found.dump(1);
  for (const char* rest : {"lumbosacral", "sacroiliac_left", "sacroiliac_right"}) {
    for (const char* angle : {"flexion", "abduction", "rotation"}) {
      EXPECT_NEAR(joints[rest]["angles_deg"][angle].get<double>(), 0.0, 2.0) << rest << " " << angle;
    }
  }
  // The root: the translation within a voxel (3 mm) once its turn about the root's centroid is the same.
  const nlohmann::json& t = found["root"]["translation_mm"];
  EXPECT_NEAR(t[0].get<double>(), 4.0, 3.0);
  EXPECT_NEAR(t[1].get<double>(), -3.0, 3.0);
  EXPECT_NEAR(t[2].get<double>(), 5.0, 3.0);
  const nlohmann::json report = nlohmann::json::parse(text(dir / "report.json"));
  EXPECT_NEAR(report["root"]["rotation_deg"].get<double>(), 4.0, 1.0);
  for (const nlohmann::json& s : report["segments"]) {
    ASSERT_TRUE(s["matched"].get<bool>()) << s.dump();
    if (s["volume_ml"].get<double>() > 5.0) {
      EXPECT_GE(s["dice"].get<double>(), 0.9) << s.dump();
    }
  }
  // The pose found is a pose file like any other.
  EXPECT_EQ(run({POSEWARP_CLI, "-q", "pose", (dir / "sample.rig").string(), "--pose", (dir / "found.json").string(),
                 "--report", (dir / "posed.json").string()},
                log),
            0)
      << text(log);
  // The same target as DICOM (a CT series and a label map SEG on it, as a PACS holds it): the same angles.
  ASSERT_EQ(run({POSEWARP_CLI, "-q", "dicom", "export", "--ct", (dir / "target_ct.nii.gz").string(), "--labels",
                 (dir / "target.nii.gz").string(), "--seg-format", "labelmap", "-o", (dir / "dicom").string()},
                log),
            0)
      << text(log);
  ASSERT_EQ(run({POSEWARP_CLI, "match", (dir / "sample.rig").string(), "--target-labels",
                 (dir / "dicom/seg.dcm").string(), "--target-ct", (dir / "dicom/ct").string(), "-o",
                 (dir / "from_dicom.json").string()},
                log),
            0)
      << text(log);
  const nlohmann::json from_dicom = nlohmann::json::parse(text(dir / "from_dicom.json"));
  EXPECT_NEAR(from_dicom["joints"]["hip_left"]["angles_deg"]["flexion"].get<double>(), 25.0, 2.0);
  EXPECT_NEAR(from_dicom["joints"]["hip_right"]["angles_deg"]["abduction"].get<double>(), 12.0, 2.0);
  EXPECT_EQ(run({POSEWARP_CLI, "match", (dir / "sample.rig").string(), "--target-labels",
                 (dir / "dicom/seg.dcm").string(), "-o", (dir / "z.json").string()},
                log) >>
                8,
            2);
  EXPECT_NE(text(log).find("give --target-ct DIR"), std::string::npos) << text(log);
  // A standard posture needs no target: the sample's legs straightened (its hips are its limbs' joints).
  ASSERT_EQ(run({POSEWARP_CLI, "match", (dir / "sample.rig").string(), "--standard", "limbs-straight", "-o",
                 (dir / "straight.json").string()},
                log),
            0)
      << text(log);
  const nlohmann::json straight = nlohmann::json::parse(text(dir / "straight.json"));
  EXPECT_TRUE(straight["joints"].contains("hip_left") && straight["joints"].contains("hip_right")) << straight.dump();
  // A target without the root's bone is refused by name; a target that is no label volume too.
  std::ofstream(dir / "no_sacrum.json") << R"({"format": "posewarp.label_map", "version": 1, "name": "no sacrum",
    "labels": [{"name": "background", "role": "background", "value": 0},
               {"name": "not_sacrum", "role": "tissue", "value": 25}]})";
  EXPECT_EQ(
      run({POSEWARP_CLI, "match", (dir / "sample.rig").string(), "--target-labels", (dir / "target.nii.gz").string(),
           "--label-map", (dir / "no_sacrum.json").string(), "-o", (dir / "x.json").string()},
          log) >>
          8,
      2);
  EXPECT_NE(text(log).find("root segment 'sacrum' is missing from the target's labels"), std::string::npos)
      << text(log);
  EXPECT_NE(run({POSEWARP_CLI, "match", (dir / "sample.rig").string(), "--target-labels", (dir / "found.json").string(),
                 "-o", (dir / "y.json").string()},
                log),
            0);
  EXPECT_FALSE(fs::exists(dir / "y.json"));
  fs::remove_all(dir);
}

}  // namespace
}  // namespace posewarp
