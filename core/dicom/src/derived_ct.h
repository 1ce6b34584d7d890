// What the writers of a derived CT share, as single-frame images (ct_series.cpp) or one Enhanced CT
// (enhanced_ct.cpp): the new series, its identifying attributes, and the posed values as int16 HU.
#pragma once

#include <dcmtk/config/osconfig.h>  // before any other DCMTK header
#include <dcmtk/dcmdata/dcdatset.h>

#include <cstdint>
#include <string>
#include <vector>

#include "multiframe.h"
#include "posewarp/dicom/ct_series.h"

namespace posewarp::dicom {

// A grid's axes as DICOM writes them.
struct SliceAxes {
  Vec row, column, slice_axis;
  bool reverse = false;  // DICOM's slice normal is row x column; a left-handed grid's slices go out in reverse order
};

// One instance of a derived series: its UID, its place in the series and when the series was made.
struct DerivedInstance {
  std::string sop_uid;
  int64_t index = 0;  // its place in the series, from 0
  int64_t slice = 0;  // the volume's slice it holds
  std::string date, time;
};

// An error unless the grid can be written as a derived CT of `source`.
Status check_derived_input(const ImageGeometry& g, const SeriesInfo& source);
// The row, column and slice directions of `g`, and whether its slices go out in reverse order.
SliceAxes slice_axes(const ImageGeometry& g);
// The derived series: the source's patient and study, a new series (UID, number, description), no instances yet.
Result<SeriesInfo> derived_series_info(const SeriesInfo& source, const DerivedSeriesOptions& options);
// The instance's identity (SOP class: `info`'s), the source's patient and study, and the new series.
void put_series_attributes(DcmDataset& d, const SeriesInfo& info, const DerivedSeriesOptions& options,
                           const DerivedInstance& instance);
// Image Pixel of int16 HU samples: one sample, MONOCHROME2, `g`'s rows and columns, 16 bits signed.
void put_hu_pixel_module(DcmItem& d, const ImageGeometry& g);
// Slice `k` of `ct` as int16 HU, rounded half away from zero; the number of values clipped to fit.
int64_t hu_samples(const IntensityVolume& ct, int64_t k, int16_t* out);

// `ct` as one Enhanced CT image of `source`'s study (enhanced_ct.cpp): its Part 10 bytes, and its series in `info`.
Result<std::string> encode_enhanced_ct(const IntensityVolume& ct, const SeriesInfo& source,
                                       const DerivedSeriesOptions& options, SeriesInfo* info);

}  // namespace posewarp::dicom
