// The DICOM path of the posewarp command, as a PACS-side user runs it: the sample exported as a DICOM CT series and
// SEG, a rig built from them, a pose written as a derived CT series and a SEG of the same study; the DICOM outputs
// hold what the NIfTI outputs of the same pose hold, and refer to the study and series they came from.
#include <gtest/gtest.h>

#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <map>

#include "../support/logged_run.h"
#include "posewarp/api/dicom.h"
#include "posewarp/api/files.h"
#include "posewarp/dicom/ct_series.h"
#include "posewarp/dicom/segmentation.h"

namespace posewarp {
namespace {

namespace fs = std::filesystem;
using testing_support::run;
using testing_support::text;

TEST(DicomCli, TheSampleIsPosedFromDicomToDicom) {
  const fs::path dir = fs::temp_directory_path() / ("posewarp-dicom-cli-" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  const std::string sample = std::string(POSEWARP_SOURCE_DIR) + "/data/totalsegmentator_example";
  const std::string pose = std::string(POSEWARP_SOURCE_DIR) + "/data/poses/sample_hip_flexion.json";
  const fs::path log = dir / "log.txt";
  ASSERT_EQ(
      run({POSEWARP_CLI, "dicom", "export", "--ct", sample + "/ct.nii.gz", "--labels", sample + "/seg_total.nii.gz",
           "--patient-name", "Sample^Phantom", "--patient-id", "PW-7", "-o", (dir / "study").string()},
          log),
      0)
      << text(log);
  ASSERT_EQ(run({POSEWARP_CLI, "-q", "rig", "build", "--labels", (dir / "study/seg.dcm").string(), "--ct",
                 (dir / "study/ct").string(), "-o", (dir / "sample.rig").string()},
                log),
            0)
      << text(log);
  ASSERT_EQ(run({POSEWARP_CLI, "-q", "pose", (dir / "sample.rig").string(), "--pose", pose, "--dicom-out",
                 (dir / "posed").string(), "--dicom-source", (dir / "study/ct").string(), "--uid-root",
                 "1.2.826.0.1.3680043.10.42", "--labels-out", (dir / "labels.nii.gz").string(), "--ct-out",
                 (dir / "ct.nii.gz").string()},
                log),
            0)
      << text(log);
  EXPECT_EQ(text(log).find("W: "), std::string::npos) << "DCMTK's own log leaked: " << text(log);
  // The derived CT series: the same voxels as the NIfTI CT of the same pose, in the source's study.
  Result<api::CtSeries> source = api::read_ct_directory((dir / "study/ct").string());
  Result<api::CtSeries> posed = api::read_ct_directory((dir / "posed/ct").string());
  ASSERT_TRUE(source.ok() && posed.ok()) << posed.status().to_string();
  Result<IntensityVolume> nifti_ct = api::read_intensity_volume((dir / "ct.nii.gz").string());
  Result<LabelVolume> nifti_labels = api::read_label_volume((dir / "labels.nii.gz").string());
  ASSERT_TRUE(nifti_ct.ok() && nifti_labels.ok());
  const ImageGeometry &a = nifti_ct->geometry(), &b = posed->ct.geometry();
  const auto original_index = [&](int64_t i, int64_t j, int64_t k) {
    const Vec3 at = a.physical_to_index(
        b.index_to_physical({static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)}));
    return std::array<int64_t, 3>{std::lround(at[0]), std::lround(at[1]), std::lround(at[2])};
  };
  for (int64_t k = 0; k < b.size[2]; ++k) {
    for (int64_t j = 0; j < b.size[1]; j += 3) {
      for (int64_t i = 0; i < b.size[0]; i += 3) {
        const auto at = original_index(i, j, k);
        ASSERT_EQ(posed->ct.at(i, j, k), nifti_ct->at(at[0], at[1], at[2])) << i << " " << j << " " << k;
      }
    }
  }
  EXPECT_EQ(posed->info.study_instance_uid, source->info.study_instance_uid);
  EXPECT_EQ(posed->info.patient_name, "Sample^Phantom");
  EXPECT_EQ(posed->info.patient_id, "PW-7");
  EXPECT_NE(posed->info.series_instance_uid, source->info.series_instance_uid);
  EXPECT_EQ(posed->info.series_instance_uid.rfind("1.2.826.0.1.3680043.10.42.", 0), 0u);
  EXPECT_NE(posed->info.series_description.find("sample_hip_flexion"), std::string::npos);
  // The SEG on it: each voxel the segment named as the posed label's name in the rig's map.
  std::string seg_bytes = text(dir / "posed/seg.dcm");
  Result<dicom::Segmentation> seg = dicom::read_segmentation(seg_bytes, b);
  ASSERT_TRUE(seg.ok()) << seg.status().to_string();
  EXPECT_EQ(seg->referenced_series_uid, posed->info.series_instance_uid);
  std::map<int, std::string> name_of_segment;
  for (const dicom::Segment& s : seg->segments) name_of_segment[s.number] = s.label;
  // The rig built from the SEG numbered its labels by segment: the posed NIfTI labels are segment numbers of the
  // input SEG, named the same way.
  Result<dicom::Segmentation> input_seg = dicom::read_segmentation(text(dir / "study/seg.dcm"), source->ct.geometry());
  ASSERT_TRUE(input_seg.ok());
  std::map<int, std::string> input_name;
  for (const dicom::Segment& s : input_seg->segments) input_name[s.number] = s.label;
  int64_t labelled = 0;
  for (int64_t k = 0; k < b.size[2]; ++k) {
    for (int64_t j = 0; j < b.size[1]; j += 2) {
      for (int64_t i = 0; i < b.size[0]; i += 2) {
        const auto at = original_index(i, j, k);
        const Label label = nifti_labels->at(at[0], at[1], at[2]);
        const Label number = seg->labels.at(i, j, k);
        ASSERT_EQ(label == 0, number == 0) << i << " " << j << " " << k;
        if (label == 0) continue;
        ASSERT_EQ(name_of_segment.at(number), input_name.at(label)) << i << " " << j << " " << k;
        ++labelled;
      }
    }
  }
  EXPECT_GT(labelled, 5000);
  // An output directory that holds something is refused before any work.
  EXPECT_EQ(run({POSEWARP_CLI, "pose", (dir / "sample.rig").string(), "--pose", pose, "--dicom-out",
                 (dir / "posed").string(), "--dicom-source", (dir / "study/ct").string()},
                log) >>
                8,
            2);
  EXPECT_NE(text(log).find("not empty"), std::string::npos) << text(log);
  EXPECT_EQ(run({POSEWARP_CLI, "pose", (dir / "sample.rig").string(), "--pose", pose, "--dicom-out",
                 (dir / "other").string()},
                log) >>
                8,
            2);
  EXPECT_NE(text(log).find("--dicom-source"), std::string::npos) << text(log);
  // A --dicom-source that is not the rig's series (another grid) is refused: its study is not the rig's.
  ASSERT_EQ(run({POSEWARP_CLI, "phantom", "bar", "-o", (dir / "bar").string()}, log), 0);
  ASSERT_EQ(run({POSEWARP_CLI, "dicom", "export", "--ct", (dir / "bar/ct.nii.gz").string(), "--labels",
                 (dir / "bar/labels.nii.gz").string(), "--label-map", (dir / "bar/label_map.json").string(), "-o",
                 (dir / "bar-study").string()},
                log),
            0)
      << text(log);
  EXPECT_EQ(run({POSEWARP_CLI, "pose", (dir / "sample.rig").string(), "--pose", pose, "--dicom-out",
                 (dir / "wrong").string(), "--dicom-source", (dir / "bar-study/ct").string()},
                log) >>
                8,
            2);
  EXPECT_NE(text(log).find("is not the CT series the rig was built from"), std::string::npos) << text(log);
  fs::remove_all(dir);
}

}  // namespace
}  // namespace posewarp
