// Animation: a sequence of poses played at a fixed frame time; its JSON form.
#pragma once

#include <string>
#include <vector>

#include "posewarp/common/animation.h"
#include "posewarp/common/result.h"
#include "posewarp/pose/pose.h"
#include "posewarp/rig/skeleton.h"

namespace posewarp::pose {

using posewarp::Animation;  // posewarp/common/animation.h

// Animation JSON, version 1:
//   {"format": "posewarp.animation", "version": 1, "frame_time_s": 0.04,
//    "frames": [{"name": "start", "joints": {...}}, {"joints": {...}, "root": {...}}, ...]}
// Each frame is a pose object as in pose.h (its "format" and "version" may be left out). "frames" must hold at
// least one pose; "frame_time_s" (default 1/30) must be positive. A frame without a name is called "frame <i>".
Result<Animation> animation_from_json(const std::string& text, const std::string& source);
// NOT_FOUND when the file cannot be opened; otherwise as animation_from_json.
Result<Animation> read_animation(const std::string& path);
std::string animation_to_json(const Animation& animation);

// validate_pose for every frame (the message names the frame), and a positive, finite frame time.
Status validate_animation(const Animation& animation, const rig::Skeleton& skeleton);

}  // namespace posewarp::pose
