// Label map SEGs (DICOM Supplement 243, 2024) through dcmdata, which DCMTK 3.6.7's dcmseg does not know: a frame per
// slice whose pixels are segment numbers, written from posed labels and read onto a CT's grid.
#pragma once

#include <dcmtk/config/osconfig.h>  // before any other DCMTK header
#include <dcmtk/dcmdata/dcdatset.h>

#include <string>
#include <vector>

#include "posewarp/dicom/segmentation.h"

namespace posewarp::dicom {

// Label Map Segmentation Storage.
inline constexpr const char* kLabelMapSegmentationStorage = "1.2.840.10008.5.1.4.1.1.66.7";

// `labels` (on the grid of `ct`) as a label map SEG of `info`'s series and instance: every label value present one
// segment of that number, described by `segments` (one per value, in value order).
Result<std::string> encode_label_map_segmentation(const LabelVolume& labels, const std::vector<Segment>& segments,
                                                  const SeriesInfo& ct, const SeriesInfo& info,
                                                  const DerivedSeriesOptions& options);
// The label map SEG `d` onto `grid`: each voxel its segment's number.
Result<Segmentation> read_label_map_segmentation(DcmDataset& d, const ImageGeometry& grid);

}  // namespace posewarp::dicom
