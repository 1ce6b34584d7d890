// CT series through DCMTK: parsed from Part 10 bytes, checked as a volume, and written back as a derived series.
#include "posewarp/dicom/ct_series.h"

#include <dcmtk/config/osconfig.h>  // before any other DCMTK header
#include <dcmtk/dcmdata/dcdeftag.h>
#include <dcmtk/dcmdata/dcfilefo.h>
#include <dcmtk/dcmdata/dcuid.h>
#include <dcmtk/oflog/oflog.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <ctime>
#include <filesystem>
#include <fstream>
#include <map>
#include <mutex>

#include "derived_ct.h"
#include "multiframe.h"
#include "part10.h"
#include "posewarp/common/atomic_file.h"
#include "posewarp/common/input_file.h"

namespace posewarp::dicom {
namespace fs = std::filesystem;

void quiet_dcmtk() {
  // DCMTK logs warnings to the console; posewarp reports what matters as its own errors and warnings.
  static std::once_flag once;
  std::call_once(once, [] { OFLog::configure(OFLogger::OFF_LOG_LEVEL); });
}

namespace {

Vec cross(const Vec& a, const Vec& b) {
  return {a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0]};
}
double dot(const Vec& a, const Vec& b) {
  return a[0] * b[0] + a[1] * b[1] + a[2] * b[2];
}
double norm(const Vec& a) {
  return std::sqrt(dot(a, a));
}

// `count` stored samples (signed when `representation` is 1) rescaled into HU.
void rescale(const Uint16* words, Uint16 representation, double slope, double intercept, size_t count, float* out) {
  for (size_t i = 0; i < count; ++i) {
    const double stored =
        representation == 1 ? static_cast<double>(static_cast<int16_t>(words[i])) : static_cast<double>(words[i]);
    out[i] = static_cast<float>(stored * slope + intercept);
  }
}

// One parsed instance with what the volume needs from it.
struct Slice {
  std::unique_ptr<DcmFileFormat> file;
  std::string series_uid;
  Vec row{}, column{}, position{};
  double pixel_spacing[2] = {0, 0};  // between rows, between columns
  int rows = 0, columns = 0;
  double slope = 1, intercept = 0;
  double along = 0;               // position along the slice normal
  int index = 0;                  // in the input, for messages
  const char* unit = "instance";  // what it is, for messages: an instance, or a frame of a multi-frame image
};

Result<Slice> parse(const std::string& bytes, int index) {
  const std::string name = "instance " + std::to_string(index + 1);
  Slice slice;
  slice.index = index;
  POSEWARP_ASSIGN_OR_RETURN(slice.file, parse_part10(bytes, name));
  DcmDataset& d = *slice.file->getDataset();
  slice.series_uid = text_of(d, DCM_SeriesInstanceUID);
  if (slice.series_uid.empty()) return invalid_argument_error(name + " has no SeriesInstanceUID");
  return slice;
}

// An image of the CT: modality CT, 16-bit greyscale pixels (decoded here where compressed); its rows and columns.
Status check_ct_pixels(DcmDataset& d, const std::string& name, int* rows_out, int* columns_out) {
  const std::string modality = text_of(d, DCM_Modality);
  if (modality != "CT") {
    return invalid_argument_error(name + " has modality '" + modality + "'; posewarp reads CT series here");
  }
  Uint16 rows = 0, columns = 0, bits = 0, samples = 1;
  d.findAndGetUint16(DCM_Rows, rows);
  d.findAndGetUint16(DCM_Columns, columns);
  d.findAndGetUint16(DCM_BitsAllocated, bits);
  d.findAndGetUint16(DCM_SamplesPerPixel, samples);
  if (rows == 0 || columns == 0 || bits != 16 || samples != 1) {
    return invalid_argument_error(name + " is not a 16-bit greyscale image (rows " + std::to_string(rows) +
                                  ", columns " + std::to_string(columns) + ", bits allocated " + std::to_string(bits) +
                                  ")");
  }
  *rows_out = rows, *columns_out = columns;
  // Compressed pixel data is decoded to little-endian explicit here (or refused).
  return decode_pixel_data(d, name);
}

// A slice's plane: two unit, orthogonal directions, a positive spacing and a usable rescale.
Status check_plane(const Slice& slice, const std::string& name) {
  if (std::abs(norm(slice.row) - 1) > 1e-3 || std::abs(norm(slice.column) - 1) > 1e-3 ||
      std::abs(dot(slice.row, slice.column)) > 1e-3 || slice.pixel_spacing[0] <= 0 || slice.pixel_spacing[1] <= 0) {
    return invalid_argument_error(name +
                                  " has an orientation that is not two unit, orthogonal vectors, or a "
                                  "spacing that is not positive");
  }
  if (!std::isfinite(slice.slope) || !std::isfinite(slice.intercept) || slice.slope == 0) {
    return invalid_argument_error(name + " has a rescale slope of 0 or a non-finite rescale");
  }
  return ok_status();
}

// Geometry and pixel format of a single-frame CT slice; an error naming what is missing.
Status check_slice(Slice& slice) {
  const std::string name = "instance " + std::to_string(slice.index + 1) + " of series " + slice.series_uid;
  DcmDataset& d = *slice.file->getDataset();
  double orientation[6];
  if (!numbers(&d, DCM_ImageOrientationPatient, orientation, 6) ||
      !numbers(&d, DCM_ImagePositionPatient, slice.position.data(), 3) ||
      !numbers(&d, DCM_PixelSpacing, slice.pixel_spacing, 2)) {
    return invalid_argument_error(name +
                                  " lacks ImageOrientationPatient, ImagePositionPatient or PixelSpacing: "
                                  "its place in the patient is unknown");
  }
  slice.row = {orientation[0], orientation[1], orientation[2]};
  slice.column = {orientation[3], orientation[4], orientation[5]};
  Float64 slope = 1, intercept = 0;
  if (d.findAndGetFloat64(DCM_RescaleSlope, slope).good()) slice.slope = slope;
  if (d.findAndGetFloat64(DCM_RescaleIntercept, intercept).good()) slice.intercept = intercept;
  POSEWARP_RETURN_IF_ERROR(check_plane(slice, name));
  return check_ct_pixels(d, name, &slice.rows, &slice.columns);
}

std::string describe_series(const std::map<std::string, int>& counts) {
  std::string list;
  for (const auto& [uid, count] : counts) list += "\n  " + uid + " (" + std::to_string(count) + " images)";
  return list;
}

// Every instance parsed, in input order; `counts` receives the number of instances of each series.
Result<std::vector<Slice>> parse_instances(const std::vector<std::string>& instances,
                                           std::map<std::string, int>* counts) {
  std::vector<Slice> all;
  for (size_t i = 0; i < instances.size(); ++i) {
    POSEWARP_ASSIGN_OR_RETURN(Slice slice, parse(instances[i], static_cast<int>(i)));
    ++(*counts)[slice.series_uid];
    all.push_back(std::move(slice));
  }
  return all;
}

// The series to read: `series_uid`, or the only one there is; an error listing them otherwise.
Result<std::string> choose_series(const std::map<std::string, int>& counts, const std::string& series_uid) {
  std::string uid = series_uid;
  if (uid.empty()) {
    if (counts.size() > 1) {
      return invalid_argument_error("the instances hold " + std::to_string(counts.size()) +
                                    " series; name the one to read:" + describe_series(counts));
    }
    uid = counts.begin()->first;
  } else if (!counts.count(uid)) {
    return not_found_error("series " + uid + " is not among the instances:" + describe_series(counts));
  }
  return uid;
}

// The slices, all of one orientation, size and pixel spacing (the first slice's).
Status check_one_stack(const std::vector<Slice>& slices, const std::string& uid) {
  const Slice& first = slices.front();
  for (const Slice& s : slices) {
    if (norm(cross(s.row, first.row)) > 1e-4 || norm(cross(s.column, first.column)) > 1e-4 ||
        dot(s.row, first.row) < 0 || dot(s.column, first.column) < 0) {
      return invalid_argument_error("series " + uid + " mixes image orientations (" + s.unit + " " +
                                    std::to_string(s.index + 1) + "); posewarp reads one stack of parallel slices");
    }
    if (s.rows != first.rows || s.columns != first.columns ||
        std::abs(s.pixel_spacing[0] - first.pixel_spacing[0]) > 1e-4 ||
        std::abs(s.pixel_spacing[1] - first.pixel_spacing[1]) > 1e-4) {
      return invalid_argument_error("series " + uid + " mixes image sizes or pixel spacings (" + s.unit + " " +
                                    std::to_string(s.index + 1) + ")");
    }
  }
  return ok_status();
}

// The sorted slices' spacing along the normal (1 for a single slice): even, without gaps or repeats, and the slices
// stacked straight along the normal (a tilted gantry shears them sideways).
Result<double> slice_spacing(const std::vector<Slice>& slices, const Vec& normal, const std::string& uid) {
  if (slices.size() < 2) return 1.0;
  std::vector<double> steps;
  for (size_t i = 1; i < slices.size(); ++i) steps.push_back(slices[i].along - slices[i - 1].along);
  std::vector<double> sorted = steps;
  std::nth_element(sorted.begin(), sorted.begin() + static_cast<long>(sorted.size() / 2), sorted.end());
  const double spacing = sorted[sorted.size() / 2];
  if (spacing <= 1e-6) {
    return invalid_argument_error("series " + uid +
                                  " has several images at the same position (a repeated "
                                  "acquisition or a localizer mixed in); keep one stack");
  }
  for (size_t i = 0; i < steps.size(); ++i) {
    const double at = slices[i].along;
    if (steps[i] < 1e-3 * spacing) {
      return invalid_argument_error("series " + uid + " has two images at the same position (" + std::to_string(at) +
                                    " mm along the slice normal)");
    }
    if (std::abs(steps[i] - spacing) > std::max(0.01, 0.01 * spacing)) {
      const double missing = std::round(steps[i] / spacing) - 1;
      if (missing >= 1 && std::abs(steps[i] - (missing + 1) * spacing) <= std::max(0.01, 0.01 * spacing)) {
        return invalid_argument_error("series " + uid + " misses " + std::to_string(static_cast<int>(missing)) +
                                      " slice(s) between " + std::to_string(at) + " and " +
                                      std::to_string(at + steps[i]) +
                                      " mm along the slice normal; fetch the whole series");
      }
      return invalid_argument_error("series " + uid + " has uneven slice spacing (" + std::to_string(steps[i]) +
                                    " mm where the others are " + std::to_string(spacing) +
                                    " mm); resample it to even slices first");
    }
    const Vec step{slices[i + 1].position[0] - slices[i].position[0], slices[i + 1].position[1] - slices[i].position[1],
                   slices[i + 1].position[2] - slices[i].position[2]};
    const Vec sideways = cross(step, normal);
    if (norm(sideways) > 1e-3 * norm(step) + 1e-3) {
      const double degrees = std::atan2(norm(sideways), dot(step, normal)) * 180.0 / M_PI;
      return invalid_argument_error("series " + uid + " is tilted: its slices are stacked " + std::to_string(degrees) +
                                    " degrees off their normal (gantry tilt); posewarp needs an untilted stack "
                                    "(resample the series onto an orthogonal grid first)");
    }
  }
  return spacing;
}

// The volume's grid from the sorted slices: x along the rows (columns index), y along the columns (rows index), z
// along the normal.
Result<ImageGeometry> volume_geometry(const std::vector<Slice>& slices, const Vec& normal, double spacing) {
  const Slice& first = slices.front();
  ImageGeometry g;
  g.size = {first.columns, first.rows, static_cast<int64_t>(slices.size())};
  g.spacing = {first.pixel_spacing[1], first.pixel_spacing[0], spacing};
  g.origin = {slices.front().position[0], slices.front().position[1], slices.front().position[2]};
  for (int r = 0; r < 3; ++r) {
    g.direction[static_cast<size_t>(3 * r + 0)] = first.row[static_cast<size_t>(r)];
    g.direction[static_cast<size_t>(3 * r + 1)] = first.column[static_cast<size_t>(r)];
    g.direction[static_cast<size_t>(3 * r + 2)] = normal[static_cast<size_t>(r)] / norm(normal);
  }
  POSEWARP_RETURN_IF_ERROR(g.validate());
  return g;
}

// The sorted slices' rescaled values into `out->ct` (on their grid already), their instance UIDs into `out->info`.
Status read_pixels(const std::vector<Slice>& slices, const std::string& uid, CtSeries* out) {
  const size_t per_slice = static_cast<size_t>(slices.front().rows) * static_cast<size_t>(slices.front().columns);
  for (size_t k = 0; k < slices.size(); ++k) {
    DcmDataset& d = *slices[k].file->getDataset();
    Uint16 representation = 0;
    d.findAndGetUint16(DCM_PixelRepresentation, representation);
    const Uint16* words = nullptr;
    unsigned long count = 0;
    if (d.findAndGetUint16Array(DCM_PixelData, words, &count).bad() || words == nullptr || count < per_slice) {
      return data_loss_error("instance " + std::to_string(slices[k].index + 1) + " of series " + uid +
                             " has less pixel data than its rows x columns");
    }
    rescale(words, representation, slices[k].slope, slices[k].intercept, per_slice, out->ct.data() + k * per_slice);
    out->info.sop_instance_uids.push_back(text_of(d, DCM_SOPInstanceUID));
  }
  return ok_status();
}

// Patient, study and series attributes of series `uid` from its instance `d` (not the instances' UIDs).
void read_series_info(DcmDataset& d, const std::string& uid, SeriesInfo* info) {
  info->specific_character_set = text_of(d, DCM_SpecificCharacterSet);
  info->patient_name = text_of(d, DCM_PatientName);
  info->patient_id = text_of(d, DCM_PatientID);
  info->patient_birth_date = text_of(d, DCM_PatientBirthDate);
  info->patient_sex = text_of(d, DCM_PatientSex);
  info->study_instance_uid = text_of(d, DCM_StudyInstanceUID);
  info->study_date = text_of(d, DCM_StudyDate);
  info->study_time = text_of(d, DCM_StudyTime);
  info->study_id = text_of(d, DCM_StudyID);
  info->accession_number = text_of(d, DCM_AccessionNumber);
  info->referring_physician_name = text_of(d, DCM_ReferringPhysicianName);
  info->study_description = text_of(d, DCM_StudyDescription);
  info->series_instance_uid = uid;
  info->series_number = text_of(d, DCM_SeriesNumber);
  info->series_description = text_of(d, DCM_SeriesDescription);
  info->modality = text_of(d, DCM_Modality);
  info->patient_position = text_of(d, DCM_PatientPosition);
  info->frame_of_reference_uid = text_of(d, DCM_FrameOfReferenceUID);
  info->sop_class_uid = text_of(d, DCM_SOPClassUID);
}

// A multi-frame CT image (an Enhanced CT) as the volume of its frames: each frame placed by its functional groups,
// the frames checked as one stack, sorted along their normal and rescaled.
Result<CtSeries> read_multiframe_ct(Slice& image, const std::string& uid) {
  const std::string name = "the multi-frame image of series " + uid;
  DcmDataset& d = *image.file->getDataset();
  int rows = 0, columns = 0;
  POSEWARP_RETURN_IF_ERROR(check_ct_pixels(d, name, &rows, &columns));
  POSEWARP_ASSIGN_OR_RETURN(const std::vector<FramePlane> planes, read_frame_planes(d, name));
  std::vector<Slice> frames(planes.size());
  for (size_t f = 0; f < planes.size(); ++f) {
    Slice& frame = frames[f];
    frame.index = static_cast<int>(f);
    frame.unit = "frame";
    frame.row = planes[f].row, frame.column = planes[f].column, frame.position = planes[f].position;
    frame.pixel_spacing[0] = planes[f].spacing[0], frame.pixel_spacing[1] = planes[f].spacing[1];
    frame.slope = planes[f].slope, frame.intercept = planes[f].intercept;
    frame.rows = rows, frame.columns = columns;
    POSEWARP_RETURN_IF_ERROR(check_plane(frame, name + ", frame " + std::to_string(f + 1) + ","));
  }
  POSEWARP_RETURN_IF_ERROR(check_one_stack(frames, uid));
  const Vec normal = cross(frames.front().row, frames.front().column);
  for (Slice& s : frames) s.along = dot(s.position, normal);
  std::sort(frames.begin(), frames.end(), [](const Slice& a, const Slice& b) { return a.along < b.along; });
  POSEWARP_ASSIGN_OR_RETURN(const double spacing, slice_spacing(frames, normal, uid));
  POSEWARP_ASSIGN_OR_RETURN(const ImageGeometry g, volume_geometry(frames, normal, spacing));
  const size_t per_frame = static_cast<size_t>(rows) * static_cast<size_t>(columns);
  Uint16 representation = 0;
  d.findAndGetUint16(DCM_PixelRepresentation, representation);
  const Uint16* words = nullptr;
  unsigned long count = 0;
  if (d.findAndGetUint16Array(DCM_PixelData, words, &count).bad() || words == nullptr ||
      count < per_frame * frames.size()) {
    return data_loss_error(name + " has less pixel data than its frames x rows x columns");
  }
  CtSeries out;
  out.ct = IntensityVolume(g);
  out.ct.set_source_type(PixelType::kInt16);
  for (size_t k = 0; k < frames.size(); ++k) {
    rescale(words + static_cast<size_t>(frames[k].index) * per_frame, representation, frames[k].slope,
            frames[k].intercept, per_frame, out.ct.data() + k * per_frame);
    out.info.frame_numbers.push_back(frames[k].index + 1);
  }
  read_series_info(d, uid, &out.info);
  out.info.sop_instance_uids = {text_of(d, DCM_SOPInstanceUID)};
  return out;
}

}  // namespace

// An error unless the grid can be written as a derived CT series of `source`.
Status check_derived_input(const ImageGeometry& g, const SeriesInfo& source) {
  POSEWARP_RETURN_IF_ERROR(g.validate());
  if (g.size[0] > 65535 || g.size[1] > 65535) {
    return invalid_argument_error("a DICOM image has at most 65535 rows and columns; this grid is " +
                                  std::to_string(g.size[0]) + " x " + std::to_string(g.size[1]));
  }
  if (source.study_instance_uid.empty()) return invalid_argument_error("the source series has no StudyInstanceUID");
  return ok_status();
}

// The row, column and slice directions of `g`, and whether its slices go out in reverse order.
SliceAxes slice_axes(const ImageGeometry& g) {
  SliceAxes axes;
  axes.row = {g.direction[0], g.direction[3], g.direction[6]};
  axes.column = {g.direction[1], g.direction[4], g.direction[7]};
  axes.slice_axis = {g.direction[2], g.direction[5], g.direction[8]};
  axes.reverse = written_in_reverse(g);
  return axes;
}

// The derived series: the source's patient and study, a new series (UID, number, description), no instances yet.
Result<SeriesInfo> derived_series_info(const SeriesInfo& source, const DerivedSeriesOptions& options) {
  SeriesInfo info = source;
  POSEWARP_ASSIGN_OR_RETURN(info.series_instance_uid, uid_for(options, "ct-series"));
  const int source_number = std::atoi(source.series_number.c_str());
  info.series_number = std::to_string(options.series_number > 0 ? options.series_number : source_number + 1000);
  info.series_description = options.series_description.empty() ? "posewarp derived" : options.series_description;
  info.modality = "CT";
  info.sop_class_uid = UID_CTImageStorage;
  if (info.frame_of_reference_uid.empty()) {
    POSEWARP_ASSIGN_OR_RETURN(info.frame_of_reference_uid, uid_for(options, "frame-of-reference"));
  }
  info.sop_instance_uids.clear();
  info.frame_numbers.clear();
  return info;
}

// The instance's identity, the source's patient and study, and the new series.
void put_series_attributes(DcmDataset& d, const SeriesInfo& info, const DerivedSeriesOptions& options,
                           const DerivedInstance& instance) {
  // Optional attributes, written only when the source has them (a dataset keeps its elements in tag order, so the
  // order of the puts does not matter).
  if (!info.specific_character_set.empty()) put(d, DCM_SpecificCharacterSet, info.specific_character_set);
  if (!info.study_description.empty()) put(d, DCM_StudyDescription, info.study_description);
  if (!options.derivation_description.empty()) put(d, DCM_DerivationDescription, options.derivation_description);
  const std::pair<DcmTagKey, std::string> attributes[] = {
      {DCM_SOPClassUID, info.sop_class_uid},
      {DCM_SOPInstanceUID, instance.sop_uid},
      {DCM_ImageType, "DERIVED\\SECONDARY\\AXIAL"},
      {DCM_InstanceCreationDate, instance.date},
      {DCM_InstanceCreationTime, instance.time},
      {DCM_ContentDate, instance.date},
      {DCM_ContentTime, instance.time},
      // Patient and study: the source's.
      {DCM_PatientName, info.patient_name},
      {DCM_PatientID, info.patient_id},
      {DCM_PatientBirthDate, info.patient_birth_date},
      {DCM_PatientSex, info.patient_sex},
      {DCM_StudyInstanceUID, info.study_instance_uid},
      {DCM_StudyDate, info.study_date},
      {DCM_StudyTime, info.study_time},
      {DCM_StudyID, info.study_id},
      {DCM_AccessionNumber, info.accession_number},
      {DCM_ReferringPhysicianName, info.referring_physician_name},
      // The new series.
      {DCM_Modality, "CT"},
      {DCM_Laterality, ""},
      {DCM_PatientPosition, info.patient_position},
      {DCM_SeriesInstanceUID, info.series_instance_uid},
      {DCM_SeriesNumber, info.series_number},
      {DCM_SeriesDescription, info.series_description},
      {DCM_SeriesDate, instance.date},
      {DCM_SeriesTime, instance.time},
      {DCM_FrameOfReferenceUID, info.frame_of_reference_uid},
      {DCM_PositionReferenceIndicator, ""},
      {DCM_Manufacturer, "posewarp"},
      {DCM_InstanceNumber, std::to_string(instance.index + 1)},
      {DCM_KVP, ""},
      {DCM_AcquisitionNumber, ""},
  };
  for (const auto& [tag, value] : attributes) put(d, tag, value);
}

void put_hu_pixel_module(DcmItem& d, const ImageGeometry& g) {
  d.putAndInsertUint16(DCM_SamplesPerPixel, 1);
  put(d, DCM_PhotometricInterpretation, "MONOCHROME2");
  d.putAndInsertUint16(DCM_Rows, static_cast<Uint16>(g.size[1]));
  d.putAndInsertUint16(DCM_Columns, static_cast<Uint16>(g.size[0]));
  d.putAndInsertUint16(DCM_BitsAllocated, 16);
  d.putAndInsertUint16(DCM_BitsStored, 16);
  d.putAndInsertUint16(DCM_HighBit, 15);
  d.putAndInsertUint16(DCM_PixelRepresentation, 1);
}

int64_t hu_samples(const IntensityVolume& ct, int64_t k, int16_t* out) {
  const ImageGeometry& g = ct.geometry();
  const size_t per_slice = static_cast<size_t>(g.size[0] * g.size[1]);
  int64_t clipped = 0;
  const float* slice = ct.data() + static_cast<size_t>(k) * per_slice;
  for (size_t i = 0; i < per_slice; ++i) {
    // Half away from zero, as the volume writers round (io: lround): a posed value of exactly -118.5 is -119 in the
    // series and in the NIfTI of the same pose alike.
    const float v = std::isfinite(slice[i]) ? std::round(slice[i]) : 0.0f;
    const float bounded = std::clamp(v, -32768.0f, 32767.0f);
    clipped += bounded != v;
    out[i] = static_cast<int16_t>(bounded);
  }
  return clipped;
}

namespace {

// Where it came from: every source image, in each slice (each posed slice draws on all of them), and the source
// series with its instances (Common Instance Reference).
void put_source_references(DcmDataset& d, const SeriesInfo& source) {
  const char* source_class = source.sop_class_uid.empty() ? UID_CTImageStorage : source.sop_class_uid.c_str();
  DcmItem* series_item = nullptr;
  if (!source.sop_instance_uids.empty() &&
      d.findOrCreateSequenceItem(DCM_ReferencedSeriesSequence, series_item, -2).good()) {
    series_item->putAndInsertString(DCM_SeriesInstanceUID, source.series_instance_uid.c_str());
  }
  for (const std::string& source_uid : source.sop_instance_uids) {
    for (auto [parent, sequence] : {std::pair<DcmItem*, DcmTagKey>{&d, DCM_SourceImageSequence},
                                    std::pair<DcmItem*, DcmTagKey>{series_item, DCM_ReferencedInstanceSequence}}) {
      DcmItem* item = nullptr;
      if (parent != nullptr && parent->findOrCreateSequenceItem(sequence, item, -2).good()) {
        item->putAndInsertString(DCM_ReferencedSOPClassUID, source_class);
        item->putAndInsertString(DCM_ReferencedSOPInstanceUID, source_uid.c_str());
      }
    }
  }
}

// The place of slice `k` of `g` in the patient: orientation, position, spacing, thickness and location.
void put_slice_geometry(DcmDataset& d, const ImageGeometry& g, const SliceAxes& axes, int64_t k) {
  const Vec &row = axes.row, &column = axes.column, &slice_axis = axes.slice_axis;
  const double offset = static_cast<double>(k) * g.spacing[2];
  const Vec position{g.origin[0] + offset * slice_axis[0], g.origin[1] + offset * slice_axis[1],
                     g.origin[2] + offset * slice_axis[2]};
  char value[256];
  std::snprintf(value, sizeof value, "%.6f\\%.6f\\%.6f\\%.6f\\%.6f\\%.6f", row[0], row[1], row[2], column[0], column[1],
                column[2]);
  put(d, DCM_ImageOrientationPatient, value);
  std::snprintf(value, sizeof value, "%.6f\\%.6f\\%.6f", position[0], position[1], position[2]);
  put(d, DCM_ImagePositionPatient, value);
  std::snprintf(value, sizeof value, "%.6f\\%.6f", g.spacing[1], g.spacing[0]);
  put(d, DCM_PixelSpacing, value);
  std::snprintf(value, sizeof value, "%.6f", g.spacing[2]);
  put(d, DCM_SliceThickness, value);
  std::snprintf(value, sizeof value, "%.6f", dot(position, cross(row, column)));
  put(d, DCM_SliceLocation, value);
}

// Slice `k` of `ct` as int16 HU pixels, rescale 1 and 0; the number of values clipped to fit int16.
int64_t put_ct_pixels(DcmDataset& d, const IntensityVolume& ct, int64_t k) {
  const ImageGeometry& g = ct.geometry();
  put_hu_pixel_module(d, g);
  put(d, DCM_RescaleIntercept, "0");
  put(d, DCM_RescaleSlope, "1");
  put(d, DCM_RescaleType, "HU");
  put(d, DCM_WindowCenter, "40");
  put(d, DCM_WindowWidth, "400");
  const size_t per_slice = static_cast<size_t>(g.size[0] * g.size[1]);
  std::vector<int16_t> samples(per_slice);
  const int64_t clipped = hu_samples(ct, k, samples.data());
  // Pixel data is OW: the signed samples' 16-bit words (PixelRepresentation 1 says how to read them).
  d.putAndInsertUint16Array(DCM_PixelData, reinterpret_cast<const Uint16*>(samples.data()),
                            static_cast<unsigned long>(per_slice));
  return clipped;
}

}  // namespace

Result<CtSeries> read_ct_series(const std::vector<std::string>& instances, const std::string& series_uid) {
  quiet_dcmtk();
  if (instances.empty()) return invalid_argument_error("no DICOM instances to read");
  std::map<std::string, int> counts;
  POSEWARP_ASSIGN_OR_RETURN(std::vector<Slice> all, parse_instances(instances, &counts));
  POSEWARP_ASSIGN_OR_RETURN(const std::string uid, choose_series(counts, series_uid));
  std::vector<Slice> slices;
  for (Slice& s : all) {
    if (s.series_uid == uid) slices.push_back(std::move(s));
  }
  for (Slice& s : slices) {
    Sint32 frames = 1;
    if (s.file->getDataset()->findAndGetSint32(DCM_NumberOfFrames, frames).good() && frames > 1) {
      if (slices.size() > 1) {
        return invalid_argument_error("series " + uid + " holds " + std::to_string(slices.size()) +
                                      " images, some of them multi-frame; posewarp reads one multi-frame image "
                                      "(an Enhanced CT) or a series of single-frame ones");
      }
      POSEWARP_ASSIGN_OR_RETURN(CtSeries out, read_multiframe_ct(s, uid));
      if (out.info.study_instance_uid.empty()) {
        return invalid_argument_error("series " + uid + " has no StudyInstanceUID");
      }
      return out;
    }
  }
  for (Slice& s : slices) POSEWARP_RETURN_IF_ERROR(check_slice(s));
  const Vec normal = cross(slices.front().row, slices.front().column);
  POSEWARP_RETURN_IF_ERROR(check_one_stack(slices, uid));
  for (Slice& s : slices) s.along = dot(s.position, normal);
  std::sort(slices.begin(), slices.end(), [](const Slice& a, const Slice& b) { return a.along < b.along; });
  POSEWARP_ASSIGN_OR_RETURN(const double spacing, slice_spacing(slices, normal, uid));
  POSEWARP_ASSIGN_OR_RETURN(const ImageGeometry g, volume_geometry(slices, normal, spacing));
  CtSeries out;
  out.ct = IntensityVolume(g);
  out.ct.set_source_type(PixelType::kInt16);
  POSEWARP_RETURN_IF_ERROR(read_pixels(slices, uid, &out));
  read_series_info(*slices.front().file->getDataset(), uid, &out.info);
  if (out.info.study_instance_uid.empty()) return invalid_argument_error("series " + uid + " has no StudyInstanceUID");
  return out;
}

bool is_dicom_file(const std::string& path) {
  std::error_code ec;
  if (!fs::is_regular_file(path, ec)) return false;
  std::ifstream in(path, std::ios::binary);
  char head[132];
  return in.read(head, sizeof head) && std::string(head + 128, 4) == "DICM";
}

Result<std::vector<std::string>> list_dicom_files(const std::string& path) {
  std::error_code ec;
  std::vector<std::string> files;
  if (fs::is_directory(path, ec)) {
    for (const auto& entry : fs::directory_iterator(path, ec)) {
      if (is_dicom_file(entry.path().string())) files.push_back(entry.path().string());
    }
  } else if (is_dicom_file(path)) {
    files.push_back(path);
  }
  if (files.empty()) {
    return not_found_error("'" + path +
                           "' is not a DICOM file (Part 10, with a DICM preamble) or a directory holding some");
  }
  std::sort(files.begin(), files.end());
  return files;
}

Result<std::vector<std::string>> read_dicom_files(const std::string& path) {
  POSEWARP_ASSIGN_OR_RETURN(const std::vector<std::string> files, list_dicom_files(path));
  std::vector<std::string> instances;
  for (const std::string& file : files) {
    std::string bytes;
    POSEWARP_ASSIGN_OR_RETURN(bytes, read_text_input(file, "DICOM file", int64_t{1} << 31));
    instances.push_back(std::move(bytes));
  }
  return instances;
}

Result<CtSeries> read_ct_directory(const std::string& directory, const std::string& series_uid) {
  std::error_code ec;
  if (!fs::is_directory(directory, ec)) return not_found_error("'" + directory + "' is not a directory of DICOM files");
  POSEWARP_ASSIGN_OR_RETURN(const std::vector<std::string> instances, read_dicom_files(directory));
  return read_ct_series(instances, series_uid);
}

Result<std::vector<std::string>> encode_derived_ct(const IntensityVolume& ct, const SeriesInfo& source,
                                                   const DerivedSeriesOptions& options, SeriesInfo* info_out) {
  quiet_dcmtk();
  if (options.ct_format == CtFormat::kEnhanced) {
    POSEWARP_ASSIGN_OR_RETURN(std::string image, encode_enhanced_ct(ct, source, options, info_out));
    return std::vector<std::string>{std::move(image)};
  }
  const ImageGeometry& g = ct.geometry();
  POSEWARP_RETURN_IF_ERROR(check_derived_input(g, source));
  const SliceAxes axes = slice_axes(g);
  POSEWARP_ASSIGN_OR_RETURN(SeriesInfo info, derived_series_info(source, options));
  DerivedInstance instance;
  instance.date = utc_now("%Y%m%d");
  instance.time = utc_now("%H%M%S");
  std::vector<std::string> files;
  int64_t clipped = 0;
  for (int64_t n = 0; n < g.size[2]; ++n) {
    instance.index = n;
    instance.slice = axes.reverse ? g.size[2] - 1 - n : n;
    POSEWARP_ASSIGN_OR_RETURN(instance.sop_uid, uid_for(options, "ct/" + std::to_string(n)));
    DcmFileFormat file;
    DcmDataset& d = *file.getDataset();
    put_series_attributes(d, info, options, instance);
    put_source_references(d, source);
    put_slice_geometry(d, g, axes, instance.slice);
    clipped += put_ct_pixels(d, ct, instance.slice);
    POSEWARP_ASSIGN_OR_RETURN(std::string bytes, encode_part10(file, "DICOM slice " + std::to_string(n + 1)));
    files.push_back(std::move(bytes));
    info.sop_instance_uids.push_back(instance.sop_uid);
  }
  if (clipped > 0) {
    return out_of_range_error(std::to_string(clipped) +
                              " CT values do not fit int16 (-32768..32767); a DICOM CT "
                              "series cannot hold them");
  }
  if (info_out != nullptr) *info_out = info;
  return files;
}

Result<SeriesInfo> write_derived_ct(const IntensityVolume& ct, const SeriesInfo& source,
                                    const DerivedSeriesOptions& options, const std::string& directory) {
  std::error_code ec;
  if (fs::exists(directory, ec) && !fs::is_empty(directory, ec)) {
    return already_exists_error("DICOM output directory '" + directory + "' is not empty; choose a new one");
  }
  SeriesInfo info;
  POSEWARP_ASSIGN_OR_RETURN(std::vector<std::string> files, encode_derived_ct(ct, source, options, &info));
  fs::create_directories(directory, ec);
  if (ec) return invalid_argument_error("cannot make the directory '" + directory + "': " + ec.message());
  for (size_t i = 0; i < files.size(); ++i) {
    char name[32];
    std::snprintf(name, sizeof name, "CT%06zu.dcm", i + 1);
    POSEWARP_RETURN_IF_ERROR(write_file_atomically((fs::path(directory) / name).string(), files[i], "DICOM slice"));
  }
  return info;
}

}  // namespace posewarp::dicom
