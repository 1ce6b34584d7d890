// The facade's DICOM: studies read with their label maps, poses written as derived series.
#include "posewarp/api/dicom.h"

#include <filesystem>
#include <fstream>
#include <map>

#include "posewarp/common/atomic_file.h"
#include "posewarp/common/input_file.h"
#include "posewarp/dicom/ct_series.h"
#include "posewarp/dicom/segmentation.h"
#include "posewarp/labels/label_map.h"

namespace posewarp::api {
namespace fs = std::filesystem;

namespace {

std::vector<DicomSegment> segments_named_by(const LabelVolume& labels, const labels::LabelMap& map) {
  std::map<Label, bool> present;
  for (Label v : labels.voxels()) {
    if (v != 0) present[v] = true;
  }
  std::vector<DicomSegment> segments;
  for (const auto& [value, yes] : present) {
    DicomSegment s;
    s.number = value;
    const labels::LabelEntry* entry = map.find(value);
    s.label = entry != nullptr ? entry->name : "label " + std::to_string(value);
    if (entry != nullptr && entry->role == labels::LabelRole::kBone) {
      s.category = {"123037004", "SCT", "Anatomical Structure"};
      s.type = {"272673000", "SCT", "Bone"};
    }
    segments.push_back(s);
  }
  return segments;
}

}  // namespace

bool is_dicom_file(const std::string& path) { return dicom::is_dicom_file(path); }

Result<std::vector<std::string>> list_dicom_files(const std::string& path) { return dicom::list_dicom_files(path); }

Result<CtSeries> read_ct_directory(const std::string& directory, const std::string& series_uid) {
  return dicom::read_ct_directory(directory, series_uid);
}

Result<DicomStudy> read_dicom_study(const std::vector<std::string>& ct_instances, const std::string& seg_bytes,
                                    const labels::LabelMap& map) {
  DicomStudy study;
  POSEWARP_ASSIGN_OR_RETURN(study.ct, dicom::read_ct_series(ct_instances));
  POSEWARP_ASSIGN_OR_RETURN(dicom::Segmentation seg, dicom::read_segmentation(seg_bytes, study.ct.ct.geometry()));
  if (!seg.referenced_series_uid.empty() && seg.referenced_series_uid != study.ct.info.series_instance_uid) {
    study.warnings.push_back("the segmentation references series " + seg.referenced_series_uid + ", not " +
                             study.ct.info.series_instance_uid + " (its frames lie on this CT's grid all the same)");
  }
  std::vector<std::pair<Label, std::string>> names;
  for (const DicomSegment& s : seg.segments) names.emplace_back(s.number, s.label);
  std::vector<std::string> unknown;
  POSEWARP_ASSIGN_OR_RETURN(study.label_map, labels::relabel_by_name(map, names, &unknown));
  for (const std::string& name : unknown) {
    study.warnings.push_back("segment '" + name + "' is not in the label map '" + map.name() +
                             "': taken as soft tissue");
  }
  study.labels = std::move(seg.labels);
  study.segments = std::move(seg.segments);
  study.warnings.insert(study.warnings.end(), seg.warnings.begin(), seg.warnings.end());
  return study;
}

Result<DicomStudy> read_dicom_study(const std::string& ct_directory, const std::string& seg_path,
                                    const labels::LabelMap& map) {
  std::error_code ec;
  if (!fs::is_directory(ct_directory, ec)) {
    return not_found_error("'" + ct_directory + "' is not a directory of DICOM files (the CT series)");
  }
  std::string seg_bytes;
  POSEWARP_ASSIGN_OR_RETURN(seg_bytes, read_text_input(seg_path, "DICOM SEG file", int64_t{1} << 32));
  POSEWARP_ASSIGN_OR_RETURN(const std::vector<std::string> instances, dicom::read_dicom_files(ct_directory));
  return read_dicom_study(instances, seg_bytes, map);
}

Result<DicomOutputs> encode_dicom_outputs(const IntensityVolume& ct, const LabelVolume& labels,
                                          const labels::LabelMap& map, const SeriesInfo& source,
                                          const DerivedSeriesOptions& options) {
  if (!ct.geometry().same_grid(labels.geometry())) {
    return invalid_argument_error("the posed CT and labels are on different grids; a SEG must lie on its CT's grid");
  }
  DicomOutputs out;
  POSEWARP_ASSIGN_OR_RETURN(out.ct_files, dicom::encode_derived_ct(ct, source, options, &out.ct));
  DerivedSeriesOptions seg_options = options;
  seg_options.series_number = std::atoi(out.ct.series_number.c_str()) + 1;
  seg_options.series_description =
      (options.series_description.empty() ? std::string("posewarp") : options.series_description) + " labels";
  POSEWARP_ASSIGN_OR_RETURN(
      out.seg_file, dicom::encode_segmentation(labels, segments_named_by(labels, map), out.ct, seg_options, &out.seg));
  return out;
}

Status write_dicom_outputs(const DicomOutputs& outputs, const std::string& dir) {
  std::error_code ec;
  if (fs::exists(dir, ec) && !fs::is_empty(dir, ec)) {
    return already_exists_error("DICOM output directory '" + dir + "' is not empty; choose a new one");
  }
  fs::create_directories(fs::path(dir) / "ct", ec);
  if (ec) return invalid_argument_error("cannot make the directory '" + dir + "': " + ec.message());
  for (size_t i = 0; i < outputs.ct_files.size(); ++i) {
    char name[32];
    std::snprintf(name, sizeof name, "CT%06zu.dcm", i + 1);
    POSEWARP_RETURN_IF_ERROR(
        write_file_atomically((fs::path(dir) / "ct" / name).string(), outputs.ct_files[i], "DICOM slice"));
  }
  return write_file_atomically((fs::path(dir) / "seg.dcm").string(), outputs.seg_file, "DICOM SEG");
}

Result<DicomOutputs> encode_new_dicom_study(const IntensityVolume& ct, const LabelVolume& labels,
                                            const labels::LabelMap& map, const std::string& patient_name,
                                            const std::string& patient_id, const DerivedSeriesOptions& options) {
  SeriesInfo study;
  study.patient_name = patient_name;
  study.patient_id = patient_id;
  POSEWARP_ASSIGN_OR_RETURN(study.study_instance_uid, dicom::new_uid(options.uid_root));
  POSEWARP_ASSIGN_OR_RETURN(study.series_instance_uid, dicom::new_uid(options.uid_root));
  POSEWARP_ASSIGN_OR_RETURN(study.frame_of_reference_uid, dicom::new_uid(options.uid_root));
  study.study_id = std::string(1, '1');  // (a one-character literal here trips GCC 12's -Wrestrict)
  study.series_number = std::string(1, '0');
  study.patient_position = "HFS";
  DerivedSeriesOptions first = options;
  first.series_number = options.series_number > 0 ? options.series_number : 1;
  if (first.series_description.empty()) first.series_description = "CT";
  return encode_dicom_outputs(ct, labels, map, study, first);
}

}  // namespace posewarp::api
