// DICOM SEG through DCMTK's dcmseg: frames placed on a CT grid by position, and labels written as binary frames.
#include "posewarp/dicom/segmentation.h"

#include <dcmtk/config/osconfig.h>  // before any other DCMTK header
#include <dcmtk/dcmdata/dcdeftag.h>
#include <dcmtk/dcmdata/dcfilefo.h>
#include <dcmtk/dcmdata/dcuid.h>
#include <dcmtk/dcmfg/fgderimg.h>
#include <dcmtk/dcmfg/fgfracon.h>
#include <dcmtk/dcmfg/fgpixmsr.h>
#include <dcmtk/dcmfg/fgplanor.h>
#include <dcmtk/dcmfg/fgplanpo.h>
#include <dcmtk/dcmfg/fgseg.h>
#include <dcmtk/dcmseg/segdoc.h>
#include <dcmtk/dcmseg/segment.h>
#include <dcmtk/dcmseg/segutils.h>

#include <algorithm>
#include <cmath>
#include <map>
#include <memory>
#include <set>

#include "part10.h"

namespace posewarp::dicom {
namespace {

using Vec = std::array<double, 3>;

std::string text(const OFString& s) {
  return s.c_str();
}

Code code_of(CodeSequenceMacro& code) {
  OFString value, scheme, meaning;
  code.getCodeValue(value);
  code.getCodingSchemeDesignator(scheme);
  code.getCodeMeaning(meaning);
  return {text(value), text(scheme), text(meaning)};
}

std::string format(const char* f, double a) {
  char out[64];
  std::snprintf(out, sizeof out, f, a);
  return out;
}

}  // namespace

Result<Segmentation> read_segmentation(const std::string& bytes, const ImageGeometry& grid) {
  quiet_dcmtk();
  POSEWARP_RETURN_IF_ERROR(grid.validate());
  POSEWARP_ASSIGN_OR_RETURN(const std::unique_ptr<DcmFileFormat> file, parse_part10(bytes, "the segmentation"));
  DcmDataset& d = *file->getDataset();
  OFString sop_class;
  d.findAndGetOFString(DCM_SOPClassUID, sop_class);
  if (sop_class != UID_SegmentationStorage) {
    return invalid_argument_error("the file is not a DICOM Segmentation (SOP class " + text(sop_class) + ")");
  }
  DcmSegmentation* loaded = nullptr;
  const OFCondition loading = DcmSegmentation::loadDataset(d, loaded);
  std::unique_ptr<DcmSegmentation> seg(loaded);
  if (loading.bad() || !seg)
    return invalid_argument_error(std::string("cannot read the segmentation: ") + loading.text());
  const bool binary = seg->getSegmentationType() == DcmSegTypes::ST_BINARY;
  if (!binary && seg->getSegmentationType() != DcmSegTypes::ST_FRACTIONAL) {
    return invalid_argument_error("the segmentation is neither BINARY nor FRACTIONAL");
  }
  Uint16 max_fraction = 255;
  d.findAndGetUint16(DCM_MaximumFractionalValue, max_fraction);
  Uint16 rows = 0, columns = 0;
  d.findAndGetUint16(DCM_Rows, rows);
  d.findAndGetUint16(DCM_Columns, columns);
  if (rows != grid.size[1] || columns != grid.size[0]) {
    return invalid_argument_error("the segmentation's frames are " + std::to_string(columns) + " x " +
                                  std::to_string(rows) + " pixels, the CT's slices " + std::to_string(grid.size[0]) +
                                  " x " + std::to_string(grid.size[1]) + ": it was not made on this CT");
  }
  Segmentation out;
  out.labels = LabelVolume(grid, 0);
  out.labels.set_source_type(PixelType::kUInt16);
  OFString uid;
  if (d.findAndGetOFString(DCM_SeriesInstanceUID, uid).good()) out.series_instance_uid = text(uid);
  DcmItem* referenced = nullptr;
  if (d.findAndGetSequenceItem(DCM_ReferencedSeriesSequence, referenced, 0).good() &&
      referenced->findAndGetOFString(DCM_SeriesInstanceUID, uid).good()) {
    out.referenced_series_uid = text(uid);
  }
  for (size_t n = 1; n <= seg->getNumberOfSegments(); ++n) {
    DcmSegment* s = seg->getSegment(n);
    if (s == nullptr) continue;
    Segment segment;
    segment.number = static_cast<int>(n);
    OFString value;
    if (s->getSegmentLabel(value).good()) segment.label = text(value);
    if (s->getSegmentDescription(value).good()) segment.description = text(value);
    segment.category = code_of(s->getSegmentedPropertyCategoryCode());
    segment.type = code_of(s->getSegmentedPropertyTypeCode());
    out.segments.push_back(segment);
  }
  // Each frame onto its slice: its orientation must be the grid's, its position one of the grid's slice origins, its
  // pixels the grid's size.
  FGInterface& groups = seg->getFunctionalGroups();
  if (auto* measures = static_cast<FGPixelMeasures*>(groups.get(0, DcmFGTypes::EFG_PIXELMEASURES))) {
    Float64 between_rows = 0, between_columns = 0;
    if (measures->getPixelSpacing(between_rows, 0).good() && measures->getPixelSpacing(between_columns, 1).good() &&
        (std::abs(between_rows - grid.spacing[1]) > 1e-3 || std::abs(between_columns - grid.spacing[0]) > 1e-3)) {
      return invalid_argument_error("the segmentation's pixel spacing (" + format("%.3f", between_columns) + " x " +
                                    format("%.3f", between_rows) + " mm) is not the CT's: it was not made on this CT");
    }
  }
  const Vec row{grid.direction[0], grid.direction[3], grid.direction[6]};
  const Vec column{grid.direction[1], grid.direction[4], grid.direction[7]};
  const size_t per_frame = static_cast<size_t>(rows) * columns;
  int64_t overlaps = 0, thresholded = 0;
  for (size_t f = 0; f < seg->getNumberOfFrames(); ++f) {
    const std::string name = "segmentation frame " + std::to_string(f + 1);
    auto* position =
        static_cast<FGPlanePosPatient*>(groups.get(static_cast<Uint32>(f), DcmFGTypes::EFG_PLANEPOSPATIENT));
    auto* orientation =
        static_cast<FGPlaneOrientationPatient*>(groups.get(static_cast<Uint32>(f), DcmFGTypes::EFG_PLANEORIENTPATIENT));
    auto* identification =
        static_cast<FGSegmentation*>(groups.get(static_cast<Uint32>(f), DcmFGTypes::EFG_SEGMENTATION));
    Float64 x = 0, y = 0, z = 0;
    Uint16 number = 0;
    if (position == nullptr || identification == nullptr || position->getImagePositionPatient(x, y, z).bad() ||
        identification->getReferencedSegmentNumber(number).bad() || number == 0) {
      return invalid_argument_error(name + " has no position or segment number");
    }
    if (orientation == nullptr) return invalid_argument_error(name + " has no orientation");
    {
      Float64 o[6];
      for (int i = 0; i < 6; ++i) {
        OFString component;
        orientation->getImageOrientationPatient(component, i);
        o[i] = std::atof(component.c_str());
      }
      for (int i = 0; i < 3; ++i) {
        if (std::abs(o[i] - row[static_cast<size_t>(i)]) > 1e-3 ||
            std::abs(o[i + 3] - column[static_cast<size_t>(i)]) > 1e-3) {
          return invalid_argument_error(name + " is not oriented as the CT's slices: it was not made on this CT");
        }
      }
    }
    const Vec3 index = grid.physical_to_index({x, y, z});
    const double k = std::round(index[2]);
    if (std::abs(index[0]) > 0.01 || std::abs(index[1]) > 0.01 || std::abs(index[2] - k) > 0.01 || k < 0 ||
        k >= static_cast<double>(grid.size[2])) {
      return invalid_argument_error(name + " lies off the CT's slices (at " + format("%.2f", x) + ", " +
                                    format("%.2f", y) + ", " + format("%.2f", z) +
                                    " mm): it was not made on this CT's grid");
    }
    const DcmIODTypes::Frame* frame = seg->getFrame(f);
    if (frame == nullptr) return data_loss_error(name + " has no pixel data");
    std::unique_ptr<DcmIODTypes::Frame> unpacked;
    if (binary) {
      unpacked.reset(DcmSegUtils::unpackBinaryFrame(frame, rows, columns));
      if (!unpacked) return data_loss_error(name + " has less pixel data than its rows x columns");
      frame = unpacked.get();
    }
    if (frame->length < per_frame) return data_loss_error(name + " has less pixel data than its rows x columns");
    Label* slice = out.labels.data() + static_cast<size_t>(k) * per_frame;
    for (size_t i = 0; i < per_frame; ++i) {
      const Uint8 v = frame->pixData[i];
      bool set = v != 0;
      if (!binary) {
        set = 2.0 * v >= max_fraction;
        thresholded += v != 0 && static_cast<int>(v) != max_fraction;
      }
      if (!set) continue;
      if (slice[i] != 0 && slice[i] != number) ++overlaps;
      slice[i] = std::max<Label>(slice[i], number);
    }
  }
  if (thresholded > 0) {
    out.warnings.push_back("fractional segmentation: " + std::to_string(thresholded) +
                           " voxels with partial values were thresholded at one half");
  }
  if (overlaps > 0) {
    out.warnings.push_back(std::to_string(overlaps) +
                           " voxels belong to more than one segment; each took the "
                           "highest-numbered one");
  }
  return out;
}

Result<std::string> encode_segmentation(const LabelVolume& labels, const std::vector<Segment>& segments,
                                        const SeriesInfo& ct, const DerivedSeriesOptions& options, SeriesInfo* info_out,
                                        std::map<Label, int>* numbers) {
  quiet_dcmtk();
  const ImageGeometry& g = labels.geometry();
  POSEWARP_RETURN_IF_ERROR(g.validate());
  if (ct.sop_instance_uids.size() != static_cast<size_t>(g.size[2])) {
    return invalid_argument_error("the labels have " + std::to_string(g.size[2]) + " slices and the CT series " +
                                  std::to_string(ct.sop_instance_uids.size()) +
                                  " images: the SEG must be on the CT's grid");
  }
  if (g.size[0] > 65535 || g.size[1] > 65535)
    return invalid_argument_error("a SEG frame has at most 65535 rows and columns");
  std::map<Label, int64_t> present;
  for (Label v : labels.voxels()) {
    if (v != 0) ++present[v];
  }
  if (present.empty()) return invalid_argument_error("the labels are all 0: a SEG needs at least one segment");
  if (present.begin()->first < 0 || present.rbegin()->first > 65535) {
    return invalid_argument_error("label values must be 1..65535 to be segment numbers");
  }
  IODGeneralEquipmentModule::EquipmentInfo equipment("posewarp", "posewarp", "0", "1");
  ContentIdentificationMacro content(
      "1", "POSEWARP", options.series_description.empty() ? "posed labels" : options.series_description, "posewarp");
  DcmSegmentation* created = nullptr;
  OFCondition ok = DcmSegmentation::createBinarySegmentation(created, static_cast<Uint16>(g.size[1]),
                                                             static_cast<Uint16>(g.size[0]), equipment, content);
  std::unique_ptr<DcmSegmentation> seg(created);
  if (ok.bad() || !seg) return internal_error(std::string("cannot create a segmentation: ") + ok.text());
  SeriesInfo info = ct;
  POSEWARP_ASSIGN_OR_RETURN(info.series_instance_uid, uid_for(options, "seg-series"));
  std::string sop_uid;
  POSEWARP_ASSIGN_OR_RETURN(sop_uid, uid_for(options, "seg"));
  info.modality = "SEG";
  info.sop_class_uid = UID_SegmentationStorage;
  info.sop_instance_uids = {sop_uid};
  info.series_number =
      std::to_string(options.series_number > 0 ? options.series_number : std::atoi(ct.series_number.c_str()) + 1);
  info.series_description = options.series_description.empty() ? "posewarp labels" : options.series_description;
  seg->getPatient().setPatientName(ct.patient_name.c_str(), OFFalse);
  seg->getPatient().setPatientID(ct.patient_id.c_str(), OFFalse);
  seg->getPatient().setPatientBirthDate(ct.patient_birth_date.c_str(), OFFalse);
  seg->getPatient().setPatientSex(ct.patient_sex.c_str(), OFFalse);
  seg->getStudy().setStudyInstanceUID(ct.study_instance_uid.c_str(), OFFalse);
  seg->getStudy().setStudyDate(ct.study_date.c_str(), OFFalse);
  seg->getStudy().setStudyTime(ct.study_time.c_str(), OFFalse);
  seg->getStudy().setStudyID(ct.study_id.c_str(), OFFalse);
  seg->getStudy().setAccessionNumber(ct.accession_number.c_str(), OFFalse);
  seg->getStudy().setReferringPhysicianName(ct.referring_physician_name.c_str(), OFFalse);
  seg->getFrameOfReference().setFrameOfReferenceUID(ct.frame_of_reference_uid.c_str(), OFFalse);
  seg->getSeries().setSeriesInstanceUID(info.series_instance_uid.c_str(), OFFalse);
  seg->getSeries().setSeriesNumber(info.series_number.c_str(), OFFalse);
  seg->getSeries().setSeriesDescription(info.series_description.c_str(), OFFalse);
  seg->getSOPCommon().setSOPInstanceUID(sop_uid.c_str(), OFFalse);
  if (!ct.specific_character_set.empty())
    seg->getSOPCommon().setSpecificCharacterSet(ct.specific_character_set.c_str(), OFFalse);
  // Shared: the CT's pixel spacing and orientation.
  FGPixelMeasures measures;
  measures.setPixelSpacing((format("%.6f", g.spacing[1]) + "\\" + format("%.6f", g.spacing[0])).c_str());
  measures.setSliceThickness(format("%.6f", g.spacing[2]).c_str());
  FGPlaneOrientationPatient orientation;
  orientation.setImageOrientationPatient(format("%.6f", g.direction[0]).c_str(), format("%.6f", g.direction[3]).c_str(),
                                         format("%.6f", g.direction[6]).c_str(), format("%.6f", g.direction[1]).c_str(),
                                         format("%.6f", g.direction[4]).c_str(),
                                         format("%.6f", g.direction[7]).c_str());
  if (seg->addForAllFrames(measures).bad() || seg->addForAllFrames(orientation).bad()) {
    return internal_error("cannot set the segmentation's shared geometry");
  }
  // Segments: one per label value present, in value order; DICOM numbers segments 1, 2, 3, ..., so values that
  // skip are renumbered (`numbers` says how; the segment's label keeps the name).
  std::map<int, const Segment*> described;
  for (const Segment& s : segments) described[s.number] = &s;
  std::map<Label, Uint16> number_of;
  for (const auto& [value, count] : present) {
    const auto d = described.find(value);
    const Segment* given = d == described.end() ? nullptr : d->second;
    const std::string label = given && !given->label.empty() ? given->label : "label " + std::to_string(value);
    const Code category = given && !given->category.value.empty() ? given->category : Code{"85756007", "SCT", "Tissue"};
    const Code type = given && !given->type.value.empty() ? given->type : Code{"85756007", "SCT", "Tissue"};
    DcmSegment* segment = nullptr;
    ok =
        DcmSegment::create(segment, label.c_str(),
                           CodeSequenceMacro(category.value.c_str(), category.scheme.c_str(), category.meaning.c_str()),
                           CodeSequenceMacro(type.value.c_str(), type.scheme.c_str(), type.meaning.c_str()),
                           DcmSegTypes::SAT_AUTOMATIC, "posewarp");
    if (ok.bad() || segment == nullptr) return internal_error("cannot describe segment '" + label + "': " + ok.text());
    if (given && !given->description.empty()) segment->setSegmentDescription(given->description.c_str(), OFFalse);
    Uint16 number = 0;
    if (seg->addSegment(segment, number).bad()) {
      delete segment;
      return internal_error("cannot add segment '" + label + "'");
    }
    number_of[value] = number;
  }
  // Frames: per segment, each slice it appears on, referencing that CT slice.
  const Vec row{g.direction[0], g.direction[3], g.direction[6]}, column{g.direction[1], g.direction[4], g.direction[7]};
  const Vec axis{g.direction[2], g.direction[5], g.direction[8]};
  const Vec normal{row[1] * column[2] - row[2] * column[1], row[2] * column[0] - row[0] * column[2],
                   row[0] * column[1] - row[1] * column[0]};
  const bool reverse = normal[0] * axis[0] + normal[1] * axis[1] + normal[2] * axis[2] < 0;  // as the CT was written
  const size_t per_frame = static_cast<size_t>(g.size[0] * g.size[1]);
  std::vector<Uint8> pixels(per_frame);
  FGSegmentation identification;
  std::vector<std::unique_ptr<FGDerivationImage>> derivations(static_cast<size_t>(g.size[2]));
  FGFrameContent content_fg;
  FGPlanePosPatient position;
  // The slices each label appears on, in one pass over the volume.
  std::map<Label, std::vector<int64_t>> slices_of;
  for (int64_t k = 0; k < g.size[2]; ++k) {
    std::set<Label> here(labels.data() + static_cast<size_t>(k) * per_frame,
                         labels.data() + static_cast<size_t>(k + 1) * per_frame);
    for (Label v : here) {
      if (v != 0) slices_of[v].push_back(k);
    }
  }
  for (const auto& [value, number] : number_of) {
    for (const int64_t k : slices_of[value]) {
      const Label* slice = labels.data() + static_cast<size_t>(k) * per_frame;
      for (size_t i = 0; i < per_frame; ++i) pixels[i] = slice[i] == value ? 1 : 0;
      const double offset = static_cast<double>(k) * g.spacing[2];
      position.setImagePositionPatient(format("%.6f", g.origin[0] + offset * axis[0]).c_str(),
                                       format("%.6f", g.origin[1] + offset * axis[1]).c_str(),
                                       format("%.6f", g.origin[2] + offset * axis[2]).c_str());
      identification.setReferencedSegmentNumber(number);
      content_fg.setDimensionIndexValues(number, 0);
      content_fg.setDimensionIndexValues(static_cast<Uint32>((reverse ? g.size[2] - 1 - k : k) + 1), 1);
      // The CT slice this frame derives from: one functional group per slice, made once and shared by its frames.
      const size_t ct_index = static_cast<size_t>(reverse ? g.size[2] - 1 - k : k);
      std::unique_ptr<FGDerivationImage>& derivation = derivations[ct_index];
      if (!derivation) {
        OFVector<ImageSOPInstanceReferenceMacro> sources(1);
        sources[0].setReferencedSOPClassUID(ct.sop_class_uid.empty() ? UID_CTImageStorage : ct.sop_class_uid.c_str());
        sources[0].setReferencedSOPInstanceUID(ct.sop_instance_uids[ct_index].c_str());
        derivation.reset(DcmSegmentation::createDerivationImageFG(sources, "posewarp posed labels"));
      }
      OFVector<FGBase*> per_frame_groups{&identification, &content_fg, &position};
      if (derivation) per_frame_groups.push_back(derivation.get());
      ok = seg->addFrame(pixels.data(), number, per_frame_groups);
      if (ok.bad()) return internal_error("cannot add a segmentation frame: " + std::string(ok.text()));
    }
  }
  std::string dimension_uid;
  POSEWARP_ASSIGN_OR_RETURN(dimension_uid, uid_for(options, "seg-dimensions"));
  IODMultiframeDimensionModule& dimensions = seg->getDimensions();
  dimensions.addDimensionIndex(DCM_ReferencedSegmentNumber, dimension_uid.c_str(), DCM_SegmentIdentificationSequence,
                               "ReferencedSegmentNumber");
  dimensions.addDimensionIndex(DCM_ImagePositionPatient, dimension_uid.c_str(), DCM_PlanePositionSequence,
                               "ImagePositionPatient");
  // DCMTK's check of the functional groups compares every frame's groups with every other's (0.4 s of the sample's
  // 2068 frames, most of a SEG's encoding). The groups are made above, shared where they are the same, and the
  // tests read back what is written and run dciodvfy on it.
  seg->setCheckFGOnWrite(OFFalse);
  dimensions.setCheckOnWrite(OFFalse);
  // The CT series it belongs to (Common Instance Reference).
  DcmFileFormat file;
  ok = seg->writeDataset(*file.getDataset());
  if (ok.bad()) return internal_error(std::string("cannot write the segmentation: ") + ok.text());
  DcmDataset& d = *file.getDataset();
  d.findAndDeleteElement(DCM_ReferencedSeriesSequence);
  DcmItem* series_item = nullptr;
  if (d.findOrCreateSequenceItem(DCM_ReferencedSeriesSequence, series_item, -2).good()) {
    series_item->putAndInsertString(DCM_SeriesInstanceUID, ct.series_instance_uid.c_str());
    for (const std::string& uid : ct.sop_instance_uids) {
      DcmItem* item = nullptr;
      if (series_item->findOrCreateSequenceItem(DCM_ReferencedInstanceSequence, item, -2).good()) {
        item->putAndInsertString(DCM_ReferencedSOPClassUID,
                                 ct.sop_class_uid.empty() ? UID_CTImageStorage : ct.sop_class_uid.c_str());
        item->putAndInsertString(DCM_ReferencedSOPInstanceUID, uid.c_str());
      }
    }
  }
  std::string bytes;
  POSEWARP_ASSIGN_OR_RETURN(bytes, encode_part10(file, "the segmentation"));
  if (info_out != nullptr) *info_out = info;
  if (numbers != nullptr) numbers->insert(number_of.begin(), number_of.end());
  return bytes;
}

}  // namespace posewarp::dicom
