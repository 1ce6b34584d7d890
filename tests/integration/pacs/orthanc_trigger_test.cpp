// The Orthanc trigger (clients/orthanc/posewarp_trigger.py) in a real Orthanc with Debian's orthanc-python, and a
// real posewarp-server: a study stored with its SEG becomes stable, is queued, rigged and posed on the server, and
// its derived CT series and SEG appear in the same study; posewarp's own series never queue it again; a study left
// queued when Orthanc stopped is taken up when it starts again, and storing the result twice adds no series.
#include <gtest/gtest.h>
#include <unistd.h>

#include <nlohmann/json.hpp>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <string>
#include <thread>

#include "../server/server_process.h"
#include "../support/logged_run.h"
#include "../support/orthanc_process.h"
#include "posewarp/api/dicom.h"
#include "posewarp/api/files.h"
#include "posewarp/pacs/dicomweb.h"

namespace posewarp {
namespace {

namespace fs = std::filesystem;
using testing_support::OrthancProcess;
using testing_support::text;

constexpr const char* kPythonPlugin = "/usr/share/orthanc/plugins/libOrthancPython.so";

// The queue file's events of one kind.
int events(const fs::path& queue, const std::string& kind) {
  std::ifstream in(queue);
  int n = 0;
  for (std::string line; std::getline(in, line);) {
    const nlohmann::json entry = nlohmann::json::parse(line, nullptr, false);
    n += entry.is_object() && entry.value("event", "") == kind;
  }
  return n;
}

// Waits until `done` holds or `seconds` pass.
template <typename Done>
bool wait_until(Done done, int seconds) {
  for (int i = 0; i < seconds * 4; ++i) {
    if (done()) return true;
    std::this_thread::sleep_for(std::chrono::milliseconds(250));
  }
  return done();
}

TEST(OrthancTrigger, AStudyWithASegIsRepositionedOnTheServerAndStoredBackOnce) {
  if (!fs::exists(kPythonPlugin) || !fs::exists(testing_support::kOrthancDicomWebPlugin) ||
      std::system("command -v Orthanc >/dev/null 2>&1") != 0) {
    GTEST_SKIP() << "Orthanc with its DICOMweb and Python plugins is not installed (scripts/setup installs orthanc, "
                    "orthanc-dicomweb and orthanc-python)";
  }
  const fs::path dir = fs::temp_directory_path() / ("posewarp-trigger-" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  testing_server::ServerProcess server(dir / "store");
  ASSERT_GT(server.port(), 0);
  std::ofstream(dir / "password") << "s3cret\n";
  const nlohmann::json settings{
      {"Command", POSEWARP_CLI},
      {"Poses",
       {{{"Pose", std::string(POSEWARP_SOURCE_DIR) + "/data/poses/sample_hip_flexion.json"}, {"Method", "cor"}}}},
      {"Server", server.address()},
      {"PacsUser", "posewarp"},
      {"PacsPasswordFile", (dir / "password").string()},
      {"WorkDirectory", (dir / "work").string()},
      {"CtFormat", "enhanced"},
      {"SegFormat", "labelmap"}};
  const std::string extra = "\"StableAge\": 1, \"PythonScript\": \"" + std::string(POSEWARP_SOURCE_DIR) +
                            "/clients/orthanc/posewarp_trigger.py\", \"Posewarp\": " + settings.dump();
  const fs::path queue = dir / "work" / "queue.jsonl";

  std::string study_uid;
  {
    OrthancProcess orthanc(dir / "orthanc", extra, {kPythonPlugin});
    ASSERT_TRUE(orthanc.ready()) << orthanc.log();
    EXPECT_NE(orthanc.log().find("posewarp: trigger ready: 1 poses, server"), std::string::npos) << orthanc.log();
    EXPECT_NE(orthanc.log().find("CT as enhanced, SEG labelmap"), std::string::npos) << orthanc.log();
    // The sample as a study with its SEG, stored as a modality would (an Enhanced CT and a label map SEG: what the
    // trigger writes back, it reads).
    const std::string sample = std::string(POSEWARP_SOURCE_DIR) + "/data/totalsegmentator_example";
    api::DerivedSeriesOptions formats;
    formats.ct_format = api::CtFormat::kEnhanced;
    formats.seg_format = api::SegFormat::kLabelMap;
    Result<api::DicomOutputs> study = api::encode_new_dicom_study(
        *api::read_intensity_volume(sample + "/ct.nii.gz"), *api::read_label_volume(sample + "/seg_total.nii.gz"),
        *api::preset_by_name("totalsegmentator"), "Trigger^Test", "PW-TRIGGER", formats);
    ASSERT_TRUE(study.ok()) << study.status().to_string();
    study_uid = study->ct.study_instance_uid;
    pacs::DicomWebClient client(orthanc.options());
    ASSERT_TRUE(client.store(study->ct_files).ok());
    ASSERT_TRUE(client.store({study->seg_file}).ok());
    // Stable after a second, queued, posed on the server, stored back: four series in the study.
    const auto series_count = [&] {
      Result<std::vector<pacs::DicomWebRecord>> series = client.search_series(study_uid);
      return series.ok() ? series->size() : size_t{0};
    };
    ASSERT_TRUE(wait_until([&] { return events(queue, "done") + events(queue, "failed") >= 1; }, 240))
        << orthanc.log() << text(queue);
    ASSERT_EQ(events(queue, "done"), 1) << text(queue) << text(dir / "work" / "batch.log");
    ASSERT_EQ(series_count(), 4u);
    Result<std::vector<pacs::DicomWebRecord>> series = client.search_series(study_uid);
    ASSERT_TRUE(series.ok());
    std::string derived_ct, derived_seg;
    for (const pacs::DicomWebRecord& s : *series) {
      const std::string description = s.count("SeriesDescription") ? s.at("SeriesDescription") : "";
      if (s.at("Modality") == "CT" && description == "posewarp: sample_hip_flexion (cor)") {
        derived_ct = s.at("SeriesInstanceUID");
      }
      if (s.at("Modality") == "SEG" && description == "posewarp: sample_hip_flexion (cor) labels") {
        derived_seg = s.at("SeriesInstanceUID");
      }
    }
    ASSERT_TRUE(!derived_ct.empty() && !derived_seg.empty()) << "the derived CT and SEG are in the study";
    // In the formats configured: one Enhanced CT image and a label map SEG, read back on its grid.
    Result<std::vector<std::string>> ct_files = client.retrieve_series(study_uid, derived_ct, (dir / "ct").string());
    Result<std::vector<std::string>> seg_files = client.retrieve_series(study_uid, derived_seg, (dir / "seg").string());
    ASSERT_TRUE(ct_files.ok() && seg_files.ok() && ct_files->size() == 1 && seg_files->size() == 1);
    Result<api::DicomStudy> posed =
        api::read_dicom_study((dir / "ct").string(), seg_files->front(), *api::preset_by_name("totalsegmentator"));
    ASSERT_TRUE(posed.ok()) << posed.status().to_string();
    EXPECT_EQ(posed->ct.info.sop_class_uid, "1.2.840.10008.5.1.4.1.1.2.1");
    EXPECT_EQ(posed->ct.info.frame_numbers.size(), static_cast<size_t>(posed->ct.ct.geometry().size[2]));
    EXPECT_NE(text(seg_files->front()).find("1.2.840.10008.5.1.4.1.1.66.7"), std::string::npos) << "a label map SEG";
    EXPECT_GT(posed->segments.size(), 20u);
    // The rig was built on the server.
    EXPECT_EQ(testing_support::run({POSEWARP_CLI, "-q", "rig", "list", "--server", server.address()}, dir / "list.txt"),
              0);
    EXPECT_EQ(testing_support::lines_of(dir / "list.txt"), 1u) << text(dir / "list.txt");
    // The stored series changed the study, which became stable again: it is not queued a second time.
    std::this_thread::sleep_for(std::chrono::seconds(4));
    EXPECT_EQ(events(queue, "queued"), 1) << text(queue);
    // The queue over HTTP.
    const fs::path listing = dir / "queue.json";
    ASSERT_EQ(std::system(("curl -sf -u posewarp:s3cret http://127.0.0.1:" + std::to_string(orthanc.port()) +
                           "/posewarp/queue > '" + listing.string() + "'")
                              .c_str()),
              0);
    const nlohmann::json items = nlohmann::json::parse(text(listing), nullptr, false);
    ASSERT_TRUE(items.is_object() && items["items"].size() == 1) << text(listing);
    EXPECT_EQ(items["items"][0]["state"], "done");
    // No patient data in Orthanc's log lines from the trigger.
    EXPECT_EQ(orthanc.log().find("Trigger^Test"), std::string::npos);
    EXPECT_EQ(orthanc.log().find("PW-TRIGGER"), std::string::npos);
  }
  // Orthanc stopped with the study queued again (as after a crash between queueing and finishing): on start it is
  // taken up, and the batch stores the same UIDs, so the study still holds four series.
  const nlohmann::json first = nlohmann::json::parse(text(queue).substr(0, text(queue).find('\n')));
  std::ofstream(queue, std::ios::app)
      << nlohmann::json{{"event", "queued"}, {"key", first["key"]}, {"study", first["study"]}}.dump() << "\n";
  fs::remove_all(dir / "work" / first["study"].get<std::string>());  // the batch's state too: it is redone
  OrthancProcess again(dir / "orthanc", extra, {kPythonPlugin});
  ASSERT_TRUE(again.ready()) << again.log();
  EXPECT_TRUE(wait_until([&] { return events(queue, "done") == 2; }, 240)) << again.log() << text(queue);
  EXPECT_NE(again.log().find("queued again (unfinished when Orthanc stopped)"), std::string::npos) << again.log();
  pacs::DicomWebClient client(again.options());
  Result<std::vector<pacs::DicomWebRecord>> series = client.search_series(study_uid);
  ASSERT_TRUE(series.ok());
  EXPECT_EQ(series->size(), 4u);
  EXPECT_EQ(server.stop(), 0);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace posewarp
