// Animation JSON (read, write) and validation against a skeleton.
#include "posewarp/pose/animation.h"

#include <cmath>

#include "json_util.h"

namespace posewarp::pose {
namespace {

using detail::Json;

constexpr std::string_view kFormat = "posewarp.animation";
constexpr int kVersion = 1;

}  // namespace

Result<Animation> animation_from_json(const std::string& text, const std::string& source) {
  const std::string where = "animation " + source;
  POSEWARP_ASSIGN_OR_RETURN(const Json doc, detail::parse_json(text, where));
  try {
    if (!doc.is_object()) return invalid_argument_error(where + " must be a JSON object");
    POSEWARP_RETURN_IF_ERROR(detail::check_fields(doc, {"format", "version", "frame_time_s", "frames"}, where));
    POSEWARP_RETURN_IF_ERROR(detail::check_format(doc, kFormat, kVersion, where));
    Animation animation;
    if (doc.contains("frame_time_s")) {
      POSEWARP_ASSIGN_OR_RETURN(animation.frame_time_s,
                                detail::finite_number(doc["frame_time_s"], where, "frame_time_s"));
      if (!(animation.frame_time_s > 0.0)) {
        return invalid_argument_error(where +
                                      ": \"frame_time_s\" must be positive (seconds between frames, e.g. 0.04)");
      }
    }
    if (!doc.contains("frames") || !doc["frames"].is_array() || doc["frames"].empty()) {
      return invalid_argument_error(where + " needs \"frames\": a list of at least one pose object");
    }
    const Json& frames = doc["frames"];
    for (size_t i = 0; i < frames.size(); ++i) {
      POSEWARP_ASSIGN_OR_RETURN(Pose pose, detail::pose_from_object(frames[i], where + ", frame " + std::to_string(i)));
      if (!frames[i].contains("name")) pose.name = "frame " + std::to_string(i);
      animation.frames.push_back(std::move(pose));
    }
    return animation;
  } catch (const Json::exception& error) {
    return invalid_argument_error(where + " has a field of the wrong type: " + error.what());
  }
}

Result<Animation> read_animation(const std::string& path) {
  POSEWARP_ASSIGN_OR_RETURN(const std::string text, detail::read_text_file(path, "animation"));
  return animation_from_json(text, "'" + path + "'");
}

std::string animation_to_json(const Animation& animation) {
  Json doc;
  doc["format"] = kFormat;
  doc["version"] = kVersion;
  doc["frame_time_s"] = animation.frame_time_s;
  Json frames = Json::array();
  for (const Pose& pose : animation.frames) {
    Json frame = detail::pose_to_object(pose);
    frame.erase("format");
    frame.erase("version");
    frames.push_back(std::move(frame));
  }
  doc["frames"] = std::move(frames);
  return doc.dump(2) + "\n";
}

Status validate_animation(const Animation& animation, const rig::Skeleton& skeleton) {
  if (!(animation.frame_time_s > 0.0) || !std::isfinite(animation.frame_time_s)) {
    return invalid_argument_error("the animation's frame time must be a positive number of seconds (got " +
                                  std::to_string(animation.frame_time_s) + ")");
  }
  if (animation.frames.empty()) return invalid_argument_error("the animation has no frames");
  for (size_t i = 0; i < animation.frames.size(); ++i) {
    const Status status = validate_pose(animation.frames[i], skeleton);
    if (!status.ok()) return status.with_context("animation frame " + std::to_string(i));
  }
  return ok_status();
}

}  // namespace posewarp::pose
