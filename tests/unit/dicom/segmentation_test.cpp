// DICOM SEG: the sample's labels through a SEG on its derived CT series and back (voxels, names, codes), dciodvfy's
// verdict, a fractional SEG thresholded at one half, and SEGs that do not belong to the grid refused.
#include <dcmtk/config/osconfig.h>
#include <dcmtk/dcmdata/dcdeftag.h>
#include <dcmtk/dcmdata/dcfilefo.h>
#include <dcmtk/dcmdata/dcistrmb.h>
#include <dcmtk/dcmdata/dcostrmb.h>
#include <dcmtk/dcmdata/dcsequen.h>
#include <dcmtk/dcmfg/fgfracon.h>
#include <dcmtk/dcmfg/fgpixmsr.h>
#include <dcmtk/dcmfg/fgplanor.h>
#include <dcmtk/dcmfg/fgplanpo.h>
#include <dcmtk/dcmfg/fgseg.h>
#include <dcmtk/dcmseg/segdoc.h>
#include <dcmtk/dcmseg/segment.h>
#include <gtest/gtest.h>

#include <cmath>
#include <filesystem>
#include <fstream>
#include <memory>

#include "dataset_edit.h"
#include "made_up_source.h"
#include "posewarp/dicom/segmentation.h"
#include "posewarp/io/volume_io.h"

namespace posewarp::dicom {
namespace {

namespace fs = std::filesystem;

struct Written {
  LabelVolume labels;
  CtSeries ct;  // as read back from its DICOM files
  std::string seg;
  std::map<Label, int> numbers;
};

// `slices` slices of `v` from slice `first`, on their place in the patient.
template <typename T>
Volume<T> slab(const Volume<T>& v, int64_t first, int64_t slices) {
  ImageGeometry g = v.geometry();
  for (size_t r = 0; r < 3; ++r) {
    g.origin[r] += static_cast<double>(first) * g.spacing[2] * g.direction[3 * r + 2];
  }
  g.size[2] = slices;
  Volume<T> out(g);
  const size_t per_slice = static_cast<size_t>(g.size[0] * g.size[1]);
  std::copy(v.data() + static_cast<size_t>(first) * per_slice,
            v.data() + static_cast<size_t>(first + slices) * per_slice, out.data());
  return out;
}

// The sample's labels as a SEG on the sample's CT written as DICOM, in the formats `formats` names; `slices` > 0:
// that many slices from the middle of the sample only.
Written sample_seg(const std::vector<Segment>& described = {}, const DerivedSeriesOptions& formats = {},
                   int64_t slices = 0) {
  const std::string dir = POSEWARP_SAMPLE_DIR;
  Written w;
  IntensityVolume ct = *io::read_intensity_volume(dir + "/ct.nii.gz");
  w.labels = *io::read_label_volume(dir + "/seg_total.nii.gz");
  if (slices > 0) {
    const int64_t first = (ct.size()[2] - slices) / 2;
    ct = slab(ct, first, slices);
    w.labels = slab(w.labels, first, slices);
  }
  SeriesInfo info;
  const std::vector<std::string> files = *encode_derived_ct(ct, made_up_source(), formats, &info);
  w.ct = *read_ct_series(files);
  Result<std::string> seg = encode_segmentation(w.labels, described, info, formats, nullptr, &w.numbers);
  EXPECT_TRUE(seg.ok()) << seg.status().to_string();
  if (seg.ok()) w.seg = *seg;
  return w;
}

const Segment* segment_numbered(const std::vector<Segment>& segments, int number) {
  for (const Segment& s : segments) {
    if (s.number == number) return &s;
  }
  return nullptr;
}

// Every format pair: the CT as a series or one Enhanced CT, the labels as a binary or a label map SEG.
class DicomSegFormats : public ::testing::TestWithParam<std::pair<CtFormat, SegFormat>> {
 protected:
  DerivedSeriesOptions formats() const {
    DerivedSeriesOptions options;
    options.ct_format = GetParam().first;
    options.seg_format = GetParam().second;
    return options;
  }
};

TEST_P(DicomSegFormats, TheSampleLabelsGoThroughASegAndBack) {
  std::vector<Segment> described(1);
  described[0].number = 2;  // the sample's kidney_right (labels_total.tsv)
  described[0].label = "kidney_right";
  described[0].description = "right kidney";
  described[0].type = {"64033007", "SCT", "Kidney"};
  described[0].category = {"123037004", "SCT", "Anatomical Structure"};
  const Written w = sample_seg(described, formats());
  ASSERT_FALSE(w.seg.empty());
  Result<Segmentation> back = read_segmentation(w.seg, w.ct.ct.geometry());
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  EXPECT_EQ(back->segments.size(), w.numbers.size());
  EXPECT_TRUE(back->warnings.empty());
  if (GetParam().second == SegFormat::kLabelMap) {
    // A label map numbers its segments by their values: the numbers are the labels.
    for (const auto& [value, number] : w.numbers) EXPECT_EQ(value, number);
  }
  // Every voxel: the segment number of its label (the CT's grid may run its slices the other way).
  const ImageGeometry &a = w.labels.geometry(), &b = back->labels.geometry();
  int64_t labelled = 0;
  for (int64_t k = 0; k < b.size[2]; ++k) {
    for (int64_t j = 0; j < b.size[1]; ++j) {
      for (int64_t i = 0; i < b.size[0]; ++i) {
        const Vec3 at = a.physical_to_index(
            b.index_to_physical({static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)}));
        const Label original = w.labels.at(std::lround(at[0]), std::lround(at[1]), std::lround(at[2]));
        const Label expected = original == 0 ? 0 : w.numbers.at(original);
        ASSERT_EQ(back->labels.at(i, j, k), expected) << "at " << i << ", " << j << ", " << k;
        labelled += original != 0;
      }
    }
  }
  EXPECT_GT(labelled, 10000);
  // The described segment keeps its name, description and codes; the others are named by their value.
  const Segment* kidney = segment_numbered(back->segments, w.numbers.at(2));
  ASSERT_NE(kidney, nullptr);
  EXPECT_EQ(kidney->label, "kidney_right");
  EXPECT_EQ(kidney->description, "right kidney");
  EXPECT_EQ(kidney->type.value, "64033007");
  EXPECT_EQ(kidney->type.meaning, "Kidney");
  EXPECT_EQ(kidney->category.scheme, "SCT");
  ASSERT_NE(segment_numbered(back->segments, w.numbers.at(1)), nullptr);
  EXPECT_EQ(segment_numbered(back->segments, w.numbers.at(1))->label, "label 1");
  EXPECT_EQ(back->referenced_series_uid, w.ct.info.series_instance_uid);
}

// dicom3tools' dciodvfy (2022) knows the binary SEG and the Enhanced CT, not yet the label map SEG (Supplement 243,
// 2024), which the independent readers check instead (tests/dicom). Twelve slices of the sample: dciodvfy takes 20 s
// over the whole sample's binary SEG.
TEST_P(DicomSegFormats, DciodvfyFindsNoErrorsWhereItKnowsTheObject) {
  if (std::system("command -v dciodvfy >/dev/null 2>&1") != 0)
    GTEST_SKIP() << "dciodvfy (dicom3tools) is not installed";
  if (GetParam() == std::pair{CtFormat::kSeries, SegFormat::kLabelMap}) {
    GTEST_SKIP() << "a label map SEG on a CT series: dciodvfy knows neither new object (the series: DicomCt.*)";
  }
  const Written w = sample_seg({}, formats(), 12);
  const fs::path dir = fs::temp_directory_path() / ("posewarp-seg-" + std::to_string(::getpid()));
  fs::create_directories(dir);
  std::vector<std::pair<std::string, std::string>> objects;  // name, bytes
  if (GetParam().second == SegFormat::kBinary) objects.emplace_back("seg", w.seg);
  if (GetParam().first == CtFormat::kEnhanced) {
    objects.emplace_back("enhanced-ct", encode_derived_ct(w.ct.ct, w.ct.info, formats())->front());
  }
  for (const auto& [name, bytes] : objects) {
    const fs::path file = dir / (name + ".dcm"), report = dir / (name + ".txt");
    std::ofstream(file, std::ios::binary) << bytes;
    std::system(("dciodvfy '" + file.string() + "' > '" + report.string() + "' 2>&1").c_str());
    std::ifstream in(report);
    std::string line, errors, all;
    while (std::getline(in, line)) {
      all += line + "\n";
      if (line.rfind("Error", 0) == 0) errors += line + "\n";
    }
    EXPECT_TRUE(errors.empty()) << name << ":\n" << errors;
    EXPECT_NE(all.find(name == "seg" ? "Segmentation" : "EnhancedCTImage"), std::string::npos) << all;
  }
  fs::remove_all(dir);
}

INSTANTIATE_TEST_SUITE_P(AllFormats, DicomSegFormats,
                         ::testing::Values(std::pair{CtFormat::kSeries, SegFormat::kBinary},
                                           std::pair{CtFormat::kSeries, SegFormat::kLabelMap},
                                           std::pair{CtFormat::kEnhanced, SegFormat::kBinary},
                                           std::pair{CtFormat::kEnhanced, SegFormat::kLabelMap}),
                         [](const ::testing::TestParamInfo<std::pair<CtFormat, SegFormat>>& param_info) {
                           return std::string(param_info.param.first == CtFormat::kSeries ? "Series" : "EnhancedCt") +
                                  (param_info.param.second == SegFormat::kBinary ? "BinarySeg" : "LabelMapSeg");
                         });

TEST(DicomSeg, SegsOfAnotherGridOrNotSegsAreRefused) {
  for (const SegFormat format : {SegFormat::kBinary, SegFormat::kLabelMap}) {
    DerivedSeriesOptions options;
    options.seg_format = format;
    const Written w = sample_seg({}, options);
    ImageGeometry shifted = w.ct.ct.geometry();
    shifted.origin[2] += 0.5 * shifted.spacing[2];
    Result<Segmentation> off = read_segmentation(w.seg, shifted);
    ASSERT_FALSE(off.ok());
    EXPECT_NE(off.status().message().find("not made on this CT"), std::string::npos) << off.status().message();
    ImageGeometry smaller = w.ct.ct.geometry();
    smaller.size[0] -= 1;
    EXPECT_FALSE(read_segmentation(w.seg, smaller).ok());
    ImageGeometry finer = w.ct.ct.geometry();
    finer.spacing[0] *= 0.5;
    Result<Segmentation> spacing = read_segmentation(w.seg, finer);
    ASSERT_FALSE(spacing.ok());
    EXPECT_NE(spacing.status().message().find("pixel spacing"), std::string::npos) << spacing.status().message();
  }
  const Written w = sample_seg();
  const std::vector<std::string> ct = *encode_derived_ct(w.ct.ct, w.ct.info, {});
  Result<Segmentation> not_seg = read_segmentation(ct.front(), w.ct.ct.geometry());
  ASSERT_FALSE(not_seg.ok());
  EXPECT_NE(not_seg.status().message().find("not a DICOM Segmentation"), std::string::npos);
  EXPECT_FALSE(read_segmentation("not dicom at all", w.ct.ct.geometry()).ok());
}

// A label map whose pixels hold a number that no segment describes is damaged, not background.
TEST(DicomSeg, ALabelMapPixelOfNoSegmentIsDataLoss) {
  DerivedSeriesOptions options;
  options.seg_format = SegFormat::kLabelMap;
  const Written w = sample_seg({}, options);
  const std::string bytes = edited(w.seg, [](DcmDataset& d) {
    DcmSequenceOfItems* segments = nullptr;
    ASSERT_TRUE(d.findAndGetSequence(DCM_SegmentSequence, segments).good());
    delete segments->remove(0UL);  // the first segment, label 1 (spleen)
  });
  Result<Segmentation> read = read_segmentation(bytes, w.ct.ct.geometry());
  ASSERT_FALSE(read.ok());
  EXPECT_EQ(read.status().code(), StatusCode::kDataLoss);
  EXPECT_NE(read.status().message().find("the value 1, which no segment"), std::string::npos)
      << read.status().message();
}

// A fractional SEG made with DCMTK itself: 4 x 4 pixels, one frame at the grid's first slice, values 0, 100, 200,
// 255 of 255: only the values of at least one half are the segment.
TEST(DicomSeg, AFractionalSegIsThresholdedAtOneHalfWithAWarning) {
  IODGeneralEquipmentModule::EquipmentInfo equipment("test", "test", "0", "1");
  ContentIdentificationMacro content("1", "TEST", "fractional", "test");
  DcmSegmentation* created = nullptr;
  ASSERT_TRUE(DcmSegmentation::createFractionalSegmentation(created, 4, 4, DcmSegTypes::SFT_PROBABILITY, 255, equipment,
                                                            content)
                  .good());
  std::unique_ptr<DcmSegmentation> seg(created);
  seg->getPatient().setPatientID("X");
  seg->getStudy().setStudyInstanceUID(new_uid("2.25")->c_str());
  seg->getFrameOfReference().setFrameOfReferenceUID(new_uid("2.25")->c_str());
  seg->getSeries().setSeriesInstanceUID(new_uid("2.25")->c_str());
  seg->getSeries().setSeriesNumber("1");
  FGPixelMeasures measures;
  measures.setPixelSpacing("1\\1");
  measures.setSliceThickness("1");
  FGPlaneOrientationPatient orientation;
  orientation.setImageOrientationPatient("1", "0", "0", "0", "1", "0");
  ASSERT_TRUE(seg->addForAllFrames(measures).good());
  ASSERT_TRUE(seg->addForAllFrames(orientation).good());
  DcmSegment* segment = nullptr;
  ASSERT_TRUE(DcmSegment::create(segment, "liver", CodeSequenceMacro("123037004", "SCT", "Anatomical Structure"),
                                 CodeSequenceMacro("10200004", "SCT", "Liver"), DcmSegTypes::SAT_AUTOMATIC, "test")
                  .good());
  Uint16 number = 0;
  ASSERT_TRUE(seg->addSegment(segment, number).good());
  FGSegmentation identification;
  identification.setReferencedSegmentNumber(number);
  FGPlanePosPatient position;
  position.setImagePositionPatient("0", "0", "0");
  FGFrameContent frame_content;
  frame_content.setDimensionIndexValues(1, 0);
  frame_content.setDimensionIndexValues(1, 1);
  Uint8 pixels[16] = {0, 100, 200, 255, 0, 0, 0, 0, 128, 127, 0, 0, 0, 0, 0, 255};
  OFVector<FGBase*> groups{&identification, &position, &frame_content};
  ASSERT_TRUE(seg->addFrame(pixels, number, groups).good());
  const std::string uid = *new_uid("2.25");
  seg->getDimensions().addDimensionIndex(DCM_ReferencedSegmentNumber, uid.c_str(), DCM_SegmentIdentificationSequence,
                                         "segment");
  seg->getDimensions().addDimensionIndex(DCM_ImagePositionPatient, uid.c_str(), DCM_PlanePositionSequence, "position");
  DcmFileFormat file;
  const OFCondition wrote = seg->writeDataset(*file.getDataset());
  ASSERT_TRUE(wrote.good()) << wrote.text();
  const std::string bytes = part10_bytes(file, 1 << 20);

  ImageGeometry grid;
  grid.size = {4, 4, 2};
  Result<Segmentation> read = read_segmentation(bytes, grid);
  ASSERT_TRUE(read.ok()) << read.status().to_string();
  const std::vector<Label> expected{0, 0, 1, 1, 0, 0, 0, 0, 1, 0, 0, 0, 0, 0, 0, 1};
  EXPECT_EQ(std::vector<Label>(read->labels.voxels().begin(), read->labels.voxels().begin() + 16), expected);
  EXPECT_EQ(read->labels.at(0, 0, 1), 0);
  ASSERT_EQ(read->warnings.size(), 1u);
  EXPECT_NE(read->warnings[0].find("thresholded at one half"), std::string::npos);
  ASSERT_EQ(read->segments.size(), 1u);
  EXPECT_EQ(read->segments[0].label, "liver");
  EXPECT_EQ(read->segments[0].type.meaning, "Liver");
}

}  // namespace
}  // namespace posewarp::dicom
