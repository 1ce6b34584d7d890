// DICOM studies for PACS-side work, through the engine facade: a CT series and its SEG read as a study whose label
// map follows the segments' names, and a pose's CT and labels written back as a derived CT series and a SEG of the
// same patient and study.
#pragma once

#include <string>
#include <vector>

#include "posewarp/dicom/ct_series.h"
#include "posewarp/dicom/segmentation.h"
#include "posewarp/labels/label_map.h"

namespace posewarp::api {

using dicom::CtSeries;
using dicom::DerivedSeriesOptions;
using dicom::encode_derived_ct;
using dicom::encode_segmentation;
using dicom::is_dicom_file;
using dicom::new_uid;
using dicom::read_ct_directory;
using dicom::read_ct_series;
using dicom::list_dicom_files;
using dicom::read_dicom_files;
using dicom::read_segmentation;
using dicom::Segment;
using dicom::Segmentation;
using dicom::SeriesInfo;
using dicom::write_derived_ct;

struct DicomStudy {
  CtSeries ct;                 // the CT (HU) and its series: patient, study, instances
  LabelVolume labels;          // on the CT's grid; each voxel its segment's number
  labels::LabelMap label_map;  // the map given, following the segments' names to their numbers
  std::vector<Segment> segments;
  std::vector<std::string> warnings;  // fractional segments thresholded, overlaps, names the map does not know
};

// A CT series (a directory of its files) and a SEG (a file) made on it; `map` (a preset or one's own) is
// relabelled by the segments' names (labels::relabel_by_name).
Result<DicomStudy> read_dicom_study(const std::string& ct_directory, const std::string& seg_path,
                                    const labels::LabelMap& map);
// The same from instances in memory (as a PACS sends them).
Result<DicomStudy> read_dicom_study(const std::vector<std::string>& ct_instances, const std::string& seg_bytes,
                                    const labels::LabelMap& map);

// A pose's CT and labels as DICOM of `source`'s study: a derived CT series and a SEG on it, whose segments are
// named by `map` (each label value present a segment).
struct DicomOutputs {
  SeriesInfo ct, seg;
  std::vector<std::string> ct_files;  // Part 10 bytes, one per slice
  std::string seg_file;
};
Result<DicomOutputs> encode_dicom_outputs(const IntensityVolume& ct, const LabelVolume& labels,
                                          const labels::LabelMap& map, const SeriesInfo& source,
                                          const DerivedSeriesOptions& options);
// Writes DIR/ct/CT000001.dcm ... and DIR/seg.dcm (DIR made; it must be empty or missing).
Status write_dicom_outputs(const DicomOutputs& outputs, const std::string& dir);

// A study that never was DICOM (NIfTI, NRRD, ...) as a new DICOM study: a CT series and its SEG, segments named by
// `map`, patient as given; for a PACS to hold the sample, or for tests.
Result<DicomOutputs> encode_new_dicom_study(const IntensityVolume& ct, const LabelVolume& labels,
                                            const labels::LabelMap& map, const std::string& patient_name,
                                            const std::string& patient_id, const DerivedSeriesOptions& options);

}  // namespace posewarp::api
