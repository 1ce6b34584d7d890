// posewarp-view's calls: rigs, assets and the preview stream.
#include "viewer_client.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cmath>

namespace posewarp::view {
bool Pose::is_rest() const {
  for (const auto& [joint, a] : joints) {
    if (!a.is_zero()) return false;
  }
  return root_deg == std::array<double, 3>{} && root_mm == std::array<double, 3>{};
}

namespace {

using Quaternion = std::array<double, 4>;  // w, x, y, z

Quaternion multiply(const Quaternion& a, const Quaternion& b) {
  return {a[0] * b[0] - a[1] * b[1] - a[2] * b[2] - a[3] * b[3], a[0] * b[1] + a[1] * b[0] + a[2] * b[3] - a[3] * b[2],
          a[0] * b[2] - a[1] * b[3] + a[2] * b[0] + a[3] * b[1], a[0] * b[3] + a[1] * b[2] - a[2] * b[1] + a[3] * b[0]};
}

// The root's three angles (about x, then y, then z: R = Rz Ry Rx) as a quaternion, and back.
Quaternion root_quaternion(const std::array<double, 3>& degrees) {
  Quaternion q{1, 0, 0, 0};
  for (int axis = 0; axis < 3; ++axis) {
    const double half = degrees[static_cast<size_t>(axis)] * M_PI / 360.0;
    Quaternion turn{std::cos(half), 0, 0, 0};
    turn[static_cast<size_t>(axis) + 1] = std::sin(half);
    q = multiply(turn, q);
  }
  return q;
}

std::array<double, 3> root_angles(Quaternion q) {
  const double n = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
  for (double& c : q) c /= n;
  const double w = q[0], x = q[1], y = q[2], z = q[3];
  const double r21 = 2 * (y * z + w * x), r22 = 1 - 2 * (x * x + y * y), r20 = 2 * (x * z - w * y);
  const double r10 = 2 * (x * y + w * z), r00 = 1 - 2 * (y * y + z * z);
  const double degrees = 180.0 / M_PI;
  return {std::atan2(r21, r22) * degrees, std::asin(std::clamp(-r20, -1.0, 1.0)) * degrees,
          std::atan2(r10, r00) * degrees};
}

bool numbers(const nlohmann::json& value, size_t count) {
  if (!value.is_array() || value.size() != count) return false;
  return std::all_of(value.begin(), value.end(), [](const nlohmann::json& v) { return v.is_number(); });
}

}  // namespace

std::string pose_json(const Pose& pose, const std::string& name) {
  nlohmann::json doc{{"format", "posewarp.pose"}, {"version", 1}, {"name", name}, {"joints", nlohmann::json::object()}};
  if (pose.root_deg != std::array<double, 3>{} || pose.root_mm != std::array<double, 3>{}) {
    doc["root"] = {{"translation_mm", pose.root_mm}, {"rotation", {{"quaternion", root_quaternion(pose.root_deg)}}}};
  }
  for (const auto& [joint, a] : pose.joints) {
    if (a.is_zero()) continue;
    doc["joints"][joint] = {
        {"angles_deg", {{"flexion", a.flexion}, {"abduction", a.abduction}, {"rotation", a.rotation}}}};
  }
  return doc.dump();
}

void put_pose(const Pose& pose, v1::Pose* out, const std::string& name) {
  out->set_name(name);
  if (pose.root_deg != std::array<double, 3>{} || pose.root_mm != std::array<double, 3>{}) {
    v1::RootMotion* root = out->mutable_root();
    for (const double mm : pose.root_mm) root->add_translation_mm(mm);
    const Quaternion q = root_quaternion(pose.root_deg);
    v1::Quaternion* typed = root->mutable_rotation()->mutable_quaternion();
    typed->set_w(q[0]);
    typed->set_x(q[1]);
    typed->set_y(q[2]);
    typed->set_z(q[3]);
  }
  for (const auto& [joint, a] : pose.joints) {
    if (a.is_zero()) continue;
    v1::JointRotation* typed = out->add_joints();
    typed->set_joint(joint);
    typed->mutable_angles()->set_flexion_deg(a.flexion);
    typed->mutable_angles()->set_abduction_deg(a.abduction);
    typed->mutable_angles()->set_rotation_deg(a.rotation);
  }
}

std::optional<Pose> pose_from_json(const std::string& text, std::string* error) {
  const nlohmann::json doc = nlohmann::json::parse(text, nullptr, false);
  if (doc.is_discarded() || !doc.is_object() || !doc.contains("joints") || !doc["joints"].is_object()) {
    *error = "not a pose JSON (an object with \"joints\")";
    return std::nullopt;
  }
  Pose pose;
  if (doc.contains("root")) {
    const nlohmann::json& root = doc["root"];
    if (!root.is_object()) {
      *error = "\"root\" must be an object with \"translation_mm\" and \"rotation\"";
      return std::nullopt;
    }
    if (root.contains("translation_mm")) {
      if (!numbers(root["translation_mm"], 3)) {
        *error = "root translation_mm must be three numbers (LPS mm)";
        return std::nullopt;
      }
      for (size_t a = 0; a < 3; ++a) pose.root_mm[a] = root["translation_mm"][a].get<double>();
    }
    if (root.contains("rotation")) {
      const nlohmann::json& r = root["rotation"];
      Quaternion q{1, 0, 0, 0};
      if (r.is_object() && r.contains("quaternion") && numbers(r["quaternion"], 4)) {
        for (size_t c = 0; c < 4; ++c) q[c] = r["quaternion"][c].get<double>();
      } else if (r.is_object() && r.contains("axis_angle") && r["axis_angle"].is_object() &&
                 numbers(r["axis_angle"].value("axis", nlohmann::json()), 3) && r["axis_angle"].contains("degrees") &&
                 r["axis_angle"]["degrees"].is_number()) {
        const nlohmann::json& axis = r["axis_angle"]["axis"];
        const double x = axis[0].get<double>(), y = axis[1].get<double>(), z = axis[2].get<double>();
        const double length = std::sqrt(x * x + y * y + z * z),
                     half = r["axis_angle"]["degrees"].get<double>() * M_PI / 360;
        if (length > 0)
          q = {std::cos(half), std::sin(half) * x / length, std::sin(half) * y / length, std::sin(half) * z / length};
      } else {
        *error = "root rotation: the viewer reads a \"quaternion\" [w, x, y, z] or an \"axis_angle\"";
        return std::nullopt;
      }
      const double norm = std::sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]);
      if (!std::isfinite(norm) || std::abs(norm - 1.0) > 1e-3) {
        *error = "root rotation: the quaternion is not a unit quaternion";
        return std::nullopt;
      }
      pose.root_deg = root_angles(q);
    }
  }
  for (const auto& [joint, value] : doc["joints"].items()) {
    if (!value.is_object() || !value.contains("angles_deg") || !value["angles_deg"].is_object()) {
      *error = "joint '" + joint + "': the viewer reads \"angles_deg\": {\"flexion\", \"abduction\", \"rotation\"}";
      return std::nullopt;
    }
    const nlohmann::json& a = value["angles_deg"];
    JointAngles& j = pose.joints[joint];
    for (auto [key, field] :
         {std::pair{"flexion", &j.flexion}, {"abduction", &j.abduction}, {"rotation", &j.rotation}}) {
      if (!a.contains(key)) continue;
      if (!a[key].is_number()) {
        *error = "joint '" + joint + "': " + key + " must be a number of degrees";
        return std::nullopt;
      }
      *field = a[key].get<double>();
    }
  }
  return pose;
}

std::unique_ptr<ViewerClient> ViewerClient::connect(const ServerAddress& address, CallError* error) {
  auto client = std::unique_ptr<ViewerClient>(new ViewerClient());
  client->connection_ = client::Connection::open(address, error);
  if (!client->connection_) return nullptr;
  return client;
}

CallError ViewerClient::list_rigs(std::vector<v1::Rig>* rigs) const { return connection_->list_rigs(rigs); }

CallError ViewerClient::rig(const std::string& rig_id, v1::Rig* rig) const {
  v1::GetRigRequest request;
  request.set_rig_id(rig_id);
  return connection_->error_of(connection_->unary(&v1::Posewarp::Stub::GetRig, request, rig, rig_id));
}

CallError ViewerClient::assets(const std::string& rig_id, RigAssets* assets) const {
  v1::GetRigAssetsRequest request;
  request.set_rig_id(rig_id);
  request.set_format(v1::ASSET_FORMAT_RAW);
  const auto call = context(rig_id);
  auto reader = stub().GetRigAssets(call.get(), request);
  v1::RigAsset part;
  while (reader->Read(&part)) {
    if (part.has_skeleton()) assets->skeleton = part.skeleton();
    if (part.has_surface()) assets->surfaces.push_back(part.surface());
  }
  return connection_->error_of(reader->Finish());
}

PreviewSession::PreviewSession(const ViewerClient& client, const std::string& rig_id)
    : context_(client.context(rig_id)), rig_id_(rig_id) {
  stream_ = client.stub().Preview(context_.get());
  reader_ = std::thread([this] { read_loop(); });
}

PreviewSession::~PreviewSession() {
  {
    std::lock_guard<std::mutex> lock(write_mutex_);
    stream_->WritesDone();
  }
  // The server answers the last update and closes; one that does not within 2 s (busy loading a rig, or gone
  // without a word) is cut off, so the window never waits on it.
  {
    std::unique_lock<std::mutex> lock(mutex_);
    if (!answered_.wait_for(lock, std::chrono::seconds(2), [&] { return closed_; })) context_->TryCancel();
  }
  reader_.join();
}

uint64_t PreviewSession::send(const Pose& pose, v1::Method method) {
  v1::PreviewRequest update;
  uint64_t sequence = 0;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    sequence = next_sequence_++;
    sent_at_[sequence] = std::chrono::steady_clock::now();
  }
  if (sequence == 1) update.set_rig_id(rig_id_);
  update.set_sequence(sequence);
  put_pose(pose, update.mutable_pose());
  update.set_method(method);
  std::lock_guard<std::mutex> lock(write_mutex_);
  stream_->Write(update);
  return sequence;
}

void PreviewSession::read_loop() {
  v1::PreviewResponse response;
  while (stream_->Read(&response)) {
    Answer answer;
    answer.sequence = response.sequence();
    answer.server_ms = response.server_ms();
    if (response.error_code() != 0) {
      answer.error = {static_cast<grpc::StatusCode>(response.error_code()), response.error_message()};
    }
    for (const v1::SurfacePositions& s : response.surfaces()) {
      answer.vertices.emplace_back(s.vertices().begin(), s.vertices().end());
    }
    for (int i = 0; i + 2 < response.joint_centres_size(); i += 3) {
      answer.joint_centres.push_back(
          {response.joint_centres(i), response.joint_centres(i + 1), response.joint_centres(i + 2)});
    }
    std::lock_guard<std::mutex> lock(mutex_);
    const auto sent = sent_at_.find(answer.sequence);
    if (sent != sent_at_.end()) {
      answer.round_trip_ms =
          std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - sent->second).count();
    }
    sent_at_.erase(sent_at_.begin(), sent_at_.upper_bound(answer.sequence));
    ++answers_;
    last_answered_ = answer.sequence;
    newest_ = std::move(answer);
    answered_.notify_all();
  }
  const grpc::Status status = stream_->Finish();
  std::lock_guard<std::mutex> lock(mutex_);
  closed_ = true;
  end_ = status.ok() ? CallError{} : CallError{status.error_code(), status.error_message()};
  answered_.notify_all();
}

std::optional<PreviewSession::Answer> PreviewSession::take() {
  std::lock_guard<std::mutex> lock(mutex_);
  std::optional<Answer> answer = std::move(newest_);
  newest_.reset();
  return answer;
}

bool PreviewSession::wait_for(uint64_t sequence, int timeout_ms) {
  std::unique_lock<std::mutex> lock(mutex_);
  return answered_.wait_for(lock, std::chrono::milliseconds(timeout_ms), [&] {
    return last_answered_ >= sequence || closed_;
  }) && last_answered_ >= sequence;
}

uint64_t PreviewSession::answers() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return answers_;
}

CallError PreviewSession::ended() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return end_;
}

VolumeRequest::VolumeRequest(const ViewerClient& client, const std::string& rig_id, const Pose& pose, v1::Method method,
                             bool raw, v1::GridPolicy grid)
    : context_(client.context(rig_id)), client_(client) {
  v1::PoseRequest request;
  request.set_rig_id(rig_id);
  put_pose(pose, request.mutable_pose());
  request.set_method(method);
  request.set_grid(grid);
  request.set_want_labels(true);
  request.set_want_ct(true);
  request.set_want_surfaces(!raw);
  request.set_format(raw ? v1::FILE_FORMAT_RAW : v1::FILE_FORMAT_NIFTI_GZ);
  request.set_samples(v1::SAMPLE_TYPE_STORED);
  if (raw) request.set_label_encoding(v1::LABEL_ENCODING_RUNS);  // decoded as they come, in a fraction of the bytes
  result_.pose_json = pose_json(pose);
  thread_ = std::thread([this, request] { run(request); });
}

VolumeRequest::VolumeRequest(const ViewerClient& client, const std::string& rig_id, v1::PoseRequest request,
                             std::string asked)
    : context_(client.context(rig_id)), client_(client) {
  result_.pose_json = std::move(asked);
  thread_ = std::thread([this, request] { run(request); });
}

std::unique_ptr<VolumeRequest> VolumeRequest::report_only(const ViewerClient& client, const std::string& rig_id,
                                                          const Pose& pose, v1::Method method) {
  v1::PoseRequest request;
  request.set_rig_id(rig_id);
  put_pose(pose, request.mutable_pose());
  request.set_method(method);
  request.set_want_labels(false);
  request.set_want_ct(false);
  request.set_want_surfaces(false);
  return std::unique_ptr<VolumeRequest>(new VolumeRequest(client, rig_id, std::move(request), pose_json(pose)));
}

VolumeRequest::~VolumeRequest() {
  cancel();
  thread_.join();
}

void VolumeRequest::run(v1::PoseRequest request) {
  auto reader = client_.stub().Pose(context_.get(), request);
  PosedVolumes result;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    result.pose_json = result_.pose_json;  // the pose file of what was asked, set before this thread started
  }
  const grpc::Status status =
      client::read_pose(*context_, *reader, &result, [this](uint64_t received, uint64_t expected) {
        std::lock_guard<std::mutex> lock(mutex_);
        received_ = received;
        expected_ = expected;
      });
  std::lock_guard<std::mutex> lock(mutex_);
  if (!error_.failed()) {  // not cancelled
    if (!status.ok()) {
      error_ = client_.connection().error_of(status);
    } else if (!request.want_labels() && !request.want_ct()) {  // a report only
      if (result.report.json().empty()) error_ = {grpc::StatusCode::DATA_LOSS, "the server's answer held no report"};
    } else if (result.labels.empty() || result.ct.empty()) {
      error_ = {grpc::StatusCode::DATA_LOSS, "the server's answer ended before the volumes were complete"};
    }
  }
  result_ = std::move(result);
  done_ = true;
  finished_.notify_all();
}

bool VolumeRequest::done() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return done_;
}

std::pair<uint64_t, uint64_t> VolumeRequest::progress() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return {received_, expected_};
}

void VolumeRequest::cancel() {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!done_) {
    error_ = {grpc::StatusCode::CANCELLED, "cancelled"};
    context_->TryCancel();
  }
}

CallError VolumeRequest::take(PosedVolumes* result) {
  std::lock_guard<std::mutex> lock(mutex_);
  if (!done_) return {grpc::StatusCode::UNAVAILABLE, "the request is still running"};
  if (!error_.failed()) *result = std::move(result_);
  return error_;
}

bool VolumeRequest::wait(int timeout_ms) {
  std::unique_lock<std::mutex> lock(mutex_);
  return finished_.wait_for(lock, std::chrono::milliseconds(timeout_ms), [&] { return done_; });
}

}  // namespace posewarp::view
