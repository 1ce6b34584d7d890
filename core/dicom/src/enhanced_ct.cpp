// A posed CT as one Enhanced CT image through dcmdata: the derived series' attributes, the Enhanced CT Image
// module, functional groups shared by every frame (geometry, anatomy, rescale, window, frame type, derivation) and
// a plane position per frame.
#include <dcmtk/dcmdata/dcdeftag.h>
#include <dcmtk/dcmdata/dcsequen.h>
#include <dcmtk/dcmdata/dcuid.h>

#include "derived_ct.h"
#include "part10.h"

namespace posewarp::dicom {
namespace {

// A functional group macro (a sequence of one item) in `groups`, made.
DcmItem* macro(DcmItem& groups, const DcmTagKey& tag) {
  DcmItem* item = nullptr;
  groups.findOrCreateSequenceItem(tag, item, 0);
  return item;
}

// The Enhanced CT Image, Enhanced General Equipment and Image Pixel modules of a derived volume.
void put_image_modules(DcmDataset& d, const ImageGeometry& g) {
  const std::pair<DcmTagKey, std::string> attributes[] = {
      {DCM_ImageType, "DERIVED\\PRIMARY\\VOLUME\\NONE"},
      {DCM_PixelPresentation, "MONOCHROME"},
      {DCM_VolumetricProperties, "VOLUME"},
      {DCM_VolumeBasedCalculationTechnique, "NONE"},
      {DCM_ContentQualification, "PRODUCT"},
      {DCM_BurnedInAnnotation, "NO"},
      {DCM_LossyImageCompression, "00"},
      {DCM_PresentationLUTShape, "IDENTITY"},
      {DCM_ManufacturerModelName, "posewarp"},
      {DCM_DeviceSerialNumber, "0"},
      {DCM_SoftwareVersions, "1"},
      {DCM_NumberOfFrames, std::to_string(g.size[2])},
  };
  for (const auto& [tag, value] : attributes) put(d, tag, value);
  // What a single-frame CT image has and an Enhanced CT holds per frame or not at all.
  for (const DcmTagKey& tag : {DCM_KVP, DCM_AcquisitionNumber, DCM_Laterality, DCM_DerivationDescription}) {
    d.findAndDeleteElement(tag);
  }
  d.insertEmptyElement(DCM_AcquisitionContextSequence);
  put_hu_pixel_module(d, g);
}

// What every frame shares: geometry, anatomy, rescale to HU, a soft-tissue window, the frame type, and the source
// images the volume was resampled from.
Status put_shared_groups(DcmDataset& d, const ImageGeometry& g, const SeriesInfo& source,
                         const DerivedSeriesOptions& options) {
  DcmItem* shared = shared_groups(d);
  if (shared == nullptr) return internal_error("cannot add the Enhanced CT's functional groups");
  put_plane_geometry(*shared, g);
  if (DcmItem* anatomy = macro(*shared, DCM_FrameAnatomySequence)) {
    put(*anatomy, DCM_FrameLaterality, "U");
    put_code(*anatomy, DCM_AnatomicRegionSequence, {"38266002", "SCT", "Entire body"});
  }
  if (DcmItem* rescale = macro(*shared, DCM_PixelValueTransformationSequence)) {
    put(*rescale, DCM_RescaleIntercept, "0");
    put(*rescale, DCM_RescaleSlope, "1");
    put(*rescale, DCM_RescaleType, "HU");
  }
  if (DcmItem* window = macro(*shared, DCM_FrameVOILUTSequence)) {
    put(*window, DCM_WindowCenter, "40");
    put(*window, DCM_WindowWidth, "400");
  }
  if (DcmItem* type = macro(*shared, DCM_CTImageFrameTypeSequence)) {
    put(*type, DCM_FrameType, "DERIVED\\PRIMARY\\VOLUME\\NONE");
    put(*type, DCM_PixelPresentation, "MONOCHROME");
    put(*type, DCM_VolumetricProperties, "VOLUME");
    put(*type, DCM_VolumeBasedCalculationTechnique, "NONE");
  }
  if (DcmItem* event = macro(*shared, DCM_IrradiationEventIdentificationSequence)) {
    std::string uid;
    POSEWARP_ASSIGN_OR_RETURN(uid, uid_for(options, "irradiation-event"));
    put(*event, DCM_IrradiationEventUID, uid);
  }
  std::vector<SourceImage> sources;
  for (size_t i = 0; i < source.slice_count(); ++i) sources.push_back(source_slice(source, i));
  put_derivation(*shared, sources, {"113085", "DCM", "Spatial resampling"}, options.derivation_description);
  return ok_status();
}

// Every slice a frame, in DICOM's order (along row x column), placed and counted along the stack; the pixels int16
// HU. OUT_OF_RANGE when values do not fit.
Status put_frames(DcmDataset& d, const IntensityVolume& ct) {
  const ImageGeometry& g = ct.geometry();
  const SliceAxes axes = slice_axes(g);
  const size_t per_slice = static_cast<size_t>(g.size[0] * g.size[1]);
  const size_t frames = static_cast<size_t>(g.size[2]);
  auto* per_frame_groups = new DcmSequenceOfItems(DCM_PerFrameFunctionalGroupsSequence);
  std::vector<int16_t> samples(per_slice * frames);
  int64_t clipped = 0;
  for (size_t n = 0; n < frames; ++n) {
    const int64_t k = axes.reverse ? g.size[2] - 1 - static_cast<int64_t>(n) : static_cast<int64_t>(n);
    auto* frame = new DcmItem();
    per_frame_groups->append(frame);
    put_frame_place(*frame, g, k, static_cast<uint32_t>(n + 1));
    if (DcmItem* content = macro(*frame, DCM_FrameContentSequence)) {
      put(*content, DCM_StackID, "1");
      content->putAndInsertUint32(DCM_InStackPositionNumber, static_cast<Uint32>(n + 1));
    }
    clipped += hu_samples(ct, k, samples.data() + n * per_slice);
  }
  if (clipped > 0) {
    delete per_frame_groups;
    return out_of_range_error(std::to_string(clipped) +
                              " CT values do not fit int16 (-32768..32767); a DICOM CT cannot hold them");
  }
  if (d.insert(per_frame_groups, OFTrue).bad()) return internal_error("cannot add the Enhanced CT's frames");
  // Pixel data is OW: the signed samples' 16-bit words (PixelRepresentation 1 says how to read them).
  const OFCondition ok = d.putAndInsertUint16Array(DCM_PixelData, reinterpret_cast<const Uint16*>(samples.data()),
                                                   static_cast<unsigned long>(samples.size()));
  if (ok.bad()) return internal_error(std::string("cannot add the Enhanced CT's pixels: ") + ok.text());
  return ok_status();
}

// The source series' images as the evidence a derived image was made from (Hierarchical SOP Instance Reference).
void put_source_evidence(DcmDataset& d, const SeriesInfo& source) {
  if (source.sop_instance_uids.empty()) return;  // a study that never was DICOM: no images to name
  DcmItem* study = nullptr;
  DcmItem* series = nullptr;
  if (d.findOrCreateSequenceItem(DCM_SourceImageEvidenceSequence, study, 0).bad() ||
      study->findOrCreateSequenceItem(DCM_ReferencedSeriesSequence, series, 0).bad()) {
    return;
  }
  put(*study, DCM_StudyInstanceUID, source.study_instance_uid);
  put(*series, DCM_SeriesInstanceUID, source.series_instance_uid);
  for (const std::string& uid : source.sop_instance_uids) {
    DcmItem* item = nullptr;
    if (series->findOrCreateSequenceItem(DCM_ReferencedSOPSequence, item, -2).bad()) return;
    put(*item, DCM_ReferencedSOPClassUID, source_slice(source, 0).sop_class_uid);
    put(*item, DCM_ReferencedSOPInstanceUID, uid);
  }
}

}  // namespace

Result<std::string> encode_enhanced_ct(const IntensityVolume& ct, const SeriesInfo& source,
                                       const DerivedSeriesOptions& options, SeriesInfo* info_out) {
  const ImageGeometry& g = ct.geometry();
  POSEWARP_RETURN_IF_ERROR(check_derived_input(g, source));
  POSEWARP_ASSIGN_OR_RETURN(SeriesInfo info, derived_series_info(source, options));
  info.sop_class_uid = UID_EnhancedCTImageStorage;
  DerivedInstance instance;
  instance.date = utc_now("%Y%m%d");
  instance.time = utc_now("%H%M%S");
  POSEWARP_ASSIGN_OR_RETURN(instance.sop_uid, uid_for(options, "ct/enhanced"));
  DcmFileFormat file;
  DcmDataset& d = *file.getDataset();
  put_series_attributes(d, info, options, instance);
  put_image_modules(d, g);
  POSEWARP_RETURN_IF_ERROR(put_shared_groups(d, g, source, options));
  std::string organization;
  POSEWARP_ASSIGN_OR_RETURN(organization, uid_for(options, "ct-dimensions"));
  put_position_dimension(d, organization);
  POSEWARP_RETURN_IF_ERROR(put_frames(d, ct));
  put_referenced_series(d, source);
  put_source_evidence(d, source);
  POSEWARP_ASSIGN_OR_RETURN(std::string bytes, encode_part10(file, "the Enhanced CT"));
  info.sop_instance_uids = {instance.sop_uid};
  for (int64_t n = 0; n < g.size[2]; ++n) info.frame_numbers.push_back(static_cast<int32_t>(n + 1));
  if (info_out != nullptr) *info_out = info;
  return bytes;
}

}  // namespace posewarp::dicom
