// DICOM series as posewarp reads and writes them: the identifying attributes of a series and its study, a CT read
// from one, the options of a derived series, and the segments of a SEG. Reading and writing them: dicom/.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "posewarp/common/volume.h"

namespace posewarp {

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
  // A multi-frame image (an Enhanced CT: sop_instance_uids holds its one instance): each slice's frame number (from
  // 1), in slice order. Empty: one single-frame instance per slice.
  std::vector<int32_t> frame_numbers;
  // The slices of the series: its frames, or its instances.
  size_t slice_count() const { return frame_numbers.empty() ? sop_instance_uids.size() : frame_numbers.size(); }
};

struct CtSeries {
  IntensityVolume ct;  // Hounsfield units (each slice's rescale applied), on a right-handed LPS grid
  SeriesInfo info;
};

// How posed labels are written: a binary SEG (a frame per segment and slice, each pixel a bit; every SEG reader knows
// it) or a label map SEG (DICOM Supplement 243: a frame per slice, each pixel its segment's number; a PACS ingests it
// many times faster, and readers are adopting it).
enum class SegFormat { kBinary, kLabelMap };
// How a posed CT is written: a series of single-frame CT images, or one multi-frame Enhanced CT image.
enum class CtFormat { kSeries, kEnhanced };

// How a derived series is named, numbered and encoded.
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
  SegFormat seg_format = SegFormat::kBinary;
  CtFormat ct_format = CtFormat::kSeries;
};

// A coded concept (SNOMED CT and the like): value, scheme ("SCT", "DCM", ...), meaning.
struct DicomCode {
  std::string value, scheme, meaning;
};

// One segment: its number (the label value it is read as; written: the label value it describes), its label and
// description, its category and type codes.
struct DicomSegment {
  int number = 0;
  std::string label, description;
  DicomCode category, type;
};

}  // namespace posewarp
