// JSON forms of the small rig sections (skeleton, parameters).
#pragma once

#include <string>

#include "posewarp/api/rig.h"
#include "posewarp/labels/label_map.h"
#include "posewarp/rig/skeleton.h"
#include "posewarp/weights/laplace_weights.h"

namespace posewarp::api::detail {

std::string skeleton_to_json(const rig::Skeleton& skeleton);
Result<rig::Skeleton> skeleton_from_json(const std::string& text);

}  // namespace posewarp::api::detail
