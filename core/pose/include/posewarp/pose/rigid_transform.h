// RigidTransform (posewarp/common/rigid_transform.h) under the name the pose stage has always used.
#pragma once

#include "posewarp/common/rigid_transform.h"

namespace posewarp::pose {

using posewarp::RigidTransform;

}  // namespace posewarp::pose
