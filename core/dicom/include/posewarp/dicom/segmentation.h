// DICOM Segmentation (SEG) in and out (DCMTK's dcmseg): segments read onto a CT's grid as label values (binary, or
// fractional thresholded at one half) with their labels and codes kept, and posed labels written as a binary SEG
// that references the derived CT series it belongs to.
#pragma once

#include <map>
#include <string>
#include <vector>

#include "posewarp/common/dicom_series.h"
#include "posewarp/common/result.h"
#include "posewarp/common/volume.h"
#include "posewarp/dicom/ct_series.h"

namespace posewarp::dicom {

// Segments are vocabulary (posewarp/common/dicom_series.h).
using Code = posewarp::DicomCode;
using Segment = posewarp::DicomSegment;

struct Segmentation {
  LabelVolume labels;             // on the grid asked for; each voxel the number of its segment (0: none)
  std::vector<Segment> segments;  // in segment-number order
  std::string series_instance_uid, referenced_series_uid;
  std::vector<std::string> warnings;  // fractional segments thresholded, overlapping segments
};

// A SEG's bytes (Part 10) read onto `grid` (the CT's), each frame placed by its position. Refused with a reason:
// not a SEG, frames without an orientation or whose orientation, pixel spacing or size is not the grid's, frames off
// the grid's slices. Where segments
// overlap the highest-numbered wins (a warning says how many voxels).
Result<Segmentation> read_segmentation(const std::string& bytes, const ImageGeometry& grid);

// `labels` (on the grid of the CT series `ct`, written by encode_derived_ct as `ct.sop_instance_uids`) as a binary
// SEG of the same patient and study: one segment per label value present, in value order (label, description and
// codes from `segments` where one has that value as its number, else "label N"), each frame referencing its CT
// slice. `info` (optional) receives the SEG's series; `numbers` (optional) each label value's segment number (DICOM
// numbers segments 1, 2, 3, ... so values that skip are renumbered).
Result<std::string> encode_segmentation(const LabelVolume& labels, const std::vector<Segment>& segments,
                                        const SeriesInfo& ct, const DerivedSeriesOptions& options,
                                        SeriesInfo* info = nullptr, std::map<Label, int>* numbers = nullptr);

}  // namespace posewarp::dicom
