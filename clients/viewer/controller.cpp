// The controller the sliders drive: the chosen joint, its angles, the method, undo, and the preview streams it feeds.
#include <chrono>
#include <cstdio>
#include <optional>
#include <string>

#include "scene.h"

namespace posewarp::view {

const char* method_name(v1::Method method) {
  return method == v1::METHOD_DQS   ? "DQS"
         : method == v1::METHOD_LBS ? "LBS"
         : method == v1::METHOD_FEM ? "FEM"
                                    : "CoR";
}

Controller::Controller(Scene& scene, PreviewSession& session) : scene_(scene), session_(&session) {
  if (!scene_.joint_names().empty()) joint_ = scene_.joint_names().front();
}

void Controller::select_joint(size_t index) {
  if (index >= scene_.joint_names().size()) return;
  joint_ = scene_.joint_names()[index];
  at_root_ = false;
}

void Controller::select_root() {
  joint_ = "root";
  at_root_ = true;
}

std::array<double, 3> Controller::chosen_angles() const {
  if (at_root_) return pose_.root_deg;
  const auto a = pose_.joints.find(joint_);
  if (a == pose_.joints.end()) return {0.0, 0.0, 0.0};
  return {a->second.flexion, a->second.abduction, a->second.rotation};
}

void Controller::set_angle(int axis, double degrees) {
  if ((joint_.empty() && !at_root_) || axis < 0 || axis > 2) return;
  if (chosen_angles()[static_cast<size_t>(axis)] == degrees) return;  // a slider event that changed nothing
  // A drag is one change for undo: moves of the same control less than a second apart extend it.
  const auto now = std::chrono::steady_clock::now();
  const std::string control = joint_ + "/" + std::to_string(axis);
  if (control != last_control_ || now - last_change_ > std::chrono::seconds(1)) remember();
  last_control_ = control;
  last_change_ = now;
  if (at_root_) {
    pose_.root_deg[static_cast<size_t>(axis)] = degrees;
  } else {
    JointAngles& a = pose_.joints[joint_];
    (axis == 0 ? a.flexion : axis == 1 ? a.abduction : a.rotation) = degrees;
  }
  send();
}

void Controller::set_method(v1::Method method) {
  method_ = method;
  send();
}

void Controller::set_pose(const Pose& pose) {
  remember();
  pose_ = pose;
  send();
}

void Controller::reset_joint() {
  remember();
  if (at_root_) {
    pose_.root_deg = {0.0, 0.0, 0.0};
    pose_.root_mm = {0.0, 0.0, 0.0};
  } else {
    pose_.joints.erase(joint_);
  }
  send();
}

void Controller::reset_all() {
  remember();
  pose_ = Pose{};
  send();
}

void Controller::undo() {
  if (history_.empty()) return;
  pose_ = history_.back();
  history_.pop_back();
  last_control_.clear();
  send();
}

void Controller::remember() {
  history_.push_back(pose_);
  if (history_.size() > 1000) history_.erase(history_.begin());
  last_control_.clear();
}

void Controller::set_session(PreviewSession& session) {
  session_ = &session;
  send();
}

void Controller::set_compare(PreviewSession* session, v1::Method method) {
  compare_ = session;
  compare_method_ = method;
  scene_.set_method_names(method_name(method_), method_name(method));
  if (compare_ != nullptr) compare_->send(pose_, compare_method_);
}

void Controller::send() {
  last_sent_ = session_->send(pose_, method_);
  if (compare_ != nullptr) compare_->send(pose_, compare_method_);
  scene_.set_method_names(method_name(method_), method_name(compare_method_));
}

bool Controller::poll() {
  bool drew = false;
  if (compare_ != nullptr) {
    if (std::optional<PreviewSession::Answer> other = compare_->take(); other && other->error.failed()) {
      scene_.set_status(std::string("refused (") + method_name(compare_method_) + "): " + other->error.message);
      drew = true;
    } else if (other) {
      scene_.apply(*other, true);
      drew = true;
    }
  }
  std::optional<PreviewSession::Answer> answer = session_->take();
  if (!answer) return drew;
  const auto now = std::chrono::steady_clock::now();
  drawn_.push_back(now);
  while (!drawn_.empty() && now - drawn_.front() > std::chrono::seconds(1)) drawn_.erase(drawn_.begin());
  last_error_ = answer->error;
  if (answer->error.failed()) {
    scene_.set_status("refused: " + answer->error.message + "  (u undoes the last change)");
    return true;
  }
  round_trip_ms_ = answer->round_trip_ms;
  scene_.apply(*answer);
  const std::array<double, 3> a = chosen_angles();
  const char* names = at_root_ ? "L-R %.0f  A-P %.0f  S-I %.0f" : "flexion %.0f  abduction %.0f  rotation %.0f";
  char angles[96], text[320];
  std::snprintf(angles, sizeof angles, names, a[0], a[1], a[2]);
  std::snprintf(text, sizeof text, "%s  %s: %s   round trip %.1f ms, %zu fps", method_name(method_), joint_.c_str(),
                angles, round_trip_ms_, drawn_.size());
  scene_.set_status(text);
  return true;
}

}  // namespace posewarp::view
