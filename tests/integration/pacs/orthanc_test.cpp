// The DICOMweb client against a real Orthanc (Debian's orthanc and orthanc-dicomweb) on a free loopback port, with
// a temporary storage directory and authentication on: the sample stored as a DICOM CT series and SEG (STOW-RS),
// found (QIDO-RS), retrieved (WADO-RS) voxel for voxel, posed, and the derived CT series and SEG stored back into the
// same study; wrong credentials and an unreachable PACS give clear errors.
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <filesystem>
#include <fstream>
#include <thread>

#include "../support/free_port.h"
#include "../support/orthanc_process.h"
#include "posewarp/api/dicom.h"
#include "posewarp/api/files.h"
#include "posewarp/api/pose_engine.h"
#include "posewarp/api/rig.h"
#include "posewarp/dicom/ct_series.h"
#include "posewarp/dicom/segmentation.h"
#include "posewarp/pacs/dicomweb.h"

namespace posewarp {
namespace {

namespace fs = std::filesystem;
using pacs::DicomWebClient;
using pacs::DicomWebOptions;
using testing_support::kOrthancDicomWebPlugin;
using testing_support::OrthancProcess;

std::vector<std::string> files_of(const std::vector<std::string>& paths) {
  std::vector<std::string> bytes;
  for (const std::string& p : paths) {
    std::ifstream in(p, std::ios::binary);
    bytes.emplace_back(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  }
  return bytes;
}

class Orthanc : public ::testing::Test {
 protected:
  void SetUp() override {
    if (!fs::exists(kOrthancDicomWebPlugin) || std::system("command -v Orthanc >/dev/null 2>&1") != 0) {
      GTEST_SKIP() << "Orthanc and its DICOMweb plugin are not installed (scripts/setup installs orthanc and "
                      "orthanc-dicomweb)";
    }
    dir_ = fs::temp_directory_path() / ("posewarp-orthanc-" + std::to_string(::getpid()) + "-" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    orthanc_ = std::make_unique<OrthancProcess>(dir_ / "orthanc");
    ASSERT_TRUE(orthanc_->ready()) << "Orthanc did not start:\n" << orthanc_->log();
    // The sample as a DICOM study (a CT series and its SEG), as a hospital's PACS would hold it.
    const std::string dir = POSEWARP_SAMPLE_DIR;
    ct_ = *api::read_intensity_volume(dir + "/ct.nii.gz");
    labels_ = *api::read_label_volume(dir + "/seg_total.nii.gz");
    map_ = *api::preset_by_name("totalsegmentator");
    Result<api::DicomOutputs> study =
        api::encode_new_dicom_study(ct_, labels_, map_, "Sample^Phantom", "PW-ORTHANC", {});
    ASSERT_TRUE(study.ok()) << study.status().to_string();
    study_ = *study;
  }
  void TearDown() override {
    orthanc_.reset();
    fs::remove_all(dir_);
  }
  fs::path dir_;
  std::unique_ptr<OrthancProcess> orthanc_;
  IntensityVolume ct_;
  LabelVolume labels_;
  api::LabelMap map_;
  api::DicomOutputs study_;
};

TEST_F(Orthanc, StoresFindsAndRetrievesASeriesVoxelForVoxel) {
  DicomWebClient client(orthanc_->options());
  ASSERT_TRUE(client.store(study_.ct_files).ok());
  ASSERT_TRUE(client.store({study_.seg_file}).ok());
  Result<std::vector<pacs::DicomWebRecord>> studies = client.search_studies("PatientID=PW-ORTHANC");
  ASSERT_TRUE(studies.ok()) << studies.status().to_string();
  ASSERT_EQ(studies->size(), 1u);
  EXPECT_EQ(studies->front().at("StudyInstanceUID"), study_.ct.study_instance_uid);
  EXPECT_TRUE(client.search_studies("PatientID=SOMEONE-ELSE")->empty());
  Result<std::vector<pacs::DicomWebRecord>> series = client.search_series(study_.ct.study_instance_uid);
  ASSERT_TRUE(series.ok());
  ASSERT_EQ(series->size(), 2u);
  Result<std::vector<pacs::DicomWebRecord>> cts = client.search_series(study_.ct.study_instance_uid, "Modality=CT");
  ASSERT_EQ(cts->size(), 1u);
  EXPECT_EQ(cts->front().at("SeriesInstanceUID"), study_.ct.series_instance_uid);
  // WADO-RS: the series streamed to disk, part by part, reads as what was stored.
  Result<std::vector<std::string>> paths = client.retrieve_series(
      study_.ct.study_instance_uid, study_.ct.series_instance_uid, (dir_ / "retrieved").string());
  ASSERT_TRUE(paths.ok()) << paths.status().to_string();
  EXPECT_EQ(paths->size(), study_.ct_files.size());
  Result<api::CtSeries> retrieved = api::read_ct_directory((dir_ / "retrieved").string());
  Result<api::CtSeries> stored = dicom::read_ct_series(study_.ct_files);
  ASSERT_TRUE(retrieved.ok() && stored.ok()) << retrieved.status().to_string();
  EXPECT_TRUE(retrieved->ct.geometry().same_grid(stored->ct.geometry(), 1e-9));
  EXPECT_EQ(retrieved->ct.voxels(), stored->ct.voxels());
  EXPECT_EQ(retrieved->info.patient_name, "Sample^Phantom");
  // A series it does not hold: not found.
  EXPECT_EQ(client.retrieve_series(study_.ct.study_instance_uid, "2.25.1", (dir_ / "none").string()).status().code(),
            StatusCode::kNotFound);
}

TEST_F(Orthanc, WrongCredentialsAndAnUnreachablePacsGetClearErrors) {
  DicomWebClient wrong(orthanc_->options("not-the-password"));
  Result<std::vector<pacs::DicomWebRecord>> refused = wrong.search_studies("");
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.status().code(), StatusCode::kPermissionDenied);
  EXPECT_NE(refused.status().message().find("refused the credentials"), std::string::npos);
  DicomWebOptions gone = orthanc_->options();
  gone.base_url = "http://127.0.0.1:" + std::to_string(testing_support::free_port()) + "/dicom-web";
  gone.connect_timeout_s = 2;
  Result<std::vector<pacs::DicomWebRecord>> unreachable = DicomWebClient(gone).search_studies("");
  ASSERT_FALSE(unreachable.ok());
  EXPECT_EQ(unreachable.status().code(), StatusCode::kUnavailable);
  EXPECT_NE(unreachable.status().message().find("is it running"), std::string::npos) << unreachable.status().message();
}

// The PACS-side job once: fetch the study, build its rig, pose it, store the derived CT series and SEG back; the
// study then holds them beside the original, with the original's patient and study, and the derived series is the
// local pose voxel for voxel.
TEST_F(Orthanc, APoseOfAStudyInThePacsIsStoredBackIntoThatStudy) {
  DicomWebClient client(orthanc_->options());
  ASSERT_TRUE(client.store(study_.ct_files).ok());
  ASSERT_TRUE(client.store({study_.seg_file}).ok());
  const std::string study_uid = study_.ct.study_instance_uid;
  Result<std::vector<std::string>> ct_paths =
      client.retrieve_series(study_uid, study_.ct.series_instance_uid, (dir_ / "fetched/ct").string());
  Result<std::vector<std::string>> seg_paths =
      client.retrieve_series(study_uid, study_.seg.series_instance_uid, (dir_ / "fetched/seg").string());
  ASSERT_TRUE(ct_paths.ok() && seg_paths.ok());
  ASSERT_EQ(seg_paths->size(), 1u);
  Result<api::DicomStudy> study = api::read_dicom_study(files_of(*ct_paths), files_of(*seg_paths).front(), map_);
  ASSERT_TRUE(study.ok()) << study.status().to_string();
  api::BuildInputs inputs;
  inputs.labels = study->labels;
  inputs.ct = study->ct.ct;
  inputs.label_map = study->label_map;
  Result<api::Rig> rig = api::build_rig(inputs, {}, {});
  ASSERT_TRUE(rig.ok()) << rig.status().to_string();
  Result<api::PoseEngine> engine = api::PoseEngine::create(std::move(rig).value());
  ASSERT_TRUE(engine.ok());
  api::PoseRequest request;
  request.pose = *api::read_pose(std::string(POSEWARP_SOURCE_DIR) + "/data/poses/sample_hip_flexion.json");
  request.want_labels = request.want_ct = true;
  Result<api::PoseResult> posed = engine->pose(request);
  ASSERT_TRUE(posed.ok()) << posed.status().to_string();
  api::DerivedSeriesOptions options;
  options.series_description = "posewarp: sample_hip_flexion (cor)";
  Result<api::DicomOutputs> outputs =
      api::encode_dicom_outputs(*posed->ct, *posed->labels, engine->rig().label_map, study->ct.info, options);
  ASSERT_TRUE(outputs.ok()) << outputs.status().to_string();
  ASSERT_TRUE(client.store(outputs->ct_files, study_uid).ok());
  ASSERT_TRUE(client.store({outputs->seg_file}, study_uid).ok());
  // In the PACS: the same study, now with four series; the derived one as posed here.
  Result<std::vector<pacs::DicomWebRecord>> series = client.search_series(study_uid);
  ASSERT_TRUE(series.ok());
  EXPECT_EQ(series->size(), 4u);
  Result<std::vector<pacs::DicomWebRecord>> studies = client.search_studies("PatientID=PW-ORTHANC");
  ASSERT_EQ(studies->size(), 1u);
  Result<std::vector<std::string>> derived_paths =
      client.retrieve_series(study_uid, outputs->ct.series_instance_uid, (dir_ / "derived").string());
  ASSERT_TRUE(derived_paths.ok());
  Result<api::CtSeries> derived = api::read_ct_directory((dir_ / "derived").string());
  ASSERT_TRUE(derived.ok()) << derived.status().to_string();
  EXPECT_EQ(derived->info.study_instance_uid, study_uid);
  EXPECT_EQ(derived->info.patient_id, "PW-ORTHANC");
  EXPECT_EQ(derived->info.series_description, "posewarp: sample_hip_flexion (cor)");
  EXPECT_EQ(derived->ct.voxels(), dicom::read_ct_series(outputs->ct_files)->ct.voxels());
  Result<std::vector<std::string>> seg_back =
      client.retrieve_series(study_uid, outputs->seg.series_instance_uid, (dir_ / "derived-seg").string());
  ASSERT_TRUE(seg_back.ok());
  Result<dicom::Segmentation> seg = dicom::read_segmentation(files_of(*seg_back).front(), derived->ct.geometry());
  ASSERT_TRUE(seg.ok()) << seg.status().to_string();
  EXPECT_EQ(seg->referenced_series_uid, outputs->ct.series_instance_uid);
}

// posewarp batch against the PACS: two poses of a study stored into it; a rerun that forgot its state (as after a
// crash before the state was written) and a query-made batch of the same pose store nothing twice.
TEST_F(Orthanc, ABatchStoresEachPoseOnceEvenWhenRunAgain) {
  DicomWebClient client(orthanc_->options());
  const std::string study_uid = study_.ct.study_instance_uid;
  std::ofstream(dir_ / "password") << "s3cret\n";
  const std::string poses = std::string(POSEWARP_SOURCE_DIR) + "/data/poses";
  std::ofstream(dir_ / "rows.csv") << "id,pacs_study,pose,method,to_pacs\n"
                                   << "cor," << study_uid << "," << poses << "/sample_hip_flexion.json,cor,true\n"
                                   << "dqs," << study_uid << "," << poses << "/sample_hip_flexion.json,dqs,true\n";
  const std::vector<std::string> pacs{"--pacs",   orthanc_->options().base_url, "--pacs-user",
                                      "posewarp", "--pacs-password-file",       (dir_ / "password").string()};
  const auto batch = [&](std::vector<std::string> args) {
    args.insert(args.begin(), POSEWARP_CLI);
    args.insert(args.end(), pacs.begin(), pacs.end());
    std::string command;
    for (const std::string& a : args) command += "'" + a + "' ";
    return std::system((command + "> '" + (dir_ / "batch.log").string() + "' 2>&1").c_str());
  };
  const auto log = [&] {
    std::ifstream in(dir_ / "batch.log");
    return std::string(std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>());
  };
  const auto count = [&](const std::string& modality) {
    Result<std::vector<pacs::DicomWebRecord>> series = client.search_series(study_uid, "Modality=" + modality);
    return series.ok() ? series->size() : size_t{999};
  };
  // The study goes in as a user would put it there: its files, then posewarp dicom store.
  ASSERT_TRUE(api::write_dicom_outputs(study_, (dir_ / "study").string()).ok());
  ASSERT_EQ(batch({"dicom", "store", (dir_ / "study/ct").string(), (dir_ / "study/seg.dcm").string()}), 0) << log();
  EXPECT_NE(log().find("stored " + std::to_string(study_.ct_files.size()) + " instances"), std::string::npos) << log();
  ASSERT_EQ(batch({"batch", (dir_ / "rows.csv").string(), "--jobs", "2"}), 0) << log();
  EXPECT_EQ(count("CT"), 3u);  // the original and two derived
  EXPECT_EQ(count("SEG"), 3u);
  Result<std::vector<pacs::DicomWebRecord>> series = client.search_series(study_uid, "Modality=CT");
  size_t derived_instances = 0;
  for (const auto& s : *series) {
    if (s.at("SeriesInstanceUID") != study_.ct.series_instance_uid)
      derived_instances += std::stoul(s.at("NumberOfSeriesRelatedInstances"));
  }
  EXPECT_EQ(derived_instances, 2 * study_.ct_files.size());
  // The summary says where each went.
  std::ifstream summary_file(dir_ / "rows.summary.csv");
  const std::string summary((std::istreambuf_iterator<char>(summary_file)), std::istreambuf_iterator<char>());
  EXPECT_NE(summary.find("pacs:"), std::string::npos) << summary;
  // Run again without its state, then as a query for the same pose: the same series, stored once.
  fs::remove(dir_ / "rows.state.jsonl");
  ASSERT_EQ(batch({"batch", (dir_ / "rows.csv").string()}), 0) << log();
  ASSERT_EQ(batch({"batch", "--query", "PatientID=PW-ORTHANC", "--pose", poses + "/sample_hip_flexion.json",
                   "--to-pacs", "--out-dir", (dir_ / "query").string()}),
            0)
      << log();
  EXPECT_NE(log().find("1 done"), std::string::npos) << log();
  EXPECT_EQ(count("CT"), 3u);
  EXPECT_EQ(count("SEG"), 3u);
  EXPECT_TRUE(fs::exists(dir_ / "query" / study_uid / "report.json"));
  // A query that finds nothing: a clear error.
  EXPECT_EQ(
      batch({"batch", "--query", "PatientID=NOBODY", "--pose", poses + "/sample_hip_flexion.json", "--to-pacs"}) >> 8,
      2)
      << log();
}

// The multipart splitter on its own: parts whose bytes hold boundary-like text, split in 1 MiB blocks.
TEST(Multipart, PartsAreSplitAtTheirBoundariesOnly) {
  const fs::path dir = fs::temp_directory_path() / ("posewarp-multipart-" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  // Parts sized so that a delimiter starts at every offset around the first 1 MiB block's edge.
  const std::string header = "--B0UND\r\nContent-Type: application/dicom\r\n\r\n";
  for (int shift = -12; shift <= 12; ++shift) {
    std::string body = "preamble\r\n";
    const std::vector<std::string> parts{
        "first\r\n--notit", std::string(static_cast<size_t>((1 << 20) - 80 + shift), 'x'), std::string("\0\1\2", 3)};
    for (const std::string& p : parts) body += header + p + "\r\n";
    body += "--B0UND--\r\nepilogue";
    std::ofstream(dir / "body", std::ios::binary | std::ios::trunc) << body;
    Result<std::vector<std::string>> written = pacs::split_multipart_file(
        (dir / "body").string(), "multipart/related; type=\"application/dicom\"; boundary=B0UND", dir.string());
    ASSERT_TRUE(written.ok()) << written.status().to_string();
    ASSERT_EQ(written->size(), parts.size()) << "shift " << shift;
    for (size_t i = 0; i < parts.size(); ++i)
      EXPECT_EQ(files_of({(*written)[i]}).front(), parts[i]) << "shift " << shift << " part " << i;
  }
  std::string body = "preamble\r\n" + header + "only\r\n--B0UND--\r\n";
  // Cut short: an error, not a silently short part.
  std::ofstream(dir / "short", std::ios::binary) << body.substr(0, body.size() / 2);
  EXPECT_FALSE(
      pacs::split_multipart_file((dir / "short").string(), "multipart/related; boundary=B0UND", dir.string()).ok());
  EXPECT_FALSE(pacs::split_multipart_file((dir / "body").string(), "application/dicom", dir.string()).ok());
  std::ofstream(dir / "none", std::ios::binary) << "no parts here";
  EXPECT_FALSE(
      pacs::split_multipart_file((dir / "none").string(), "multipart/related; boundary=B0UND", dir.string()).ok());
  fs::remove_all(dir);
}

}  // namespace
}  // namespace posewarp
