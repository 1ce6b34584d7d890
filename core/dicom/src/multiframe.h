// Multi-frame images through dcmdata, for the label map SEG and the Enhanced CT (DCMTK 3.6.7's dcmseg knows neither):
// the functional groups that place each frame in the patient and name what it was derived from, written and read.
#pragma once

#include <dcmtk/config/osconfig.h>  // before any other DCMTK header
#include <dcmtk/dcmdata/dcitem.h>

#include <array>
#include <string>
#include <vector>

#include "posewarp/common/dicom_series.h"
#include "posewarp/common/result.h"
#include "posewarp/common/volume.h"

namespace posewarp::dicom {

using Vec = std::array<double, 3>;

// `count` finite numbers of attribute `tag` of `item` into `out`; false when `item` is null or they are not there.
bool numbers(DcmItem* item, const DcmTagKey& tag, double* out, int count);
// A string attribute, inserted or replaced; an attribute's value as text (empty when missing).
void put(DcmItem& d, const DcmTagKey& tag, const std::string& value);
std::string text_of(DcmItem& d, const DcmTagKey& tag);
// A code sequence of one item (value, scheme, meaning) into `parent`; the code a sequence holds (empty if none).
void put_code(DcmItem& parent, const DcmTagKey& sequence, const DicomCode& code);
DicomCode code_in(DcmItem& parent, const DcmTagKey& sequence);
// A number as a DICOM decimal string (at most 16 characters).
std::string decimal(double value);
// Now in UTC, as `format` (strftime) writes it: "%Y%m%d" a DICOM date, "%H%M%S" a time.
std::string utc_now(const char* format);

// The one item of the Shared Functional Groups Sequence, and frame `f`'s item of the Per-Frame one (both made when
// missing; frames are made in order).
DcmItem* shared_groups(DcmItem& d);
DcmItem* frame_groups(DcmItem& d, size_t f);

// Whether `g`'s slices go out in reverse order: DICOM's slice normal is row x column, and a left-handed grid's slice
// axis points the other way.
bool written_in_reverse(const ImageGeometry& g);
// Slice `k` of `g` in the patient: where its first pixel lies.
Vec slice_position(const ImageGeometry& g, int64_t k);
// Pixel Measures and Plane Orientation (Patient) of `g`'s slices, into `groups` (the shared ones).
void put_plane_geometry(DcmItem& groups, const ImageGeometry& g);
// Plane Position (Patient) of slice `k` of `g` and Frame Content with the frame's index along the stack (from 1).
void put_frame_place(DcmItem& frame, const ImageGeometry& g, int64_t k, uint32_t index);
// The frames' one dimension, their position (Multi-frame Dimension module).
void put_position_dimension(DcmItem& d, const std::string& organization_uid);

// An image a frame was derived from: a single-frame image, or a frame of a multi-frame one.
struct SourceImage {
  std::string sop_class_uid, sop_instance_uid;
  int32_t frame = 0;  // from 1; 0: the whole image
};
// The images of slice `index` (in slice order) of `series`: its instance, or its frame.
SourceImage source_slice(const SeriesInfo& series, size_t index);
// A Derivation Image functional group into `groups`: derived from `sources` by the coded operation `code` (value,
// scheme, meaning), described in words.
void put_derivation(DcmItem& groups, const std::vector<SourceImage>& sources, const DicomCode& code,
                    const std::string& description);
// The series the derived image came from, with its instances (Common Instance Reference module).
void put_referenced_series(DcmItem& d, const SeriesInfo& series);

// One frame's plane in the patient, and its rescale.
struct FramePlane {
  Vec position{}, row{}, column{};
  double spacing[2] = {0, 0};  // between rows, between columns
  double slope = 1, intercept = 0;
};
// Each frame's plane from its per-frame functional groups, else from the shared ones; an error naming `what` and
// the frame where its position, orientation or pixel spacing is missing.
Result<std::vector<FramePlane>> read_frame_planes(DcmItem& d, const std::string& what);
// The slice of `grid` that a frame (`name`, for messages) of a segmentation made on it lies on; an error unless its
// orientation and pixel spacing are the grid's and its position is one of the grid's slice origins.
Result<size_t> slice_on_grid(const FramePlane& plane, const ImageGeometry& grid, const std::string& name);

}  // namespace posewarp::dicom
