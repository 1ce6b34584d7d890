// posewarp-view's calls: rigs, assets and the preview stream.
#include "viewer_client.h"

#include <nlohmann/json.hpp>

#include <fstream>
#include <sstream>

namespace posewarp::view {
namespace {

CallError error_of(const grpc::Status& status, const std::string& server) {
  if (status.ok()) return {};
  if (status.error_code() == grpc::StatusCode::UNAVAILABLE) {
    return {status.error_code(), "cannot reach posewarp-server at " + server + " (is it running, and is the address "
                                 "right?): " + status.error_message()};
  }
  return {status.error_code(), status.error_message()};
}

bool read_file(const std::string& path, std::string* text) {
  std::ifstream in(path, std::ios::binary);
  if (!in) return false;
  std::ostringstream out;
  out << in.rdbuf();
  *text = out.str();
  return true;
}

}  // namespace

std::string pose_json(const PoseAngles& angles, const std::string& name) {
  nlohmann::json doc{{"format", "posewarp.pose"}, {"version", 1}, {"name", name}, {"joints", nlohmann::json::object()}};
  for (const auto& [joint, a] : angles) {
    if (a.is_zero()) continue;
    doc["joints"][joint] = {{"angles_deg", {{"flexion", a.flexion}, {"abduction", a.abduction}, {"rotation", a.rotation}}}};
  }
  return doc.dump();
}

std::optional<PoseAngles> angles_from_json(const std::string& text, std::string* error) {
  const nlohmann::json doc = nlohmann::json::parse(text, nullptr, false);
  if (doc.is_discarded() || !doc.is_object() || !doc.contains("joints") || !doc["joints"].is_object()) {
    *error = "not a pose JSON (an object with \"joints\")";
    return std::nullopt;
  }
  PoseAngles angles;
  for (const auto& [joint, value] : doc["joints"].items()) {
    if (!value.is_object() || !value.contains("angles_deg") || !value["angles_deg"].is_object()) {
      *error = "joint '" + joint + "': the viewer reads \"angles_deg\": {\"flexion\", \"abduction\", \"rotation\"}";
      return std::nullopt;
    }
    const nlohmann::json& a = value["angles_deg"];
    JointAngles& j = angles[joint];
    for (auto [key, field] : {std::pair{"flexion", &j.flexion}, {"abduction", &j.abduction}, {"rotation", &j.rotation}}) {
      if (!a.contains(key)) continue;
      if (!a[key].is_number()) {
        *error = "joint '" + joint + "': " + key + " must be a number of degrees";
        return std::nullopt;
      }
      *field = a[key].get<double>();
    }
  }
  return angles;
}

std::unique_ptr<ViewerClient> ViewerClient::connect(const ServerAddress& address, CallError* error) {
  auto client = std::unique_ptr<ViewerClient>(new ViewerClient());
  client->server_ = address.server;
  std::shared_ptr<grpc::ChannelCredentials> credentials = grpc::InsecureChannelCredentials();
  if (!address.tls_ca.empty()) {
    grpc::SslCredentialsOptions ssl;
    if (!read_file(address.tls_ca, &ssl.pem_root_certs)) {
      *error = {grpc::StatusCode::INVALID_ARGUMENT, "cannot read the TLS CA certificate '" + address.tls_ca + "'"};
      return nullptr;
    }
    credentials = grpc::SslCredentials(ssl);
  }
  if (!address.token_file.empty()) {
    std::string token;
    if (!read_file(address.token_file, &token)) {
      *error = {grpc::StatusCode::INVALID_ARGUMENT, "cannot read the token file '" + address.token_file + "'"};
      return nullptr;
    }
    const size_t first = token.find_first_not_of(" \t\r\n"), last = token.find_last_not_of(" \t\r\n");
    if (first == std::string::npos) {
      *error = {grpc::StatusCode::INVALID_ARGUMENT, "the token file '" + address.token_file + "' is empty"};
      return nullptr;
    }
    client->token_ = token.substr(first, last - first + 1);
  }
  grpc::ChannelArguments arguments;
  arguments.SetMaxReceiveMessageSize(256 << 20);
  client->channel_ = grpc::CreateCustomChannel(address.server, credentials, arguments);
  client->stub_ = v1::Posewarp::NewStub(client->channel_);
  return client;
}

std::unique_ptr<grpc::ClientContext> ViewerClient::context(const std::string& rig_id) const {
  auto context = std::make_unique<grpc::ClientContext>();
  if (!token_.empty()) context->AddMetadata("authorization", "Bearer " + token_);
  if (!rig_id.empty()) context->AddMetadata("x-posewarp-rig", rig_id);
  return context;
}

CallError ViewerClient::list_rigs(std::vector<v1::Rig>* rigs) const {
  v1::ListRigsRequest request;
  request.set_page_size(1000);
  for (;;) {
    v1::ListRigsResponse page;
    const auto call = context();
    call->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(30));
    if (CallError e = error_of(stub_->ListRigs(call.get(), request, &page), server_); e.failed()) return e;
    rigs->insert(rigs->end(), page.rigs().begin(), page.rigs().end());
    if (page.next_page_token().empty()) return {};
    request.set_page_token(page.next_page_token());
  }
}

CallError ViewerClient::rig(const std::string& rig_id, v1::Rig* rig) const {
  v1::GetRigRequest request;
  request.set_rig_id(rig_id);
  const auto call = context(rig_id);
  return error_of(stub_->GetRig(call.get(), request, rig), server_);
}

CallError ViewerClient::assets(const std::string& rig_id, RigAssets* assets) const {
  v1::GetRigAssetsRequest request;
  request.set_rig_id(rig_id);
  request.set_format(v1::ASSET_FORMAT_RAW);
  const auto call = context(rig_id);
  auto reader = stub_->GetRigAssets(call.get(), request);
  v1::RigAsset part;
  while (reader->Read(&part)) {
    if (part.has_skeleton()) assets->skeleton = part.skeleton();
    if (part.has_surface()) assets->surfaces.push_back(part.surface());
  }
  return error_of(reader->Finish(), server_);
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
  reader_.join();
}

uint64_t PreviewSession::send(const PoseAngles& angles, v1::Method method) {
  v1::PreviewRequest update;
  uint64_t sequence = 0;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    sequence = next_sequence_++;
    sent_at_[sequence] = std::chrono::steady_clock::now();
  }
  if (sequence == 1) update.set_rig_id(rig_id_);
  update.set_sequence(sequence);
  update.set_pose_json(pose_json(angles));
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
      answer.joint_centres.push_back({response.joint_centres(i), response.joint_centres(i + 1), response.joint_centres(i + 2)});
    }
    std::lock_guard<std::mutex> lock(mutex_);
    const auto sent = sent_at_.find(answer.sequence);
    if (sent != sent_at_.end()) {
      answer.round_trip_ms = std::chrono::duration<double, std::milli>(std::chrono::steady_clock::now() - sent->second).count();
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
  return answered_.wait_for(lock, std::chrono::milliseconds(timeout_ms),
                            [&] { return last_answered_ >= sequence || closed_; }) &&
         last_answered_ >= sequence;
}

uint64_t PreviewSession::answers() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return answers_;
}

CallError PreviewSession::ended() const {
  std::lock_guard<std::mutex> lock(mutex_);
  return end_;
}

}  // namespace posewarp::view
