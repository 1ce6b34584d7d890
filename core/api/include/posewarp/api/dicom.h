// DICOM studies for PACS-side work, through the engine facade: a CT series and its SEG read as a study whose label
// map follows the segments' names, and a pose's CT and labels written back as a derived CT series and a SEG of the
// same patient and study.
#pragma once

#include <string>
#include <vector>

#include "posewarp/common/dicom_series.h"
#include "posewarp/common/label_map.h"
#include "posewarp/common/result.h"
#include "posewarp/common/volume.h"

namespace posewarp::api {

using posewarp::CtFormat;
using posewarp::CtSeries;
using posewarp::DerivedSeriesOptions;
using posewarp::DicomSegment;
using posewarp::SegFormat;
using posewarp::SeriesInfo;

// True when `path` is a regular file that starts as a DICOM Part 10 file (a 128-byte preamble, then "DICM").
bool is_dicom_file(const std::string& path);
// A DICOM file, or a directory's DICOM files in name order (other files and subdirectories are skipped); NOT_FOUND
// when there are none.
Result<std::vector<std::string>> list_dicom_files(const std::string& path);
// A CT series (HU, on a right-handed LPS grid) from a directory's DICOM files; `series_uid` picks one of several.
Result<CtSeries> read_ct_directory(const std::string& directory, const std::string& series_uid = "");

struct DicomStudy {
  CtSeries ct;                 // the CT (HU) and its series: patient, study, instances
  LabelVolume labels;          // on the CT's grid; each voxel its segment's number
  LabelMap label_map;  // the map given, following the segments' names to their numbers
  std::vector<DicomSegment> segments;
  std::vector<std::string> warnings;  // fractional segments thresholded, overlaps, names the map does not know
};

// A CT series (a directory of its files) and a SEG (a file) made on it; `map` (a preset or one's own) is
// relabelled by the segments' names (labels::relabel_by_name).
Result<DicomStudy> read_dicom_study(const std::string& ct_directory, const std::string& seg_path,
                                    const LabelMap& map);
// The same from instances in memory (as a PACS sends them).
Result<DicomStudy> read_dicom_study(const std::vector<std::string>& ct_instances, const std::string& seg_bytes,
                                    const LabelMap& map);

// A pose's CT and labels as DICOM of `source`'s study: a derived CT series and a SEG on it, whose segments are
// named by `map` (each label value present a segment), in the formats options.ct_format and options.seg_format
// name.
struct DicomOutputs {
  SeriesInfo ct, seg;
  std::vector<std::string> ct_files;  // Part 10 bytes, one per slice (one Enhanced CT: one)
  std::string seg_file;
};
Result<DicomOutputs> encode_dicom_outputs(const IntensityVolume& ct, const LabelVolume& labels,
                                          const LabelMap& map, const SeriesInfo& source,
                                          const DerivedSeriesOptions& options);
// Writes DIR/ct/CT000001.dcm ... and DIR/seg.dcm (DIR made; it must be empty or missing).
Status write_dicom_outputs(const DicomOutputs& outputs, const std::string& dir);

// A study that never was DICOM (NIfTI, NRRD, ...) as a new DICOM study: a CT series and its SEG, segments named by
// `map`, patient as given; for a PACS to hold the sample, or for tests.
Result<DicomOutputs> encode_new_dicom_study(const IntensityVolume& ct, const LabelVolume& labels,
                                            const LabelMap& map, const std::string& patient_name,
                                            const std::string& patient_id, const DerivedSeriesOptions& options);

}  // namespace posewarp::api
