// DICOM CT series in and out, for PACS-side work (DCMTK): a series read from files or from instances in memory (as
// a PACS sends them), sorted by position with its geometry checked and its rescale applied; a posed CT written back
// as a derived series of the same study that any DICOM viewer opens beside the original.
#pragma once

#include <string>
#include <vector>

#include "posewarp/common/dicom_series.h"
#include "posewarp/common/result.h"
#include "posewarp/common/status.h"
#include "posewarp/common/volume.h"

namespace posewarp::dicom {

// A series, its CT and the options of a derived series are vocabulary (posewarp/common/dicom_series.h).
using posewarp::CtSeries;
using posewarp::DerivedSeriesOptions;
using posewarp::SeriesInfo;

// A CT series from Part 10 files' bytes: single-frame images, one per slice, or one multi-frame image (an Enhanced
// CT) whose frames are the slices. Several series: `series_uid` names the one to read (an error lists them
// otherwise). Refused with a message: missing geometry, multi-frame images mixed with others, other modalities, mixed
// orientations or sizes, gantry tilt, missing or duplicated slices, uneven slice spacing, compressed pixel data
// without a decoder.
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

// A new UID under `root` (see DerivedSeriesOptions::uid_root); at most 64 characters.
Result<std::string> new_uid(const std::string& root);
// The UID `options` give the thing `purpose` names ("ct-series", "ct/12", ...): derived from options.uid_seed when
// set, else new.
Result<std::string> uid_for(const DerivedSeriesOptions& options, const std::string& purpose);

// `ct` as a derived CT series of `source`'s study (same patient and study, new series and instance UIDs, the
// original series referenced, every source image in each slice's derivation, int16 samples with rescale slope 1 and
// intercept 0). options.ct_format says how: single-frame CT images (ImageType DERIVED\SECONDARY\AXIAL), one Part 10
// file's bytes per slice in slice order; or one multi-frame Enhanced CT image (DERIVED\PRIMARY\VOLUME\NONE), one
// file. A left-handed grid is written with its slices in reverse order. `info` (optional) receives the new series'
// description (an Enhanced CT's: its frame numbers too).
Result<std::vector<std::string>> encode_derived_ct(const IntensityVolume& ct, const SeriesInfo& source,
                                                   const DerivedSeriesOptions& options, SeriesInfo* info = nullptr);
// The same written into `directory` (made; it must be empty or missing), one file per slice named by instance
// number, each written beside its name and renamed.
Result<SeriesInfo> write_derived_ct(const IntensityVolume& ct, const SeriesInfo& source,
                                    const DerivedSeriesOptions& options, const std::string& directory);

// DCMTK's own console log off (every function here calls it; posewarp reports errors and warnings itself).
void quiet_dcmtk();

}  // namespace posewarp::dicom
