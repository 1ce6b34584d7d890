// The preview session: newest-update reader and the answers.
#include "preview_session.h"

#include <utility>

#include "convert.h"

namespace posewarp::server {

PreviewUpdates::PreviewUpdates(grpc::ServerContext* context, PreviewStream* stream) : context_(context) {
  reader_ = std::thread([this, stream] {
    v1::PreviewRequest update;
    while (stream->Read(&update)) {
      std::lock_guard<std::mutex> lock(mutex_);
      if (rig_id_.empty()) rig_id_ = update.rig_id();
      if (latest_) ++skipped_;
      latest_ = std::move(update);
      arrived_.notify_one();
    }
    std::lock_guard<std::mutex> lock(mutex_);
    closed_ = true;
    arrived_.notify_one();
  });
}

PreviewUpdates::~PreviewUpdates() {
  bool reading = false;
  {
    std::lock_guard<std::mutex> lock(mutex_);
    reading = !closed_;
  }
  if (reading) context_->TryCancel();
  reader_.join();
}

bool PreviewUpdates::next(v1::PreviewRequest* update, uint64_t* dropped) {
  std::unique_lock<std::mutex> lock(mutex_);
  arrived_.wait(lock, [&] { return latest_.has_value() || closed_; });
  if (!latest_) return false;
  *update = std::move(*latest_);
  latest_.reset();
  *dropped = std::exchange(skipped_, 0);
  if (update->rig_id().empty()) update->set_rig_id(rig_id_);
  return true;
}

v1::PreviewResponse preview_answer(const v1::PreviewRequest& update, uint64_t dropped,
                                   const api::PreviewResult& preview, PreviewSession& session,
                                   const Stopwatch& start) {
  v1::PreviewResponse answer;
  answer.set_sequence(update.sequence());
  answer.set_dropped(dropped);
  const std::vector<SurfaceMesh>& rest = session.engine->rig().surfaces;
  for (size_t i = 0; i < preview.surface_vertices.size(); ++i) {
    v1::SurfacePositions* positions = answer.add_surfaces();
    positions->set_name(rest[i].name);
    const Eigen::MatrixXd& v = preview.surface_vertices[i];
    positions->mutable_vertices()->Reserve(static_cast<int>(v.size()));
    for (Eigen::Index r = 0; r < v.rows(); ++r) {
      for (int a = 0; a < 3; ++a) positions->add_vertices(static_cast<float>(v(r, a)));
    }
    if (!session.topology_sent) put_surface(rest[i], false, answer.add_topology());
  }
  session.topology_sent = true;
  for (const Eigen::Vector3d& c : preview.joint_centres) {
    for (int a = 0; a < 3; ++a) answer.add_joint_centres(c[a]);
  }
  answer.set_server_ms(1000.0 * start.seconds());
  return answer;
}

v1::PreviewResponse preview_refusal(const v1::PreviewRequest& update, uint64_t dropped, int32_t code,
                                    const std::string& message) {
  v1::PreviewResponse answer;
  answer.set_sequence(update.sequence());
  answer.set_dropped(dropped);
  answer.set_error_code(code);
  answer.set_error_message(message);
  return answer;
}

}  // namespace posewarp::server
