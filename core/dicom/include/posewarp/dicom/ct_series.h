// DICOM CT series in and out, for PACS-side work (DCMTK): a series read from files or from instances in memory (as
// a PACS sends them), sorted by position with its geometry checked and its rescale applied; a posed CT written back
// as a derived series of the same study that any DICOM viewer opens beside the original.
#pragma once

#include <string>
#include <vector>

#include "posewarp/common/result.h"
#include "posewarp/common/status.h"
#include "posewarp/common/volume.h"

namespace posewarp::dicom {

// What a derived series takes from its source: patient, study, series and the instances it came from.
struct SeriesInfo {
  std::string specific_character_set;
  std::string patient_name, patient_id, patient_birth_date, patient_sex;
  std::string study_instance_uid, study_date, study_time, study_id, accession_number, referring_physician_name,
      study_description;
  std::string series_instance_uid, series_number, series_description, modality, frame_of_reference_uid;
  std::string patient_position;  // HFS, FFS, ... (as the patient lay in the scanner)
  std::string sop_class_uid;
  std::vector<std::string> sop_instance_uids;  // in slice order (along the slice normal)
};

struct CtSeries {
  IntensityVolume ct;  // Hounsfield units (each slice's rescale applied), on a right-handed LPS grid
  SeriesInfo info;
};

// A CT series from Part 10 files' bytes (one single-frame image each). Several series: `series_uid` names the one
// to read (an error lists them otherwise). Refused with a message: missing geometry, multi-frame images, other
// modalities, mixed orientations or sizes, gantry tilt, missing or duplicated slices, uneven slice spacing,
// compressed pixel data without a decoder.
Result<CtSeries> read_ct_series(const std::vector<std::string>& instances, const std::string& series_uid = "");
// True when `path` is a regular file that starts as a DICOM Part 10 file (a 128-byte preamble, then "DICM").
bool is_dicom_file(const std::string& path);
// A DICOM file, or a directory's DICOM files in name order (other files and subdirectories are skipped); NOT_FOUND
// when there are none.
Result<std::vector<std::string>> list_dicom_files(const std::string& path);
// The bytes of those files.
Result<std::vector<std::string>> read_dicom_files(const std::string& path);
// read_ct_series from a directory's DICOM files.
Result<CtSeries> read_ct_directory(const std::string& directory, const std::string& series_uid = "");

// How a derived series is named and numbered.
struct DerivedSeriesOptions {
  // New UIDs are this root, a dot and a number: "2.25" (the default) makes UUID-derived UIDs that need no
  // registered root; an organisation's own root works the same way. At most 40 characters.
  std::string uid_root = "2.25";
  std::string series_description;      // e.g. "posewarp: knee bent (CoR)"
  std::string derivation_description;  // e.g. the pose and method in words
  int series_number = 0;               // 0: the source's number + 1000
  // Non-empty: every new UID is derived from this text (and what it names) instead of drawn at random, so writing
  // the same result again gives the same UIDs (a PACS then replaces, never duplicates; a batch uses its row's key).
  std::string uid_seed;
};

// A new UID under `root` (see DerivedSeriesOptions::uid_root); at most 64 characters.
Result<std::string> new_uid(const std::string& root);
// The UID `options` give the thing `purpose` names ("ct-series", "ct/12", ...): derived from options.uid_seed when
// set, else new.
Result<std::string> uid_for(const DerivedSeriesOptions& options, const std::string& purpose);

// `ct` as a derived CT series of `source`'s study (same patient and study, new series and instance UIDs, ImageType
// DERIVED\SECONDARY\AXIAL, the original series referenced, every source instance in each slice's Source Image Sequence,
// int16 samples with rescale slope 1 and intercept 0), one Part 10 file's bytes per slice in slice order. A left-
// handed grid is written with its slices in reverse order. `info` (optional) receives the new series' description.
Result<std::vector<std::string>> encode_derived_ct(const IntensityVolume& ct, const SeriesInfo& source,
                                                   const DerivedSeriesOptions& options, SeriesInfo* info = nullptr);
// The same written into `directory` (made; it must be empty or missing), one file per slice named by instance
// number, each written beside its name and renamed.
Result<SeriesInfo> write_derived_ct(const IntensityVolume& ct, const SeriesInfo& source,
                                    const DerivedSeriesOptions& options, const std::string& directory);

// DCMTK's own console log off (every function here calls it; posewarp reports errors and warnings itself).
void quiet_dcmtk();

}  // namespace posewarp::dicom
