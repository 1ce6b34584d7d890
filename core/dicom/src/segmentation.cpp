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

#include "label_map_segmentation.h"
#include "multiframe.h"
#include "part10.h"

namespace posewarp::dicom {
namespace {

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

// Per label value: its voxel count (LabelCounts), its DICOM segment number (SegmentNumbers).
using LabelCounts = std::map<Label, int64_t>;
using SegmentNumbers = std::map<Label, Uint16>;

// How a SEG's frames hold their pixels.
struct FrameLayout {
  bool binary = true;
  Uint16 max_fraction = 255;
  Uint16 rows = 0, columns = 0;
};

// One frame of a SEG and where it goes on the grid.
struct SegFrame {
  size_t index = 0;
  std::string name;   // for messages
  size_t slice = 0;   // the grid's slice it lies on
  Uint16 number = 0;  // its segment
};

// Voxels that needed a decision while frames were painted, for the warnings.
struct PaintCounts {
  int64_t overlaps = 0, thresholded = 0;
};

// The SEG that `d` holds, loaded by dcmseg; an error when `d` is not one.
Result<std::unique_ptr<DcmSegmentation>> load_segmentation(DcmDataset& d) {
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
  return seg;
}

// The frames' type and size; an error when they are not the size of the grid's slices.
Result<FrameLayout> frame_layout(DcmDataset& d, DcmSegmentation& seg, const ImageGeometry& grid) {
  FrameLayout layout;
  layout.binary = seg.getSegmentationType() == DcmSegTypes::ST_BINARY;
  if (!layout.binary && seg.getSegmentationType() != DcmSegTypes::ST_FRACTIONAL) {
    return invalid_argument_error("the segmentation is neither BINARY nor FRACTIONAL");
  }
  d.findAndGetUint16(DCM_MaximumFractionalValue, layout.max_fraction);
  d.findAndGetUint16(DCM_Rows, layout.rows);
  d.findAndGetUint16(DCM_Columns, layout.columns);
  if (layout.rows != grid.size[1] || layout.columns != grid.size[0]) {
    return invalid_argument_error("the segmentation's frames are " + std::to_string(layout.columns) + " x " +
                                  std::to_string(layout.rows) + " pixels, the CT's slices " +
                                  std::to_string(grid.size[0]) + " x " + std::to_string(grid.size[1]) +
                                  ": it was not made on this CT");
  }
  return layout;
}

// The SEG's own series UID and the CT series it references, where it names them.
void read_series_uids(DcmDataset& d, Segmentation* out) {
  OFString uid;
  if (d.findAndGetOFString(DCM_SeriesInstanceUID, uid).good()) out->series_instance_uid = text(uid);
  DcmItem* referenced = nullptr;
  if (d.findAndGetSequenceItem(DCM_ReferencedSeriesSequence, referenced, 0).good() &&
      referenced->findAndGetOFString(DCM_SeriesInstanceUID, uid).good()) {
    out->referenced_series_uid = text(uid);
  }
}

// The segments' numbers, labels, descriptions and codes, in segment-number order.
std::vector<Segment> read_segments(DcmSegmentation& seg) {
  std::vector<Segment> segments;
  for (size_t n = 1; n <= seg.getNumberOfSegments(); ++n) {
    DcmSegment* s = seg.getSegment(n);
    if (s == nullptr) continue;
    Segment segment;
    segment.number = static_cast<int>(n);
    OFString value;
    if (s->getSegmentLabel(value).good()) segment.label = text(value);
    if (s->getSegmentDescription(value).good()) segment.description = text(value);
    segment.category = code_of(s->getSegmentedPropertyCategoryCode());
    segment.type = code_of(s->getSegmentedPropertyTypeCode());
    segments.push_back(segment);
  }
  return segments;
}

// Frame `f`'s segment, and the slice its plane lies on.
Result<SegFrame> place_frame(FGInterface& groups, size_t f, const FramePlane& plane, const ImageGeometry& grid) {
  SegFrame frame;
  frame.index = f;
  frame.name = "segmentation frame " + std::to_string(f + 1);
  auto* identification = static_cast<FGSegmentation*>(groups.get(static_cast<Uint32>(f), DcmFGTypes::EFG_SEGMENTATION));
  if (identification == nullptr || identification->getReferencedSegmentNumber(frame.number).bad() ||
      frame.number == 0) {
    return invalid_argument_error(frame.name + " has no segment number");
  }
  POSEWARP_ASSIGN_OR_RETURN(frame.slice, slice_on_grid(plane, grid, frame.name));
  return frame;
}

// A frame's set pixels written onto its slice of `labels`; where segments overlap the highest number wins.
Status paint_frame(DcmSegmentation& seg, const SegFrame& frame, const FrameLayout& layout, LabelVolume* labels,
                   PaintCounts* counts) {
  const size_t per_frame = static_cast<size_t>(layout.rows) * layout.columns;
  const DcmIODTypes::Frame* pixels = seg.getFrame(frame.index);
  if (pixels == nullptr) return data_loss_error(frame.name + " has no pixel data");
  std::unique_ptr<DcmIODTypes::Frame> unpacked;
  if (layout.binary) {
    unpacked.reset(DcmSegUtils::unpackBinaryFrame(pixels, layout.rows, layout.columns));
    if (!unpacked) return data_loss_error(frame.name + " has less pixel data than its rows x columns");
    pixels = unpacked.get();
  }
  if (pixels->length < per_frame) return data_loss_error(frame.name + " has less pixel data than its rows x columns");
  Label* slice = labels->data() + frame.slice * per_frame;
  for (size_t i = 0; i < per_frame; ++i) {
    const Uint8 v = pixels->pixData[i];
    bool set = v != 0;
    if (!layout.binary) {
      set = 2.0 * v >= layout.max_fraction;
      counts->thresholded += v != 0 && static_cast<int>(v) != layout.max_fraction;
    }
    if (!set) continue;
    if (slice[i] != 0 && slice[i] != frame.number) ++counts->overlaps;
    slice[i] = std::max<Label>(slice[i], frame.number);
  }
  return ok_status();
}

// Warnings for the voxels that were thresholded or claimed by several segments.
void add_paint_warnings(const PaintCounts& counts, std::vector<std::string>* warnings) {
  if (counts.thresholded > 0) {
    warnings->push_back("fractional segmentation: " + std::to_string(counts.thresholded) +
                        " voxels with partial values were thresholded at one half");
  }
  if (counts.overlaps > 0) {
    warnings->push_back(std::to_string(counts.overlaps) +
                        " voxels belong to more than one segment; each took the "
                        "highest-numbered one");
  }
}

// The voxel count of each label value present; an error unless the labels can be a SEG on the CT's grid.
Result<LabelCounts> labels_present(const LabelVolume& labels, const SeriesInfo& ct) {
  const ImageGeometry& g = labels.geometry();
  if (ct.slice_count() != static_cast<size_t>(g.size[2])) {
    return invalid_argument_error("the labels have " + std::to_string(g.size[2]) + " slices and the CT series " +
                                  std::to_string(ct.slice_count()) + " images: the SEG must be on the CT's grid");
  }
  if (g.size[0] > 65535 || g.size[1] > 65535)
    return invalid_argument_error("a SEG frame has at most 65535 rows and columns");
  LabelCounts present;
  for (Label v : labels.voxels()) {
    if (v != 0) ++present[v];
  }
  if (present.empty()) return invalid_argument_error("the labels are all 0: a SEG needs at least one segment");
  if (present.begin()->first < 0 || present.rbegin()->first > 65535) {
    return invalid_argument_error("label values must be 1..65535 to be segment numbers");
  }
  return present;
}

// An empty binary SEG with frames of the grid's slice size, made by posewarp.
Result<std::unique_ptr<DcmSegmentation>> create_segmentation(const ImageGeometry& g,
                                                             const DerivedSeriesOptions& options) {
  IODGeneralEquipmentModule::EquipmentInfo equipment("posewarp", "posewarp", "0", "1");
  ContentIdentificationMacro content(
      "1", "POSEWARP", options.series_description.empty() ? "posed labels" : options.series_description, "posewarp");
  DcmSegmentation* created = nullptr;
  const OFCondition ok = DcmSegmentation::createBinarySegmentation(created, static_cast<Uint16>(g.size[1]),
                                                                   static_cast<Uint16>(g.size[0]), equipment, content);
  std::unique_ptr<DcmSegmentation> seg(created);
  if (ok.bad() || !seg) return internal_error(std::string("cannot create a segmentation: ") + ok.text());
  return seg;
}

// The new SEG series: the CT's patient and study, new series and instance UIDs, one instance.
Result<SeriesInfo> seg_series_info(const SeriesInfo& ct, const DerivedSeriesOptions& options) {
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
  return info;
}

// Patient, study and frame of reference the CT's; series and instance the new SEG's (`info`).
void set_seg_modules(DcmSegmentation& seg, const SeriesInfo& ct, const SeriesInfo& info) {
  seg.getPatient().setPatientName(ct.patient_name.c_str(), OFFalse);
  seg.getPatient().setPatientID(ct.patient_id.c_str(), OFFalse);
  seg.getPatient().setPatientBirthDate(ct.patient_birth_date.c_str(), OFFalse);
  seg.getPatient().setPatientSex(ct.patient_sex.c_str(), OFFalse);
  seg.getStudy().setStudyInstanceUID(ct.study_instance_uid.c_str(), OFFalse);
  seg.getStudy().setStudyDate(ct.study_date.c_str(), OFFalse);
  seg.getStudy().setStudyTime(ct.study_time.c_str(), OFFalse);
  seg.getStudy().setStudyID(ct.study_id.c_str(), OFFalse);
  seg.getStudy().setAccessionNumber(ct.accession_number.c_str(), OFFalse);
  seg.getStudy().setReferringPhysicianName(ct.referring_physician_name.c_str(), OFFalse);
  seg.getFrameOfReference().setFrameOfReferenceUID(ct.frame_of_reference_uid.c_str(), OFFalse);
  seg.getSeries().setSeriesInstanceUID(info.series_instance_uid.c_str(), OFFalse);
  seg.getSeries().setSeriesNumber(info.series_number.c_str(), OFFalse);
  seg.getSeries().setSeriesDescription(info.series_description.c_str(), OFFalse);
  seg.getSOPCommon().setSOPInstanceUID(info.sop_instance_uids.front().c_str(), OFFalse);
  if (!ct.specific_character_set.empty())
    seg.getSOPCommon().setSpecificCharacterSet(ct.specific_character_set.c_str(), OFFalse);
}

// Shared by all frames: the CT's pixel spacing and orientation.
Status add_shared_geometry(DcmSegmentation& seg, const ImageGeometry& g) {
  FGPixelMeasures measures;
  measures.setPixelSpacing((format("%.6f", g.spacing[1]) + "\\" + format("%.6f", g.spacing[0])).c_str());
  measures.setSliceThickness(format("%.6f", g.spacing[2]).c_str());
  FGPlaneOrientationPatient orientation;
  orientation.setImageOrientationPatient(format("%.6f", g.direction[0]).c_str(), format("%.6f", g.direction[3]).c_str(),
                                         format("%.6f", g.direction[6]).c_str(), format("%.6f", g.direction[1]).c_str(),
                                         format("%.6f", g.direction[4]).c_str(),
                                         format("%.6f", g.direction[7]).c_str());
  if (seg.addForAllFrames(measures).bad() || seg.addForAllFrames(orientation).bad()) {
    return internal_error("cannot set the segmentation's shared geometry");
  }
  return ok_status();
}

// One segment per label value present, in value order, numbered by its value and described by `segments` where one
// has that value as its number (else "label N", tissue).
std::vector<Segment> describe_segments(const LabelCounts& present, const std::vector<Segment>& segments) {
  std::map<int, const Segment*> described;
  for (const Segment& s : segments) described[s.number] = &s;
  std::vector<Segment> out;
  for (const auto& [value, count] : present) {
    const auto d = described.find(value);
    Segment segment = d == described.end() ? Segment{} : *d->second;
    segment.number = value;
    if (segment.label.empty()) segment.label = "label " + std::to_string(value);
    if (segment.category.value.empty()) segment.category = {"85756007", "SCT", "Tissue"};
    if (segment.type.value.empty()) segment.type = {"85756007", "SCT", "Tissue"};
    out.push_back(segment);
  }
  return out;
}

// The segments added to a binary SEG; DICOM numbers its segments 1, 2, 3, ..., so values that skip are renumbered
// (the result says how; the segment's label keeps the name).
Result<SegmentNumbers> add_segments(DcmSegmentation& seg, const std::vector<Segment>& segments) {
  SegmentNumbers number_of;
  for (const Segment& given : segments) {
    const Code &category = given.category, &type = given.type;
    DcmSegment* segment = nullptr;
    const OFCondition ok =
        DcmSegment::create(segment, given.label.c_str(),
                           CodeSequenceMacro(category.value.c_str(), category.scheme.c_str(), category.meaning.c_str()),
                           CodeSequenceMacro(type.value.c_str(), type.scheme.c_str(), type.meaning.c_str()),
                           DcmSegTypes::SAT_AUTOMATIC, "posewarp");
    if (ok.bad() || segment == nullptr) {
      return internal_error("cannot describe segment '" + given.label + "': " + ok.text());
    }
    if (!given.description.empty()) segment->setSegmentDescription(given.description.c_str(), OFFalse);
    Uint16 number = 0;
    if (seg.addSegment(segment, number).bad()) {
      delete segment;
      return internal_error("cannot add segment '" + given.label + "'");
    }
    number_of[given.number] = number;
  }
  return number_of;
}

// The slices each label appears on, in one pass over the volume.
std::map<Label, std::vector<int64_t>> slices_of_labels(const LabelVolume& labels) {
  const ImageGeometry& g = labels.geometry();
  const size_t per_frame = static_cast<size_t>(g.size[0] * g.size[1]);
  std::map<Label, std::vector<int64_t>> slices_of;
  for (int64_t k = 0; k < g.size[2]; ++k) {
    std::set<Label> here(labels.data() + static_cast<size_t>(k) * per_frame,
                         labels.data() + static_cast<size_t>(k + 1) * per_frame);
    for (Label v : here) {
      if (v != 0) slices_of[v].push_back(k);
    }
  }
  return slices_of;
}

// The Derivation Image functional group naming CT slice `ct_index` (an image, or a frame) as a frame's source (null
// if DCMTK made none).
std::unique_ptr<FGDerivationImage> derivation_from(const SeriesInfo& ct, size_t ct_index) {
  const SourceImage source = source_slice(ct, ct_index);
  OFVector<ImageSOPInstanceReferenceMacro> sources(1);
  sources[0].setReferencedSOPClassUID(source.sop_class_uid.c_str());
  sources[0].setReferencedSOPInstanceUID(source.sop_instance_uid.c_str());
  if (source.frame > 0) sources[0].addReferencedFrameNumber(static_cast<Uint16>(source.frame));
  return std::unique_ptr<FGDerivationImage>(DcmSegmentation::createDerivationImageFG(sources, "posewarp posed labels"));
}

// Frames: per segment, each slice it appears on, referencing that CT slice.
Status add_frames(DcmSegmentation& seg, const LabelVolume& labels, const SeriesInfo& ct,
                  const SegmentNumbers& number_of) {
  const ImageGeometry& g = labels.geometry();
  const bool reverse = written_in_reverse(g);  // as the CT was written
  const size_t per_frame = static_cast<size_t>(g.size[0] * g.size[1]);
  std::vector<Uint8> pixels(per_frame);
  FGSegmentation identification;
  std::vector<std::unique_ptr<FGDerivationImage>> derivations(static_cast<size_t>(g.size[2]));
  FGFrameContent content_fg;
  FGPlanePosPatient position;
  std::map<Label, std::vector<int64_t>> slices_of = slices_of_labels(labels);
  for (const auto& [value, number] : number_of) {
    for (const int64_t k : slices_of[value]) {
      const Label* slice = labels.data() + static_cast<size_t>(k) * per_frame;
      for (size_t i = 0; i < per_frame; ++i) pixels[i] = slice[i] == value ? 1 : 0;
      const Vec at = slice_position(g, k);
      position.setImagePositionPatient(format("%.6f", at[0]).c_str(), format("%.6f", at[1]).c_str(),
                                       format("%.6f", at[2]).c_str());
      identification.setReferencedSegmentNumber(number);
      content_fg.setDimensionIndexValues(number, 0);
      content_fg.setDimensionIndexValues(static_cast<Uint32>((reverse ? g.size[2] - 1 - k : k) + 1), 1);
      // The CT slice this frame derives from: one functional group per slice, made once and shared by its frames.
      const size_t ct_index = static_cast<size_t>(reverse ? g.size[2] - 1 - k : k);
      std::unique_ptr<FGDerivationImage>& derivation = derivations[ct_index];
      if (!derivation) derivation = derivation_from(ct, ct_index);
      OFVector<FGBase*> per_frame_groups{&identification, &content_fg, &position};
      if (derivation) per_frame_groups.push_back(derivation.get());
      const OFCondition ok = seg.addFrame(pixels.data(), number, per_frame_groups);
      if (ok.bad()) return internal_error("cannot add a segmentation frame: " + std::string(ok.text()));
    }
  }
  return ok_status();
}

// The frames' dimensions: segment number, then position.
Status add_dimensions(DcmSegmentation& seg, const DerivedSeriesOptions& options) {
  std::string dimension_uid;
  POSEWARP_ASSIGN_OR_RETURN(dimension_uid, uid_for(options, "seg-dimensions"));
  IODMultiframeDimensionModule& dimensions = seg.getDimensions();
  dimensions.addDimensionIndex(DCM_ReferencedSegmentNumber, dimension_uid.c_str(), DCM_SegmentIdentificationSequence,
                               "ReferencedSegmentNumber");
  dimensions.addDimensionIndex(DCM_ImagePositionPatient, dimension_uid.c_str(), DCM_PlanePositionSequence,
                               "ImagePositionPatient");
  // DCMTK's check of the functional groups compares every frame's groups with every other's (0.4 s of the sample's
  // 2068 frames, most of a SEG's encoding). The groups are made above, shared where they are the same, and the
  // tests read back what is written and run dciodvfy on it.
  seg.setCheckFGOnWrite(OFFalse);
  dimensions.setCheckOnWrite(OFFalse);
  return ok_status();
}

// The SEG written into `file`, with the CT series it belongs to (Common Instance Reference).
Status write_seg_dataset(DcmSegmentation& seg, const SeriesInfo& ct, DcmFileFormat* file) {
  const OFCondition ok = seg.writeDataset(*file->getDataset());
  if (ok.bad()) return internal_error(std::string("cannot write the segmentation: ") + ok.text());
  DcmDataset& d = *file->getDataset();
  d.findAndDeleteElement(DCM_ReferencedSeriesSequence);
  put_referenced_series(d, ct);
  return ok_status();
}

}  // namespace

Result<Segmentation> read_segmentation(const std::string& bytes, const ImageGeometry& grid) {
  quiet_dcmtk();
  POSEWARP_RETURN_IF_ERROR(grid.validate());
  POSEWARP_ASSIGN_OR_RETURN(const std::unique_ptr<DcmFileFormat> file, parse_part10(bytes, "the segmentation"));
  DcmDataset& d = *file->getDataset();
  OFString sop_class;
  d.findAndGetOFString(DCM_SOPClassUID, sop_class);
  if (sop_class == kLabelMapSegmentationStorage) return read_label_map_segmentation(d, grid);
  POSEWARP_ASSIGN_OR_RETURN(const std::unique_ptr<DcmSegmentation> seg, load_segmentation(d));
  POSEWARP_ASSIGN_OR_RETURN(const std::vector<FramePlane> planes, read_frame_planes(d, "the segmentation"));
  POSEWARP_ASSIGN_OR_RETURN(const FrameLayout layout, frame_layout(d, *seg, grid));
  Segmentation out;
  out.labels = LabelVolume(grid, 0);
  out.labels.set_source_type(PixelType::kUInt16);
  read_series_uids(d, &out);
  out.segments = read_segments(*seg);
  // Each frame onto its slice: its orientation must be the grid's, its position one of the grid's slice origins, its
  // pixels the grid's size.
  FGInterface& groups = seg->getFunctionalGroups();
  if (planes.size() != seg->getNumberOfFrames()) return data_loss_error("the segmentation's frames are incomplete");
  PaintCounts counts;
  for (size_t f = 0; f < seg->getNumberOfFrames(); ++f) {
    POSEWARP_ASSIGN_OR_RETURN(const SegFrame frame, place_frame(groups, f, planes[f], grid));
    POSEWARP_RETURN_IF_ERROR(paint_frame(*seg, frame, layout, &out.labels, &counts));
  }
  add_paint_warnings(counts, &out.warnings);
  return out;
}

Result<std::string> encode_segmentation(const LabelVolume& labels, const std::vector<Segment>& segments,
                                        const SeriesInfo& ct, const DerivedSeriesOptions& options, SeriesInfo* info_out,
                                        std::map<Label, int>* numbers) {
  quiet_dcmtk();
  const ImageGeometry& g = labels.geometry();
  POSEWARP_RETURN_IF_ERROR(g.validate());
  POSEWARP_ASSIGN_OR_RETURN(const LabelCounts present, labels_present(labels, ct));
  POSEWARP_ASSIGN_OR_RETURN(SeriesInfo info, seg_series_info(ct, options));
  const std::vector<Segment> described = describe_segments(present, segments);
  std::string bytes;
  SegmentNumbers number_of;
  if (options.seg_format == SegFormat::kLabelMap) {
    // A label map's segments are numbered by their values.
    info.sop_class_uid = kLabelMapSegmentationStorage;
    POSEWARP_ASSIGN_OR_RETURN(bytes, encode_label_map_segmentation(labels, described, ct, info, options));
    for (const Segment& s : described) number_of[s.number] = static_cast<Uint16>(s.number);
  } else {
    POSEWARP_ASSIGN_OR_RETURN(const std::unique_ptr<DcmSegmentation> seg, create_segmentation(g, options));
    set_seg_modules(*seg, ct, info);
    POSEWARP_RETURN_IF_ERROR(add_shared_geometry(*seg, g));
    POSEWARP_ASSIGN_OR_RETURN(number_of, add_segments(*seg, described));
    POSEWARP_RETURN_IF_ERROR(add_frames(*seg, labels, ct, number_of));
    POSEWARP_RETURN_IF_ERROR(add_dimensions(*seg, options));
    DcmFileFormat file;
    POSEWARP_RETURN_IF_ERROR(write_seg_dataset(*seg, ct, &file));
    POSEWARP_ASSIGN_OR_RETURN(bytes, encode_part10(file, "the segmentation"));
  }
  if (info_out != nullptr) *info_out = info;
  if (numbers != nullptr) numbers->insert(number_of.begin(), number_of.end());
  return bytes;
}

}  // namespace posewarp::dicom
