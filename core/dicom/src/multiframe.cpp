// Functional groups of multi-frame images through dcmdata: where each frame lies, what it was derived from.
#include "multiframe.h"

#include <dcmtk/dcmdata/dcdeftag.h>
#include <dcmtk/dcmdata/dcsequen.h>
#include <dcmtk/dcmdata/dcuid.h>

#include <cmath>
#include <cstdio>
#include <cstring>
#include <ctime>

namespace posewarp::dicom {
namespace {

// The first item of sequence `tag` in `item`, or null.
DcmItem* first_item(DcmItem* item, const DcmTagKey& tag) {
  DcmItem* found = nullptr;
  if (item == nullptr || item->findAndGetSequenceItem(tag, found, 0).bad()) return nullptr;
  return found;
}

// The macro `tag` (a sequence of one item) of a frame: its per-frame groups' where they have it, else the shared.
DcmItem* macro_of(DcmItem* frame, DcmItem* shared, const DcmTagKey& tag) {
  DcmItem* found = first_item(frame, tag);
  return found != nullptr ? found : first_item(shared, tag);
}

// The SOP class a series' images are referenced by: theirs, or CT Image Storage where it gives none.
std::string sop_class_of(const SeriesInfo& series) {
  return series.sop_class_uid.empty() ? UID_CTImageStorage : series.sop_class_uid;
}

}  // namespace

bool numbers(DcmItem* item, const DcmTagKey& tag, double* out, int count) {
  if (item == nullptr) return false;
  for (int i = 0; i < count; ++i) {
    Float64 value = 0;
    if (item->findAndGetFloat64(tag, value, static_cast<unsigned long>(i)).bad() || !std::isfinite(value)) return false;
    out[i] = value;
  }
  return true;
}

void put(DcmItem& d, const DcmTagKey& tag, const std::string& value) {
  d.putAndInsertString(tag, value.c_str());
}

std::string text_of(DcmItem& d, const DcmTagKey& tag) {
  OFString value;
  if (d.findAndGetOFStringArray(tag, value).bad()) return {};
  return value.c_str();
}

void put_code(DcmItem& parent, const DcmTagKey& sequence, const DicomCode& code) {
  DcmItem* item = nullptr;
  if (parent.findOrCreateSequenceItem(sequence, item, 0).bad()) return;
  put(*item, DCM_CodeValue, code.value);
  put(*item, DCM_CodingSchemeDesignator, code.scheme);
  put(*item, DCM_CodeMeaning, code.meaning);
}

DicomCode code_in(DcmItem& parent, const DcmTagKey& sequence) {
  DcmItem* item = nullptr;
  if (parent.findAndGetSequenceItem(sequence, item, 0).bad()) return {};
  return {text_of(*item, DCM_CodeValue), text_of(*item, DCM_CodingSchemeDesignator), text_of(*item, DCM_CodeMeaning)};
}

bool written_in_reverse(const ImageGeometry& g) {
  const Vec row{g.direction[0], g.direction[3], g.direction[6]}, column{g.direction[1], g.direction[4], g.direction[7]};
  const Vec axis{g.direction[2], g.direction[5], g.direction[8]};
  const Vec normal{row[1] * column[2] - row[2] * column[1], row[2] * column[0] - row[0] * column[2],
                   row[0] * column[1] - row[1] * column[0]};
  return normal[0] * axis[0] + normal[1] * axis[1] + normal[2] * axis[2] < 0;
}

std::string decimal(double value) {
  char out[32];
  // DS holds 16 characters: six decimals while they fit, fewer for large magnitudes.
  for (int digits = 6; digits >= 0; --digits) {
    std::snprintf(out, sizeof out, "%.*f", digits, value);
    if (std::strlen(out) <= 16) break;
  }
  return out;
}

std::string utc_now(const char* format) {
  const std::time_t now = std::time(nullptr);
  std::tm utc{};
  gmtime_r(&now, &utc);
  char out[32];
  std::strftime(out, sizeof out, format, &utc);
  return out;
}

DcmItem* shared_groups(DcmItem& d) {
  DcmItem* item = nullptr;
  d.findOrCreateSequenceItem(DCM_SharedFunctionalGroupsSequence, item, 0);
  return item;
}

DcmItem* frame_groups(DcmItem& d, size_t f) {
  DcmItem* item = nullptr;
  d.findOrCreateSequenceItem(DCM_PerFrameFunctionalGroupsSequence, item, static_cast<signed long>(f));
  return item;
}

Vec slice_position(const ImageGeometry& g, int64_t k) {
  const double offset = static_cast<double>(k) * g.spacing[2];
  return {g.origin[0] + offset * g.direction[2], g.origin[1] + offset * g.direction[5],
          g.origin[2] + offset * g.direction[8]};
}

void put_plane_geometry(DcmItem& groups, const ImageGeometry& g) {
  DcmItem* measures = nullptr;
  if (groups.findOrCreateSequenceItem(DCM_PixelMeasuresSequence, measures, 0).good()) {
    put(*measures, DCM_PixelSpacing, decimal(g.spacing[1]) + "\\" + decimal(g.spacing[0]));
    put(*measures, DCM_SliceThickness, decimal(g.spacing[2]));
    put(*measures, DCM_SpacingBetweenSlices, decimal(g.spacing[2]));
  }
  DcmItem* orientation = nullptr;
  if (groups.findOrCreateSequenceItem(DCM_PlaneOrientationSequence, orientation, 0).good()) {
    std::string value = decimal(g.direction[0]);
    for (size_t i : {3, 6, 1, 4, 7}) {
      value += '\\';
      value += decimal(g.direction[i]);
    }
    put(*orientation, DCM_ImageOrientationPatient, value);
  }
}

void put_frame_place(DcmItem& frame, const ImageGeometry& g, int64_t k, uint32_t index) {
  DcmItem* position = nullptr;
  if (frame.findOrCreateSequenceItem(DCM_PlanePositionSequence, position, 0).good()) {
    const Vec p = slice_position(g, k);
    put(*position, DCM_ImagePositionPatient, decimal(p[0]) + "\\" + decimal(p[1]) + "\\" + decimal(p[2]));
  }
  DcmItem* content = nullptr;
  if (frame.findOrCreateSequenceItem(DCM_FrameContentSequence, content, 0).good()) {
    content->putAndInsertUint32(DCM_DimensionIndexValues, index);
  }
}

void put_position_dimension(DcmItem& d, const std::string& organization_uid) {
  DcmItem* organization = nullptr;
  if (d.findOrCreateSequenceItem(DCM_DimensionOrganizationSequence, organization, 0).good()) {
    put(*organization, DCM_DimensionOrganizationUID, organization_uid);
  }
  put(d, DCM_DimensionOrganizationType, "3D");
  DcmItem* index = nullptr;
  if (d.findOrCreateSequenceItem(DCM_DimensionIndexSequence, index, 0).good()) {
    put(*index, DCM_DimensionOrganizationUID, organization_uid);
    index->putAndInsertTagKey(DCM_DimensionIndexPointer, DCM_ImagePositionPatient);
    index->putAndInsertTagKey(DCM_FunctionalGroupPointer, DCM_PlanePositionSequence);
    put(*index, DCM_DimensionDescriptionLabel, "position");
  }
}

SourceImage source_slice(const SeriesInfo& series, size_t index) {
  SourceImage source;
  source.sop_class_uid = sop_class_of(series);
  if (series.frame_numbers.empty()) {
    source.sop_instance_uid = series.sop_instance_uids.at(index);
  } else {
    source.sop_instance_uid = series.sop_instance_uids.front();
    source.frame = series.frame_numbers.at(index);
  }
  return source;
}

void put_derivation(DcmItem& groups, const std::vector<SourceImage>& sources, const DicomCode& code,
                    const std::string& description) {
  DcmItem* derivation = nullptr;
  if (groups.findOrCreateSequenceItem(DCM_DerivationImageSequence, derivation, 0).bad()) return;
  if (!description.empty()) put(*derivation, DCM_DerivationDescription, description.substr(0, 1024));
  put_code(*derivation, DCM_DerivationCodeSequence, code);
  if (sources.empty()) derivation->insertEmptyElement(DCM_SourceImageSequence);  // type 2: present, maybe empty
  for (const SourceImage& s : sources) {
    DcmItem* item = nullptr;
    if (derivation->findOrCreateSequenceItem(DCM_SourceImageSequence, item, -2).bad()) return;
    put(*item, DCM_ReferencedSOPClassUID, s.sop_class_uid);
    put(*item, DCM_ReferencedSOPInstanceUID, s.sop_instance_uid);
    if (s.frame > 0) put(*item, DCM_ReferencedFrameNumber, std::to_string(s.frame));
    put_code(*item, DCM_PurposeOfReferenceCodeSequence,
             {"121322", "DCM", "Source image for image processing operation"});
  }
}

void put_referenced_series(DcmItem& d, const SeriesInfo& series) {
  if (series.sop_instance_uids.empty()) return;
  const std::string sop_class = sop_class_of(series);
  DcmItem* series_item = nullptr;
  if (d.findOrCreateSequenceItem(DCM_ReferencedSeriesSequence, series_item, 0).bad()) return;
  put(*series_item, DCM_SeriesInstanceUID, series.series_instance_uid);
  for (const std::string& uid : series.sop_instance_uids) {
    DcmItem* item = nullptr;
    if (series_item->findOrCreateSequenceItem(DCM_ReferencedInstanceSequence, item, -2).bad()) return;
    put(*item, DCM_ReferencedSOPClassUID, sop_class);
    put(*item, DCM_ReferencedSOPInstanceUID, uid);
  }
}

Result<std::vector<FramePlane>> read_frame_planes(DcmItem& d, const std::string& what) {
  Sint32 count = 0;
  if (d.findAndGetSint32(DCM_NumberOfFrames, count).bad() || count < 1) {
    return invalid_argument_error(what + " has no NumberOfFrames");
  }
  DcmSequenceOfItems* per_frame = nullptr;
  if (d.findAndGetSequence(DCM_PerFrameFunctionalGroupsSequence, per_frame).bad() || per_frame == nullptr ||
      per_frame->card() != static_cast<unsigned long>(count)) {
    return invalid_argument_error(what + " has " + std::to_string(count) +
                                  " frames but not as many items of per-frame functional groups");
  }
  DcmItem* shared = first_item(&d, DCM_SharedFunctionalGroupsSequence);
  std::vector<FramePlane> planes(static_cast<size_t>(count));
  // The per-frame sequence is a list: walked once, not indexed.
  DcmObject* object = nullptr;
  for (size_t f = 0; f < planes.size(); ++f) {
    object = per_frame->nextInContainer(object);
    auto* frame = dynamic_cast<DcmItem*>(object);
    const std::string name = what + ", frame " + std::to_string(f + 1) + ",";
    FramePlane& plane = planes[f];
    double orientation[6];
    if (!numbers(macro_of(frame, shared, DCM_PlanePositionSequence), DCM_ImagePositionPatient, plane.position.data(),
                 3) ||
        !numbers(macro_of(frame, shared, DCM_PlaneOrientationSequence), DCM_ImageOrientationPatient, orientation, 6) ||
        !numbers(macro_of(frame, shared, DCM_PixelMeasuresSequence), DCM_PixelSpacing, plane.spacing, 2)) {
      return invalid_argument_error(name +
                                    " lacks its position, orientation or pixel spacing: its place in the patient "
                                    "is unknown");
    }
    plane.row = {orientation[0], orientation[1], orientation[2]};
    plane.column = {orientation[3], orientation[4], orientation[5]};
    if (DcmItem* rescale = macro_of(frame, shared, DCM_PixelValueTransformationSequence)) {
      numbers(rescale, DCM_RescaleSlope, &plane.slope, 1);
      numbers(rescale, DCM_RescaleIntercept, &plane.intercept, 1);
    }
  }
  return planes;
}

Result<size_t> slice_on_grid(const FramePlane& plane, const ImageGeometry& grid, const std::string& name) {
  const Vec row{grid.direction[0], grid.direction[3], grid.direction[6]};
  const Vec column{grid.direction[1], grid.direction[4], grid.direction[7]};
  for (size_t i = 0; i < 3; ++i) {
    if (std::abs(plane.row[i] - row[i]) > 1e-3 || std::abs(plane.column[i] - column[i]) > 1e-3) {
      return invalid_argument_error(name + " is not oriented as the CT's slices: it was not made on this CT");
    }
  }
  if (std::abs(plane.spacing[0] - grid.spacing[1]) > 1e-3 || std::abs(plane.spacing[1] - grid.spacing[0]) > 1e-3) {
    return invalid_argument_error(name + " has a pixel spacing (" + decimal(plane.spacing[1]) + " x " +
                                  decimal(plane.spacing[0]) + " mm) that is not the CT's: it was not made on this CT");
  }
  const Vec& p = plane.position;
  const Vec3 index = grid.physical_to_index({p[0], p[1], p[2]});
  const double k = std::round(index[2]);
  if (std::abs(index[0]) > 0.01 || std::abs(index[1]) > 0.01 || std::abs(index[2] - k) > 0.01 || k < 0 ||
      k >= static_cast<double>(grid.size[2])) {
    char at[96];
    std::snprintf(at, sizeof at, "%.2f, %.2f, %.2f", p[0], p[1], p[2]);
    return invalid_argument_error(name + " lies off the CT's slices (at " + at +
                                  " mm): it was not made on this CT's grid");
  }
  return static_cast<size_t>(k);
}

}  // namespace posewarp::dicom
