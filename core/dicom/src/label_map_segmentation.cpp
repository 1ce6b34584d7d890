// Label map SEGs through dcmdata: the Segmentation IOD's modules written attribute by attribute, a frame per slice.
#include "label_map_segmentation.h"

#include <dcmtk/dcmdata/dcdeftag.h>
#include <dcmtk/dcmdata/dcsequen.h>

#include <algorithm>

#include "multiframe.h"
#include "part10.h"

namespace posewarp::dicom {
namespace {

// Patient, study, frame of reference and equipment: the CT's; series and instance: the SEG's (`info`).
void put_identity(DcmDataset& d, const SeriesInfo& ct, const SeriesInfo& info, const DerivedSeriesOptions& options) {
  if (!ct.specific_character_set.empty()) put(d, DCM_SpecificCharacterSet, ct.specific_character_set);
  const std::string date = utc_now("%Y%m%d"), time = utc_now("%H%M%S");
  const std::pair<DcmTagKey, std::string> attributes[] = {
      {DCM_SOPClassUID, kLabelMapSegmentationStorage},
      {DCM_SOPInstanceUID, info.sop_instance_uids.front()},
      {DCM_PatientName, ct.patient_name},
      {DCM_PatientID, ct.patient_id},
      {DCM_PatientBirthDate, ct.patient_birth_date},
      {DCM_PatientSex, ct.patient_sex},
      {DCM_StudyInstanceUID, ct.study_instance_uid},
      {DCM_StudyDate, ct.study_date},
      {DCM_StudyTime, ct.study_time},
      {DCM_StudyID, ct.study_id},
      {DCM_AccessionNumber, ct.accession_number},
      {DCM_ReferringPhysicianName, ct.referring_physician_name},
      {DCM_Modality, "SEG"},
      {DCM_SeriesInstanceUID, info.series_instance_uid},
      {DCM_SeriesNumber, info.series_number},
      {DCM_SeriesDescription, info.series_description},
      {DCM_FrameOfReferenceUID, ct.frame_of_reference_uid},
      {DCM_PositionReferenceIndicator, ""},
      {DCM_Manufacturer, "posewarp"},
      {DCM_ManufacturerModelName, "posewarp"},
      {DCM_DeviceSerialNumber, "0"},
      {DCM_SoftwareVersions, "1"},
      {DCM_InstanceNumber, "1"},
      {DCM_InstanceCreationDate, date},
      {DCM_InstanceCreationTime, time},
      {DCM_SeriesDate, date},
      {DCM_SeriesTime, time},
      {DCM_ContentDate, date},
      {DCM_ContentTime, time},
      {DCM_ImageType, "DERIVED\\PRIMARY"},
      {DCM_ContentLabel, "POSEWARP"},
      {DCM_ContentDescription,
       options.series_description.empty() ? "posed labels" : options.series_description.substr(0, 64)},
      {DCM_ContentCreatorName, "posewarp"},
      {DCM_SegmentationType, "LABELMAP"},
      {DCM_SegmentsOverlap, "NO"},
      {DCM_LossyImageCompression, "00"},
  };
  for (const auto& [tag, value] : attributes) put(d, tag, value);
  if (!ct.study_description.empty()) put(d, DCM_StudyDescription, ct.study_description);
}

// The Segment Sequence: each segment by its number, label, codes and the algorithm that made it.
void put_segments(DcmDataset& d, const std::vector<Segment>& segments) {
  for (const Segment& s : segments) {
    DcmItem* item = nullptr;
    if (d.findOrCreateSequenceItem(DCM_SegmentSequence, item, -2).bad()) return;
    item->putAndInsertUint16(DCM_SegmentNumber, static_cast<Uint16>(s.number));
    put(*item, DCM_SegmentLabel, s.label.substr(0, 64));
    if (!s.description.empty()) put(*item, DCM_SegmentDescription, s.description);
    put(*item, DCM_SegmentAlgorithmType, "AUTOMATIC");
    put(*item, DCM_SegmentAlgorithmName, "posewarp");
    put_code(*item, DCM_SegmentedPropertyCategoryCodeSequence, s.category);
    put_code(*item, DCM_SegmentedPropertyTypeCodeSequence, s.type);
  }
}

// Image Pixel: unsigned samples of 8 bits where every number fits, else 16.
int put_pixel_description(DcmDataset& d, const ImageGeometry& g, int max_number) {
  const int bits = max_number <= 255 ? 8 : 16;
  d.putAndInsertUint16(DCM_SamplesPerPixel, 1);
  put(d, DCM_PhotometricInterpretation, "MONOCHROME2");
  d.putAndInsertUint16(DCM_Rows, static_cast<Uint16>(g.size[1]));
  d.putAndInsertUint16(DCM_Columns, static_cast<Uint16>(g.size[0]));
  d.putAndInsertUint16(DCM_BitsAllocated, static_cast<Uint16>(bits));
  d.putAndInsertUint16(DCM_BitsStored, static_cast<Uint16>(bits));
  d.putAndInsertUint16(DCM_HighBit, static_cast<Uint16>(bits - 1));
  d.putAndInsertUint16(DCM_PixelRepresentation, 0);
  put(d, DCM_NumberOfFrames, std::to_string(g.size[2]));
  return bits;
}

// The frames: slice after slice in the CT's order, each placed and derived from its CT slice; their pixels the
// label values, as `bits`-bit samples.
Status put_frames(DcmDataset& d, const LabelVolume& labels, const SeriesInfo& ct, int bits) {
  const ImageGeometry& g = labels.geometry();
  const bool reverse = written_in_reverse(g);  // as the CT was written
  const size_t per_frame = static_cast<size_t>(g.size[0] * g.size[1]);
  const size_t frames = static_cast<size_t>(g.size[2]);
  // The per-frame items appended one after another (indexing a DCMTK sequence walks its list).
  auto* per_frame_groups = new DcmSequenceOfItems(DCM_PerFrameFunctionalGroupsSequence);
  std::vector<Uint8> bytes(bits == 8 ? per_frame * frames : 0);
  std::vector<Uint16> words(bits == 16 ? per_frame * frames : 0);
  for (size_t n = 0; n < frames; ++n) {
    const int64_t k = reverse ? g.size[2] - 1 - static_cast<int64_t>(n) : static_cast<int64_t>(n);
    auto* frame = new DcmItem();
    per_frame_groups->append(frame);
    put_frame_place(*frame, g, k, static_cast<uint32_t>(n + 1));
    put_derivation(*frame, {source_slice(ct, n)}, {"113076", "DCM", "Segmentation"}, "posewarp posed labels");
    const Label* slice = labels.data() + static_cast<size_t>(k) * per_frame;
    for (size_t i = 0; i < per_frame; ++i) {
      if (bits == 8) {
        bytes[n * per_frame + i] = static_cast<Uint8>(slice[i]);
      } else {
        words[n * per_frame + i] = static_cast<Uint16>(slice[i]);
      }
    }
  }
  if (d.insert(per_frame_groups, OFTrue).bad()) {
    delete per_frame_groups;
    return internal_error("cannot add the label map's frames");
  }
  const OFCondition ok =
      bits == 8 ? d.putAndInsertUint8Array(DCM_PixelData, bytes.data(), static_cast<unsigned long>(bytes.size()))
                : d.putAndInsertUint16Array(DCM_PixelData, words.data(), static_cast<unsigned long>(words.size()));
  if (ok.bad()) return internal_error(std::string("cannot add the label map's pixels: ") + ok.text());
  return ok_status();
}

// Each frame's pixels onto its slice of `labels`; a number that no segment has (`described`, by number) is an error.
Status read_frames(DcmDataset& d, const std::vector<FramePlane>& planes, const ImageGeometry& grid,
                   const std::vector<bool>& described, LabelVolume* labels) {
  Uint16 rows = 0, columns = 0, bits = 0, representation = 0, samples = 1;
  d.findAndGetUint16(DCM_Rows, rows);
  d.findAndGetUint16(DCM_Columns, columns);
  d.findAndGetUint16(DCM_BitsAllocated, bits);
  d.findAndGetUint16(DCM_PixelRepresentation, representation);
  d.findAndGetUint16(DCM_SamplesPerPixel, samples);
  if (rows != grid.size[1] || columns != grid.size[0]) {
    return invalid_argument_error("the segmentation's frames are " + std::to_string(columns) + " x " +
                                  std::to_string(rows) + " pixels, the CT's slices " + std::to_string(grid.size[0]) +
                                  " x " + std::to_string(grid.size[1]) + ": it was not made on this CT");
  }
  if ((bits != 8 && bits != 16) || representation != 0 || samples != 1) {
    return invalid_argument_error("the label map's pixels are not unsigned 8- or 16-bit segment numbers (bits " +
                                  std::to_string(bits) + ")");
  }
  POSEWARP_RETURN_IF_ERROR(decode_pixel_data(d, "the label map segmentation"));
  const size_t per_frame = static_cast<size_t>(rows) * columns;
  const size_t needed = per_frame * planes.size();
  const Uint8* bytes = nullptr;
  const Uint16* words = nullptr;
  unsigned long count = 0;
  const bool read = bits == 8 ? d.findAndGetUint8Array(DCM_PixelData, bytes, &count).good()
                              : d.findAndGetUint16Array(DCM_PixelData, words, &count).good();
  if (!read || count < needed) {
    return data_loss_error("the label map segmentation has less pixel data than its frames x rows x columns");
  }
  std::vector<bool> painted(static_cast<size_t>(grid.size[2]), false);
  for (size_t f = 0; f < planes.size(); ++f) {
    const std::string name = "segmentation frame " + std::to_string(f + 1);
    POSEWARP_ASSIGN_OR_RETURN(const size_t k, slice_on_grid(planes[f], grid, name));
    if (painted[k]) return invalid_argument_error(name + " lies on a slice that another frame already covers");
    painted[k] = true;
    Label* slice = labels->data() + k * per_frame;
    for (size_t i = 0; i < per_frame; ++i) {
      const int v = bits == 8 ? bytes[f * per_frame + i] : words[f * per_frame + i];
      if (v != 0 && !described[static_cast<size_t>(v)]) {
        return data_loss_error(name + " holds the value " + std::to_string(v) +
                               ", which no segment of the label map has");
      }
      slice[i] = v;
    }
  }
  return ok_status();
}

}  // namespace

Result<std::string> encode_label_map_segmentation(const LabelVolume& labels, const std::vector<Segment>& segments,
                                                  const SeriesInfo& ct, const SeriesInfo& info,
                                                  const DerivedSeriesOptions& options) {
  const ImageGeometry& g = labels.geometry();
  DcmFileFormat file;
  DcmDataset& d = *file.getDataset();
  put_identity(d, ct, info, options);
  put_segments(d, segments);
  int max_number = 0;
  for (const Segment& s : segments) max_number = std::max(max_number, s.number);
  const int bits = put_pixel_description(d, g, max_number);
  DcmItem* shared = shared_groups(d);
  if (shared == nullptr) return internal_error("cannot add the label map's functional groups");
  put_plane_geometry(*shared, g);
  std::string organization;
  POSEWARP_ASSIGN_OR_RETURN(organization, uid_for(options, "seg-dimensions"));
  put_position_dimension(d, organization);
  POSEWARP_RETURN_IF_ERROR(put_frames(d, labels, ct, bits));
  put_referenced_series(d, ct);
  return encode_part10(file, "the label map segmentation");
}

Result<Segmentation> read_label_map_segmentation(DcmDataset& d, const ImageGeometry& grid) {
  Segmentation out;
  out.series_instance_uid = text_of(d, DCM_SeriesInstanceUID);
  DcmItem* referenced = nullptr;
  if (d.findAndGetSequenceItem(DCM_ReferencedSeriesSequence, referenced, 0).good()) {
    out.referenced_series_uid = text_of(*referenced, DCM_SeriesInstanceUID);
  }
  // Segments by number; a segment numbered 0 (a described background) stays 0.
  std::vector<bool> described(size_t{1} << 16, false);
  DcmSequenceOfItems* sequence = nullptr;
  if (d.findAndGetSequence(DCM_SegmentSequence, sequence).good() && sequence != nullptr) {
    for (unsigned long i = 0; i < sequence->card(); ++i) {
      DcmItem* item = sequence->getItem(i);
      Uint16 number = 0;
      if (item->findAndGetUint16(DCM_SegmentNumber, number).bad()) {
        return invalid_argument_error("segment " + std::to_string(i + 1) + " of the label map has no number");
      }
      if (number == 0) continue;
      described[number] = true;
      Segment s;
      s.number = number;
      s.label = text_of(*item, DCM_SegmentLabel);
      s.description = text_of(*item, DCM_SegmentDescription);
      s.category = code_in(*item, DCM_SegmentedPropertyCategoryCodeSequence);
      s.type = code_in(*item, DCM_SegmentedPropertyTypeCodeSequence);
      out.segments.push_back(s);
    }
  }
  std::sort(out.segments.begin(), out.segments.end(),
            [](const Segment& a, const Segment& b) { return a.number < b.number; });
  POSEWARP_ASSIGN_OR_RETURN(const std::vector<FramePlane> planes, read_frame_planes(d, "the label map segmentation"));
  out.labels = LabelVolume(grid, 0);
  out.labels.set_source_type(PixelType::kUInt16);
  POSEWARP_RETURN_IF_ERROR(read_frames(d, planes, grid, described, &out.labels));
  return out;
}

}  // namespace posewarp::dicom
