// DICOM CT series: the sample through a derived series and back (geometry and voxels), what a derived series says
// about where it came from, instances in memory, and the series that must be refused (tilted, gappy, repeated,
// mixed, not CT), the rescale, UIDs, and dciodvfy's verdict where dicom3tools is installed.
#include <dcmtk/config/osconfig.h>
#include <dcmtk/dcmdata/dcdeftag.h>
#include <dcmtk/dcmdata/dcfilefo.h>
#include <dcmtk/dcmdata/dcistrmb.h>
#include <dcmtk/dcmdata/dcostrmb.h>
#include <dcmtk/dcmdata/dcsequen.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <functional>
#include <set>

#include "dataset_edit.h"
#include "made_up_source.h"
#include "posewarp/dicom/ct_series.h"
#include "posewarp/dicom/segmentation.h"
#include "posewarp/io/volume_io.h"

namespace posewarp::dicom {
namespace {

namespace fs = std::filesystem;

IntensityVolume sample_ct() {
  Result<IntensityVolume> ct = io::read_intensity_volume(std::string(POSEWARP_SAMPLE_DIR) + "/ct.nii.gz");
  EXPECT_TRUE(ct.ok()) << ct.status().to_string();
  return *ct;
}

std::string text_of(const std::string& bytes, const DcmTagKey& tag) {
  std::string value;
  edited(bytes, [&](DcmDataset& d) {
    OFString v;
    d.findAndGetOFStringArray(tag, v);
    value = v.c_str();
  });
  return value;
}

// Every voxel of `back` sits (to a micrometre) on a voxel of `ct`, with its value.
void expect_same_voxels(const IntensityVolume& ct, const IntensityVolume& back) {
  const ImageGeometry &a = ct.geometry(), &b = back.geometry();
  for (int axis = 0; axis < 3; ++axis) {
    EXPECT_EQ(a.size[static_cast<size_t>(axis)], b.size[static_cast<size_t>(axis)]);
    EXPECT_NEAR(a.spacing[static_cast<size_t>(axis)], b.spacing[static_cast<size_t>(axis)], 1e-6);
  }
  for (int64_t k = 0; k < b.size[2]; ++k) {
    for (int64_t j = 0; j < b.size[1]; j += 3) {
      for (int64_t i = 0; i < b.size[0]; i += 2) {
        const Vec3 p = b.index_to_physical({static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)});
        const Vec3 at = a.physical_to_index(p);
        for (double c : at) ASSERT_NEAR(c, std::round(c), 1e-4);
        ASSERT_EQ(back.at(i, j, k), ct.at(std::lround(at[0]), std::lround(at[1]), std::lround(at[2])));
      }
    }
  }
}

class DicomCt : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = fs::temp_directory_path() / ("posewarp-dicom-test-" + std::to_string(::getpid()) + "-" +
                                        ::testing::UnitTest::GetInstance()->current_test_info()->name());
    fs::remove_all(dir_);
    fs::create_directories(dir_);
  }
  void TearDown() override { fs::remove_all(dir_); }
  fs::path dir_;
};

TEST_F(DicomCt, TheSampleGoesThroughADerivedSeriesAndBackExactly) {
  const IntensityVolume ct = sample_ct();
  Result<SeriesInfo> written = write_derived_ct(ct, made_up_source(), {}, (dir_ / "series").string());
  ASSERT_TRUE(written.ok()) << written.status().to_string();
  EXPECT_EQ(written->sop_instance_uids.size(), static_cast<size_t>(ct.size()[2]));
  Result<CtSeries> back = read_ct_directory((dir_ / "series").string());
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  // The same voxels at the same places: each voxel read back sits (to a micrometre) on a voxel of the original,
  // with its value. (A left-handed grid comes back with its slice axis reversed.)
  expect_same_voxels(ct, back->ct);
  EXPECT_EQ(back->info.patient_name, "Sample^Phantom");
  EXPECT_EQ(back->info.series_instance_uid, written->series_instance_uid);
}

TEST_F(DicomCt, ADerivedSeriesNamesItsPatientStudyAndSource) {
  // The original: a series made from the sample; the derived one: that series posed (here: as it is).
  std::vector<std::string> original = *encode_derived_ct(sample_ct(), made_up_source(), {});
  Result<CtSeries> source = read_ct_series(original);
  ASSERT_TRUE(source.ok()) << source.status().to_string();
  DerivedSeriesOptions options;
  options.uid_root = "1.2.826.0.1.3680043.10.999";
  options.series_description = "posewarp: left hip flexed 30 (CoR)";
  options.derivation_description = "re-posed by posewarp from series " + source->info.series_instance_uid;
  SeriesInfo info;
  Result<std::vector<std::string>> derived = encode_derived_ct(source->ct, source->info, options, &info);
  ASSERT_TRUE(derived.ok()) << derived.status().to_string();
  const std::string& one = derived->front();
  EXPECT_EQ(text_of(one, DCM_StudyInstanceUID), source->info.study_instance_uid);
  EXPECT_EQ(text_of(one, DCM_PatientName), "Sample^Phantom");
  EXPECT_EQ(text_of(one, DCM_PatientID), "PW-0001");
  EXPECT_NE(text_of(one, DCM_SeriesInstanceUID), source->info.series_instance_uid);
  EXPECT_EQ(text_of(one, DCM_SeriesInstanceUID).rfind(options.uid_root + ".", 0), 0u);
  EXPECT_EQ(text_of(one, DCM_ImageType), "DERIVED\\SECONDARY\\AXIAL");
  EXPECT_EQ(text_of(one, DCM_SeriesDescription), options.series_description);
  EXPECT_EQ(text_of(one, DCM_DerivationDescription), options.derivation_description);
  EXPECT_EQ(text_of(one, DCM_SeriesNumber), std::to_string(std::stoi(source->info.series_number) + 1000));
  edited(one, [&](DcmDataset& d) {
    DcmItem* series = nullptr;
    ASSERT_TRUE(d.findAndGetSequenceItem(DCM_ReferencedSeriesSequence, series, 0).good());
    OFString uid;
    series->findAndGetOFString(DCM_SeriesInstanceUID, uid);
    EXPECT_EQ(std::string(uid.c_str()), source->info.series_instance_uid);
    DcmSequenceOfItems* images = nullptr;
    ASSERT_TRUE(d.findAndGetSequence(DCM_SourceImageSequence, images).good());
    EXPECT_EQ(images->card(), source->info.sop_instance_uids.size());
  });
  std::set<std::string> uids;
  for (const std::string& file : *derived) uids.insert(text_of(file, DCM_SOPInstanceUID));
  EXPECT_EQ(uids.size(), derived->size());
  EXPECT_EQ(info.sop_instance_uids.size(), derived->size());
}

TEST_F(DicomCt, TheSampleGoesThroughAnEnhancedCtAndBackExactlyWhateverItsFramesOrder) {
  const IntensityVolume ct = sample_ct();
  DerivedSeriesOptions options;
  options.ct_format = CtFormat::kEnhanced;
  SeriesInfo info;
  Result<std::vector<std::string>> written = encode_derived_ct(ct, made_up_source(), options, &info);
  ASSERT_TRUE(written.ok()) << written.status().to_string();
  ASSERT_EQ(written->size(), 1u);
  EXPECT_EQ(info.sop_instance_uids.size(), 1u);
  EXPECT_EQ(info.slice_count(), static_cast<size_t>(ct.size()[2]));
  EXPECT_EQ(text_of(written->front(), DCM_SOPClassUID), "1.2.840.10008.5.1.4.1.1.2.1");
  EXPECT_EQ(text_of(written->front(), DCM_NumberOfFrames), std::to_string(ct.size()[2]));
  Result<CtSeries> back = read_ct_series(*written);
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  expect_same_voxels(ct, back->ct);
  EXPECT_EQ(back->info.frame_numbers.front(), 1);
  EXPECT_EQ(back->info.patient_name, "Sample^Phantom");
  // The same image with its frames (their groups and their pixels) in reverse order reads as the same volume; the
  // info says which frame each slice is.
  const size_t frames = static_cast<size_t>(ct.size()[2]), per_frame = static_cast<size_t>(ct.size()[0] * ct.size()[1]);
  const std::string reversed = edited(written->front(), [&](DcmDataset& d) {
    DcmSequenceOfItems* groups = nullptr;
    ASSERT_TRUE(d.findAndGetSequence(DCM_PerFrameFunctionalGroupsSequence, groups).good());
    std::vector<DcmItem*> items;
    while (groups->card() > 0) items.push_back(groups->remove(0UL));
    for (auto it = items.rbegin(); it != items.rend(); ++it) groups->append(*it);
    const Uint16* words = nullptr;
    unsigned long count = 0;
    ASSERT_TRUE(d.findAndGetUint16Array(DCM_PixelData, words, &count).good());
    std::vector<Uint16> pixels(count);
    for (size_t f = 0; f < frames; ++f) {
      std::copy(words + f * per_frame, words + (f + 1) * per_frame, pixels.begin() + (frames - 1 - f) * per_frame);
    }
    d.putAndInsertUint16Array(DCM_PixelData, pixels.data(), count);
  });
  Result<CtSeries> shuffled = read_ct_series({reversed});
  ASSERT_TRUE(shuffled.ok()) << shuffled.status().to_string();
  expect_same_voxels(ct, shuffled->ct);
  EXPECT_EQ(shuffled->info.frame_numbers.front(), static_cast<int32_t>(frames));
  // A frame without its position is refused, by name.
  const std::string lost = edited(written->front(), [&](DcmDataset& d) {
    DcmItem* frame = nullptr;
    ASSERT_TRUE(d.findAndGetSequenceItem(DCM_PerFrameFunctionalGroupsSequence, frame, 4).good());
    frame->findAndDeleteElement(DCM_PlanePositionSequence);
  });
  Result<CtSeries> refused = read_ct_series({lost});
  ASSERT_FALSE(refused.ok());
  EXPECT_NE(refused.status().message().find("frame 5, lacks its position"), std::string::npos)
      << refused.status().message();
  // A multi-frame image in a series of other images is refused.
  std::vector<std::string> mixed = *encode_derived_ct(ct, made_up_source(), {});
  mixed.push_back(edited(written->front(), [&](DcmDataset& d) {
    d.putAndInsertString(DCM_SeriesInstanceUID, text_of(mixed.front(), DCM_SeriesInstanceUID).c_str());
  }));
  Result<CtSeries> both = read_ct_series(mixed);
  ASSERT_FALSE(both.ok());
  EXPECT_NE(both.status().message().find("some of them multi-frame"), std::string::npos) << both.status().message();
}

TEST_F(DicomCt, AnEnhancedCtNamesEverySourceImageOnceForAllFrames) {
  std::vector<std::string> original = *encode_derived_ct(sample_ct(), made_up_source(), {});
  Result<CtSeries> source = read_ct_series(original);
  ASSERT_TRUE(source.ok()) << source.status().to_string();
  DerivedSeriesOptions options;
  options.ct_format = CtFormat::kEnhanced;
  Result<std::vector<std::string>> derived = encode_derived_ct(source->ct, source->info, options);
  ASSERT_TRUE(derived.ok()) << derived.status().to_string();
  EXPECT_EQ(text_of(derived->front(), DCM_StudyInstanceUID), source->info.study_instance_uid);
  EXPECT_EQ(text_of(derived->front(), DCM_ImageType), "DERIVED\\PRIMARY\\VOLUME\\NONE");
  edited(derived->front(), [&](DcmDataset& d) {
    DcmItem* shared = nullptr;
    DcmItem* derivation = nullptr;
    DcmSequenceOfItems* images = nullptr;
    ASSERT_TRUE(d.findAndGetSequenceItem(DCM_SharedFunctionalGroupsSequence, shared, 0).good());
    ASSERT_TRUE(shared->findAndGetSequenceItem(DCM_DerivationImageSequence, derivation, 0).good());
    ASSERT_TRUE(derivation->findAndGetSequence(DCM_SourceImageSequence, images).good());
    EXPECT_EQ(images->card(), source->info.sop_instance_uids.size());
    DcmItem* evidence = nullptr;
    ASSERT_TRUE(d.findAndGetSequenceItem(DCM_SourceImageEvidenceSequence, evidence, 0).good());
    OFString study;
    evidence->findAndGetOFString(DCM_StudyInstanceUID, study);
    EXPECT_EQ(std::string(study.c_str()), source->info.study_instance_uid);
  });
}

TEST_F(DicomCt, InstancesInMemoryReadAsTheirDirectory) {
  const IntensityVolume ct = sample_ct();
  std::vector<std::string> files = *encode_derived_ct(ct, made_up_source(), {});
  // Shuffled (a PACS sends instances in any order), they still stack by position.
  std::reverse(files.begin(), files.end());
  std::swap(files[3], files[40]);
  Result<CtSeries> memory = read_ct_series(files);
  ASSERT_TRUE(memory.ok()) << memory.status().to_string();
  for (size_t i = 0; i < files.size(); ++i) {
    std::ofstream((dir_ / (std::to_string(i) + ".dcm")).string(), std::ios::binary) << files[i];
  }
  std::ofstream(dir_ / "README.txt") << "not DICOM";
  Result<CtSeries> directory = read_ct_directory(dir_.string());
  ASSERT_TRUE(directory.ok()) << directory.status().to_string();
  EXPECT_TRUE(memory->ct.geometry().same_grid(directory->ct.geometry(), 1e-9));
  EXPECT_EQ(memory->ct.voxels(), directory->ct.voxels());
}

TEST_F(DicomCt, TiltedGappyRepeatedMixedAndOtherSeriesAreRefusedWithAReason) {
  const std::vector<std::string> files = *encode_derived_ct(sample_ct(), made_up_source(), {});
  const auto refused = [](const std::vector<std::string>& instances, const std::string& says) {
    Result<CtSeries> r = read_ct_series(instances);
    ASSERT_FALSE(r.ok()) << "accepted a series that " << says;
    EXPECT_NE(r.status().message().find(says), std::string::npos) << r.status().message();
  };
  // A missing slice in the middle.
  std::vector<std::string> gappy = files;
  gappy.erase(gappy.begin() + 20);
  refused(gappy, "misses 1 slice");
  // Gantry tilt: each slice shifted along its rows by 0.5 mm more than the one before.
  std::vector<std::string> tilted;
  for (size_t k = 0; k < files.size(); ++k) {
    tilted.push_back(edited(files[k], [&](DcmDataset& d) {
      double p[3], o[6];
      for (unsigned long i = 0; i < 3; ++i) d.findAndGetFloat64(DCM_ImagePositionPatient, p[i], i);
      for (unsigned long i = 0; i < 6; ++i) d.findAndGetFloat64(DCM_ImageOrientationPatient, o[i], i);
      char value[128];
      std::snprintf(value, sizeof value, "%f\\%f\\%f", p[0] + 0.5 * static_cast<double>(k) * o[0],
                    p[1] + 0.5 * static_cast<double>(k) * o[1], p[2] + 0.5 * static_cast<double>(k) * o[2]);
      d.putAndInsertString(DCM_ImagePositionPatient, value);
    }));
  }
  refused(tilted, "tilted");
  // The same slice twice.
  std::vector<std::string> repeated = files;
  repeated.push_back(edited(files[10], [](DcmDataset& d) { d.putAndInsertString(DCM_SOPInstanceUID, "2.25.1"); }));
  refused(repeated, "same position");
  // Two series in one set of instances, without saying which.
  std::vector<std::string> mixed = files;
  const std::vector<std::string> other = *encode_derived_ct(sample_ct(), made_up_source(), {});
  mixed.insert(mixed.end(), other.begin(), other.end());
  refused(mixed, "hold 2 series");
  // Another modality; a damaged file.
  refused({edited(files[0], [](DcmDataset& d) { d.putAndInsertString(DCM_Modality, "MR"); })}, "modality 'MR'");
  refused({files[0].substr(0, 300)}, "not a readable DICOM file");
}

// A damaged length field (an element declaring more bytes than the file has) is refused before DCMTK allocates
// what it declares; the fuzzer's inputs (tests/fuzz/corpus/dicom) give a volume, a segmentation or an error.
TEST_F(DicomCt, ALengthBeyondTheFileIsRefusedBeforeItIsAllocated) {
  const std::vector<std::string> files = *encode_derived_ct(sample_ct(), made_up_source(), {});
  std::string damaged = files.front();
  const size_t at = damaged.find(std::string("\x10\x00\x10\x00PN", 6));  // Patient's Name, a 2-byte length
  ASSERT_NE(at, std::string::npos);
  damaged.replace(at + 4, 4, std::string("OB\0\0", 4));  // now an OB: 2 reserved bytes, a 4-byte length
  damaged.insert(at + 8, std::string("\xf0\xff\xff\xff", 4));
  Result<CtSeries> refused = read_ct_series({damaged});
  ASSERT_FALSE(refused.ok());
  EXPECT_EQ(refused.status().code(), StatusCode::kDataLoss);
  EXPECT_NE(refused.status().message().find("not a readable DICOM file"), std::string::npos)
      << refused.status().message();
  int inputs = 0;
  for (const auto& entry : fs::directory_iterator(std::string(POSEWARP_SOURCE_DIR) + "/tests/fuzz/corpus/dicom")) {
    std::ifstream in(entry.path(), std::ios::binary);
    const std::string bytes{std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
    if (bytes.empty()) continue;
    (void)read_ct_series({bytes.substr(1)});
    ImageGeometry grid;
    grid.size = {8, 6, 4};
    (void)read_segmentation(bytes.substr(1), grid);
    ++inputs;
  }
  EXPECT_GE(inputs, 7);
}

TEST_F(DicomCt, EachSlicesRescaleIsApplied) {
  const IntensityVolume ct = sample_ct();
  const std::vector<std::string> files = *encode_derived_ct(ct, made_up_source(), {});
  const CtSeries plain = *read_ct_series(files);
  std::vector<std::string> rescaled;
  for (const std::string& f : files) {
    rescaled.push_back(edited(f, [](DcmDataset& d) {
      d.putAndInsertString(DCM_RescaleSlope, "2");
      d.putAndInsertString(DCM_RescaleIntercept, "100");
    }));
  }
  Result<CtSeries> back = read_ct_series(rescaled);
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  for (size_t i = 0; i < plain.ct.voxels().size(); i += 97) {
    ASSERT_EQ(back->ct.voxels()[i], 2.0f * plain.ct.voxels()[i] + 100.0f);
  }
}

TEST(DicomUid, NewUidsAreValidAndUnderTheirRoot) {
  std::set<std::string> seen;
  for (int i = 0; i < 200; ++i) {
    const std::string uid = *new_uid("2.25");
    EXPECT_LE(uid.size(), 64u);
    EXPECT_EQ(uid.rfind("2.25.", 0), 0u);
    EXPECT_NE(uid[5], '0');
    EXPECT_EQ(uid.find_first_not_of("0123456789."), std::string::npos);
    seen.insert(uid);
  }
  EXPECT_EQ(seen.size(), 200u);
  EXPECT_EQ(new_uid("1.2.840.99999.1")->rfind("1.2.840.99999.1.", 0), 0u);
  // Seeded: the same seed and purpose give the same UID (a rewrite replaces instead of duplicating).
  DerivedSeriesOptions seeded;
  seeded.uid_seed = std::string(POSEWARP_SOURCE_DIR) + "/batch.json row 7";
  EXPECT_EQ(*uid_for(seeded, "ct/3"), *uid_for(seeded, "ct/3"));
  EXPECT_NE(*uid_for(seeded, "ct/3"), *uid_for(seeded, "ct/4"));
  EXPECT_EQ(uid_for(seeded, "ct/3")->rfind("2.25.", 0), 0u);
  EXPECT_LE(uid_for(seeded, "ct/3")->size(), 64u);
  DerivedSeriesOptions other;
  other.uid_seed = seeded.uid_seed + " again";
  EXPECT_NE(*uid_for(seeded, "ct/3"), *uid_for(other, "ct/3"));
  EXPECT_NE(*uid_for(DerivedSeriesOptions{}, "ct/3"), *uid_for(DerivedSeriesOptions{}, "ct/3"));
  for (const char* bad : {"", "1.02.3", "1..2", "1.2.", "abc", "1.2.3.4.5.6.7.8.9.10.11.12.13.14.15.16.17.18.19"}) {
    EXPECT_FALSE(new_uid(bad).ok()) << bad;
  }
}

// dicom3tools' dciodvfy checks a written slice against the CT Image IOD (skipped where it is not installed).
TEST_F(DicomCt, DciodvfyFindsNoErrorsInADerivedSlice) {
  if (std::system("command -v dciodvfy >/dev/null 2>&1") != 0)
    GTEST_SKIP() << "dciodvfy (dicom3tools) is not installed";
  // A derived series of a derived series: it references source instances, as one from a PACS does.
  const std::vector<std::string> original = *encode_derived_ct(sample_ct(), made_up_source(), {});
  const CtSeries source = *read_ct_series(original);
  ASSERT_TRUE(write_derived_ct(source.ct, source.info, {}, (dir_ / "series").string()).ok());
  const fs::path report = dir_ / "dciodvfy.txt";
  std::system(
      ("dciodvfy '" + (dir_ / "series" / "CT000010.dcm").string() + "' > '" + report.string() + "' 2>&1").c_str());
  std::ifstream in(report);
  std::string line, errors;
  while (std::getline(in, line)) {
    if (line.rfind("Error", 0) == 0) errors += line + "\n";
  }
  EXPECT_TRUE(errors.empty()) << errors;
}

}  // namespace
}  // namespace posewarp::dicom
