// The DICOM path of the posewarp command, as a PACS-side user runs it, in each format (a CT series and a binary SEG;
// one Enhanced CT and a label map SEG): the sample exported as DICOM, a rig built from it, a pose written as a
// derived CT and a SEG of the same study; the DICOM outputs hold what the NIfTI outputs of the same pose hold, voxel
// for voxel, as posewarp reads them and as highdicom, dcmqi and SimpleITK read them; they refer to the study and
// series they came from.
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

struct Formats {
  std::string ct, seg;
};

class DicomCli : public ::testing::TestWithParam<Formats> {};

TEST_P(DicomCli, TheSampleIsPosedFromDicomToDicom) {
  const std::string ct_format = GetParam().ct, seg_format = GetParam().seg;
  const fs::path dir =
      fs::temp_directory_path() / ("posewarp-dicom-cli-" + std::to_string(::getpid()) + "-" + ct_format);
  fs::remove_all(dir);
  fs::create_directories(dir);
  const std::string sample = std::string(POSEWARP_SOURCE_DIR) + "/data/totalsegmentator_example";
  const std::string pose = std::string(POSEWARP_SOURCE_DIR) + "/data/poses/sample_hip_flexion.json";
  const fs::path log = dir / "log.txt";
  ASSERT_EQ(run({POSEWARP_CLI, "dicom", "export", "--ct", sample + "/ct.nii.gz", "--labels",
                 sample + "/seg_total.nii.gz", "--patient-name", "Sample^Phantom", "--patient-id", "PW-7",
                 "--ct-format", ct_format, "--seg-format", seg_format, "-o", (dir / "study").string()},
                log),
            0)
      << text(log);
  ASSERT_EQ(run({POSEWARP_CLI, "-q", "rig", "build", "--labels", (dir / "study/seg.dcm").string(), "--ct",
                 (dir / "study/ct").string(), "-o", (dir / "sample.rig").string()},
                log),
            0)
      << text(log);
  ASSERT_EQ(run({POSEWARP_CLI,     "-q",
                 "pose",           (dir / "sample.rig").string(),
                 "--pose",         pose,
                 "--dicom-out",    (dir / "posed").string(),
                 "--dicom-source", (dir / "study/ct").string(),
                 "--uid-root",     "1.2.826.0.1.3680043.10.42",
                 "--labels-out",   (dir / "labels.nii.gz").string(),
                 "--ct-out",       (dir / "ct.nii.gz").string(),
                 "--ct-format",    ct_format,
                 "--seg-format",   seg_format},
                log),
            0)
      << text(log);
  EXPECT_EQ(text(log).find("W: "), std::string::npos) << "DCMTK's own log leaked: " << text(log);
  EXPECT_EQ(api::list_dicom_files((dir / "posed/ct").string())->size(), ct_format == "enhanced" ? 1u : 112u);
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
  // Readers that are not posewarp's see the same voxels (tests/dicom/read_independently.py, in the project's venv).
  const fs::path venv_path = dir / "venv.txt";
  ASSERT_EQ(
      std::system((std::string(POSEWARP_SOURCE_DIR) + "/scripts/python-env > '" + venv_path.string() + "'").c_str()),
      0);
  const std::string venv = text(venv_path).substr(0, text(venv_path).find('\n'));
  const int independent =
      run({"/usr/bin/env", "PATH=" + venv + "/bin:/usr/bin:/bin", venv + "/bin/python",
           std::string(POSEWARP_SOURCE_DIR) + "/tests/dicom/read_independently.py", (dir / "posed").string(),
           (dir / "labels.nii.gz").string(), (dir / "ct.nii.gz").string()},
          log);
  EXPECT_EQ(independent, 0) << text(log);
  EXPECT_EQ(testing_support::lines_of(log), 4u) << text(log);  // highdicom and dcmqi (the SEG), highdicom and SimpleITK
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

INSTANTIATE_TEST_SUITE_P(Formats, DicomCli,
                         ::testing::Values(Formats{"series", "binary"}, Formats{"enhanced", "labelmap"}),
                         [](const ::testing::TestParamInfo<Formats>& param_info) {
                           return param_info.param.ct == "series" ? std::string("CtSeriesBinarySeg")
                                                                  : std::string("EnhancedCtLabelMapSeg");
                         });

}  // namespace
}  // namespace posewarp
