// The DICOM tests' made-up source series: for volumes that never were DICOM (the sample is NIfTI).
#pragma once

#include "posewarp/dicom/ct_series.h"

namespace posewarp::dicom {

inline SeriesInfo made_up_source() {
  SeriesInfo s;
  s.patient_name = "Sample^Phantom";
  s.patient_id = "PW-0001";
  s.patient_sex = "O";
  s.patient_position = "HFS";
  s.study_instance_uid = *new_uid("2.25");
  s.study_date = "20250101";
  s.study_time = "120000";
  s.study_id = "1";
  s.series_instance_uid = *new_uid("2.25");
  s.series_number = "3";
  s.frame_of_reference_uid = *new_uid("2.25");
  return s;
}

}  // namespace posewarp::dicom
