// Placing an ITK image on an ImageGeometry (io internals; ITK only).
#pragma once

#include <itkImageBase.h>

#include "posewarp/common/image_geometry.h"

namespace posewarp::io::detail {

// Sets the region, spacing, origin and direction of `image` from `g` (allocation is the caller's).
template <typename Image>
void set_itk_geometry(Image* image, const ImageGeometry& g) {
  typename Image::RegionType region;
  typename Image::SpacingType spacing;
  typename Image::PointType origin;
  typename Image::DirectionType direction;
  for (unsigned a = 0; a < 3; ++a) {
    region.SetSize(a, static_cast<itk::SizeValueType>(g.size[a]));
    spacing[a] = g.spacing[a];
    origin[a] = g.origin[a];
    for (unsigned c = 0; c < 3; ++c) direction(a, c) = g.direction[3 * a + c];
  }
  image->SetRegions(region);
  image->SetSpacing(spacing);
  image->SetOrigin(origin);
  image->SetDirection(direction);
}

}  // namespace posewarp::io::detail
