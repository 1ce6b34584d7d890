// The real posewarp-server process on a loopback port, driven through the generated gRPC client: upload a bar
// phantom's volumes, build its rig as an operation, pose it, and compare with the same rig posed in this process;
// bad requests get their canonical codes and the server keeps serving; SIGTERM ends it with exit 0.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>
#include <signal.h>
#include <sys/wait.h>
#include <unistd.h>

#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <iterator>
#include <sstream>
#include <string>
#include <thread>
#include <vector>

#include "posewarp/api/files.h"
#include "posewarp/api/pose_engine.h"
#include "posewarp/api/rig_file.h"
#include "posewarp/common/sha256.h"
#include "posewarp/v1/posewarp.grpc.pb.h"
#include "server_process.h"

namespace posewarp {
namespace {

using namespace testing_server;

class Server : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = fs::temp_directory_path() / ("posewarp-server-test-" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    ASSERT_EQ(run({POSEWARP_CLI, "--quiet", "phantom", "bar", "-o", (dir_ / "bar").string()}), 0);
    server_ = new ServerProcess(dir_ / "store", {"--pose-slots", "2"});
    ASSERT_GT(server_->port(), 0);
    channel_ = grpc::CreateChannel("127.0.0.1:" + std::to_string(server_->port()), grpc::InsecureChannelCredentials());
    ASSERT_TRUE(channel_->WaitForConnected(std::chrono::system_clock::now() + std::chrono::seconds(60)));  // a loaded CI machine
    stub_ = v1::Posewarp::NewStub(channel_);
  }
  static void TearDownTestSuite() {
    stub_.reset();
    channel_.reset();
    delete server_;
    fs::remove_all(dir_);
  }

  static grpc::Status upload(const fs::path& path, v1::VolumeKind kind, v1::Volume* volume,
                             const std::string& claimed_sha = "") {
    const std::string bytes = file_text(path);
    grpc::ClientContext context;
    auto writer = stub_->UploadVolume(&context, volume);
    v1::UploadVolumeRequest header;
    header.mutable_header()->set_kind(kind);
    header.mutable_header()->set_format(v1::FILE_FORMAT_NIFTI_GZ);
    header.mutable_header()->set_size_bytes(bytes.size());
    header.mutable_header()->set_sha256(claimed_sha.empty() ? sha256_hex(bytes) : claimed_sha);
    writer->Write(header);
    for (size_t offset = 0; offset < bytes.size(); offset += 4096) {
      v1::UploadVolumeRequest chunk;
      chunk.set_chunk(bytes.substr(offset, 4096));
      writer->Write(chunk);
    }
    writer->WritesDone();
    return writer->Finish();
  }

  // Uploads the bar, builds its rig and returns the rig id (once per test binary).
  static std::string bar_rig_id() {
    static std::string id;
    if (!id.empty()) return id;
    v1::Volume labels, ct;
    EXPECT_TRUE(upload(dir_ / "bar" / "labels.nii.gz", v1::VOLUME_KIND_LABELS, &labels).ok());
    EXPECT_TRUE(upload(dir_ / "bar" / "ct.nii.gz", v1::VOLUME_KIND_INTENSITY, &ct).ok());
    v1::BuildRigRequest build;
    build.set_labels_volume_id(labels.id());
    build.set_ct_volume_id(ct.id());
    build.set_label_map_json(file_text(dir_ / "bar" / "label_map.json"));
    build.set_name("bar phantom");
    v1::Operation operation;
    {
      grpc::ClientContext context;
      EXPECT_TRUE(stub_->BuildRig(&context, build, &operation).ok());
    }
    grpc::ClientContext context;
    v1::GetOperationRequest watch;
    watch.set_operation_id(operation.id());
    auto reader = stub_->WatchOperation(&context, watch);
    v1::Operation state;
    while (reader->Read(&state)) operation = state;
    EXPECT_TRUE(reader->Finish().ok());
    EXPECT_EQ(operation.state(), v1::Operation::SUCCEEDED) << operation.error_message();
    id = operation.rig_id();
    return id;
  }

  static inline fs::path dir_;
  static inline ServerProcess* server_ = nullptr;
  static inline std::shared_ptr<grpc::Channel> channel_;
  static inline std::unique_ptr<v1::Posewarp::Stub> stub_;
};

TEST_F(Server, UploadBuildAndPoseGiveWhatTheEnginePosesLocally) {
  const std::string rig_id = bar_rig_id();
  ASSERT_TRUE(is_hex_id(rig_id));
  v1::PoseRequest request;
  request.set_rig_id(rig_id);
  request.set_pose_json(file_text(fs::path(POSEWARP_SOURCE_DIR) / "data/poses/bar_bend_90.json"));
  request.set_want_labels(true);
  request.set_want_ct(true);
  request.set_want_surfaces(true);
  request.set_samples(v1::SAMPLE_TYPE_COMPUTED);  // int32 labels and float32 CT, compared byte for byte below
  request.set_chunk_bytes(65536);
  grpc::ClientContext context;
  auto reader = stub_->Pose(&context, request);
  v1::PoseResponse part;
  v1::PoseHeader header;
  std::string labels, ct, report;
  int surfaces = 0;
  while (reader->Read(&part)) {
    if (part.has_header()) header = part.header();
    if (part.has_labels()) {
      EXPECT_EQ(part.labels().offset(), labels.size());
      labels += part.labels().data();
    }
    if (part.has_ct()) ct += part.ct().data();
    if (part.has_surface()) ++surfaces;
    if (part.has_report()) report = part.report().json();
  }
  const grpc::Status status = reader->Finish();
  ASSERT_TRUE(status.ok()) << status.error_message();
  EXPECT_EQ(labels.size(), header.label_bytes());
  EXPECT_EQ(ct.size(), header.ct_bytes());
  EXPECT_FALSE(report.empty());

  // The same rig, read from the store and posed in this process.
  Result<api::Rig> rig = api::load_rig((dir_ / "store" / "rigs" / (rig_id + ".rig")).string());
  ASSERT_TRUE(rig.ok()) << rig.status().to_string();
  Result<api::PoseEngine> engine = api::PoseEngine::create(std::move(rig).value());
  ASSERT_TRUE(engine.ok());
  api::PoseRequest local;
  local.pose = *api::read_pose((fs::path(POSEWARP_SOURCE_DIR) / "data/poses/bar_bend_90.json").string());
  Result<api::PoseResult> result = engine->pose(local);
  ASSERT_TRUE(result.ok()) << result.status().to_string();
  ASSERT_EQ(labels.size(), result->labels->voxel_count() * sizeof(Label));
  EXPECT_EQ(std::memcmp(labels.data(), result->labels->data(), labels.size()), 0);  // byte for byte
  ASSERT_EQ(ct.size(), result->ct->voxel_count() * sizeof(float));
  EXPECT_EQ(std::memcmp(ct.data(), result->ct->data(), ct.size()), 0);
  EXPECT_EQ(surfaces, static_cast<int>(result->surfaces.size()));
  EXPECT_EQ(header.grid().size(0), result->output_grid.size[0]);

  // The same build again is answered from the store.
  v1::GetRigRequest get;
  get.set_rig_id(rig_id);
  v1::Rig info;
  grpc::ClientContext get_context;
  ASSERT_TRUE(stub_->GetRig(&get_context, get, &info).ok());
  EXPECT_EQ(info.name(), "bar phantom");
  EXPECT_EQ(info.joints_size(), static_cast<int>(engine->rig().skeleton.joints.size()));
  // Each joint's range of motion, measured at build, as the local rig says it.
  ASSERT_GT(info.joints_size(), 0);
  const auto& first = engine->rig().skeleton.joints[0];
  ASSERT_EQ(info.joints(0).ranges_size(), static_cast<int>(first.ranges.size()));
  ASSERT_GT(info.joints(0).ranges_size(), 0);
  EXPECT_EQ(info.joints(0).ranges(0).motion(), first.ranges[0].motion);
  EXPECT_EQ(info.joints(0).ranges(0).positive_deg(), first.ranges[0].positive_deg);
  v1::ListRigsResponse listed;
  grpc::ClientContext list_context;
  ASSERT_TRUE(stub_->ListRigs(&list_context, {}, &listed).ok());
  ASSERT_EQ(listed.rigs_size(), 1);
  EXPECT_EQ(listed.rigs(0).id(), rig_id);
}

// A pose request's labels and CT as computed (int32, float32), or why it was refused.
grpc::Status posed_volumes(v1::Posewarp::Stub& stub, v1::PoseRequest request, std::string* labels, std::string* ct) {
  request.set_want_labels(true);
  request.set_want_ct(true);
  request.set_samples(v1::SAMPLE_TYPE_COMPUTED);
  grpc::ClientContext context;
  auto reader = stub.Pose(&context, request);
  v1::PoseResponse part;
  while (reader->Read(&part)) {
    if (part.has_labels()) *labels += part.labels().data();
    if (part.has_ct()) *ct += part.ct().data();
  }
  return reader->Finish();
}

// The typed Pose poses exactly as the same pose in JSON (root turned and moved, anatomical angles, a quaternion), and
// what the JSON could not say wrongly or that the rig does not have is refused with the field named.
TEST_F(Server, ATypedPoseGivesTheVolumesOfTheSamePoseInJsonAndItsMistakesAreNamed) {
  const std::string rig_id = bar_rig_id();
  v1::PoseRequest as_json;
  as_json.set_rig_id(rig_id);
  as_json.set_pose_json(R"({"format": "posewarp.pose", "version": 1, "name": "typed",
    "root": {"translation_mm": [3.5, -2, 5], "rotation": {"axis_angle": {"axis": [0, 0, 1], "degrees": 10}}},
    "joints": {"joint_2_3": {"angles_deg": {"flexion": 60, "abduction": 15}},
               "joint_1_2": {"quaternion": [0.9659258262890683, 0.25881904510252074, 0, 0]}}})");
  v1::PoseRequest typed;
  typed.set_rig_id(rig_id);
  v1::Pose* pose = typed.mutable_pose();
  pose->set_name("typed");
  for (const double mm : {3.5, -2.0, 5.0}) pose->mutable_root()->add_translation_mm(mm);
  v1::AxisAngle* turn = pose->mutable_root()->mutable_rotation()->mutable_axis_angle();
  for (const double a : {0.0, 0.0, 1.0}) turn->add_axis(a);
  turn->set_degrees(10);
  v1::JointRotation* knee = pose->add_joints();
  knee->set_joint("joint_2_3");
  knee->mutable_angles()->set_flexion_deg(60);
  knee->mutable_angles()->set_abduction_deg(15);
  v1::JointRotation* hip = pose->add_joints();
  hip->set_joint("joint_1_2");
  hip->mutable_quaternion()->set_w(0.9659258262890683);
  hip->mutable_quaternion()->set_x(0.25881904510252074);
  std::string json_labels, json_ct, typed_labels, typed_ct;
  ASSERT_TRUE(posed_volumes(*stub_, as_json, &json_labels, &json_ct).ok());
  const grpc::Status status = posed_volumes(*stub_, typed, &typed_labels, &typed_ct);
  ASSERT_TRUE(status.ok()) << status.error_message();
  ASSERT_FALSE(json_labels.empty());
  EXPECT_TRUE(typed_labels == json_labels);  // byte for byte
  EXPECT_TRUE(typed_ct == json_ct);
  std::string rest_labels, rest_ct;  // and the pose did move something
  v1::PoseRequest rest;
  rest.set_rig_id(rig_id);
  rest.mutable_pose();
  ASSERT_TRUE(posed_volumes(*stub_, rest, &rest_labels, &rest_ct).ok());
  EXPECT_FALSE(rest_labels == typed_labels);

  const std::vector<std::pair<std::function<void(v1::PoseRequest&)>, std::string>> mistakes = {
      {[](v1::PoseRequest& r) { r.set_pose_json("{\"joints\": {}}"); }, "both pose and pose_json"},
      {[](v1::PoseRequest& r) { r.mutable_pose()->mutable_joints(0)->set_joint("joint_2_33"); }, "joint_2_3\""},
      {[](v1::PoseRequest& r) { r.mutable_pose()->mutable_joints(0)->mutable_angles()->set_flexion_deg(NAN); }, "NaN"},
      {[](v1::PoseRequest& r) { r.mutable_pose()->mutable_joints(0)->mutable_angles()->set_flexion_deg(400); },
       "flexion"},
      {[](v1::PoseRequest& r) { r.mutable_pose()->mutable_joints(1)->set_joint("joint_2_3"); }, "second time"},
      {[](v1::PoseRequest& r) { r.mutable_pose()->mutable_joints(1)->clear_quaternion(); }, "no rotation"},
      {[](v1::PoseRequest& r) { r.mutable_pose()->mutable_joints(1)->mutable_quaternion()->set_w(2); }, "quaternion"},
      {[](v1::PoseRequest& r) { r.mutable_pose()->mutable_root()->mutable_translation_mm()->RemoveLast(); }, "give 3"},
  };
  for (const auto& [spoil, says] : mistakes) {
    v1::PoseRequest wrong = typed;
    spoil(wrong);
    std::string l, c;
    const grpc::Status refused = posed_volumes(*stub_, wrong, &l, &c);
    EXPECT_EQ(refused.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << says << ": " << refused.error_message();
    EXPECT_NE(refused.error_message().find(says), std::string::npos) << refused.error_message();
  }
  // The preview takes it too.
  grpc::ClientContext context;
  auto stream = stub_->Preview(&context);
  v1::PreviewRequest update;
  update.set_rig_id(rig_id);
  update.set_sequence(1);
  *update.mutable_pose() = typed.pose();
  ASSERT_TRUE(stream->Write(update));
  v1::PreviewResponse answer;
  ASSERT_TRUE(stream->Read(&answer));
  EXPECT_EQ(answer.error_code(), 0) << answer.error_message();
  EXPECT_EQ(answer.sequence(), 1u);
  EXPECT_GT(answer.surfaces_size(), 0);
  stream->WritesDone();
  while (stream->Read(&answer)) {
  }
  EXPECT_TRUE(stream->Finish().ok());
}

TEST_F(Server, BadRequestsGetTheirCanonicalCodesAndTheServerKeepsServing) {
  v1::Volume volume;
  EXPECT_EQ(upload(dir_ / "bar" / "labels.nii.gz", v1::VOLUME_KIND_LABELS, &volume, std::string(64, 'a')).error_code(),
            grpc::StatusCode::DATA_LOSS);
  // Bytes that are not a volume (a pose file uploaded as labels): refused, named as the upload, no server path.
  {
    std::ofstream(dir_ / "not_a_volume.nii.gz") << "{\"joints\": {}}";
    const grpc::Status refused = upload(dir_ / "not_a_volume.nii.gz", v1::VOLUME_KIND_LABELS, &volume);
    EXPECT_EQ(refused.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << refused.error_message();
    EXPECT_EQ(refused.error_message().find(dir_.string()), std::string::npos) << refused.error_message();
  }
  for (const std::string& id : {std::string("../../etc/passwd"), std::string(64, '0'), std::string("abc/def")}) {
    v1::PoseRequest request;
    request.set_rig_id(id);
    request.set_pose_json("{}");
    grpc::ClientContext context;
    auto reader = stub_->Pose(&context, request);
    v1::PoseResponse part;
    while (reader->Read(&part)) {
    }
    const grpc::Status status = reader->Finish();
    EXPECT_EQ(status.error_code(), id.size() == 64 ? grpc::StatusCode::NOT_FOUND : grpc::StatusCode::INVALID_ARGUMENT)
        << id << ": " << status.error_message();
  }
  {
    v1::PoseRequest request;
    request.set_rig_id(bar_rig_id());
    request.set_pose_json("{\"joints\": {\"joint_2_3\": {\"axis_angle\": {\"axis\": [1, 0, 0]}}}}");
    grpc::ClientContext context;
    auto reader = stub_->Pose(&context, request);
    v1::PoseResponse part;
    while (reader->Read(&part)) {
    }
    EXPECT_EQ(reader->Finish().error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  }
  {
    v1::PoseRequest request;  // over its own output budget: refused before the warp allocates
    request.set_rig_id(bar_rig_id());
    request.set_pose_json(file_text(fs::path(POSEWARP_SOURCE_DIR) / "data/poses/bar_bend_90.json"));
    request.set_want_labels(true);
    request.set_max_output_bytes(1000);
    grpc::ClientContext context;
    auto reader = stub_->Pose(&context, request);
    v1::PoseResponse part;
    while (reader->Read(&part)) {
    }
    EXPECT_EQ(reader->Finish().error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  }
  v1::BuildRigRequest build;
  build.set_labels_volume_id(std::string(64, 'f'));
  v1::Operation operation;
  grpc::ClientContext context;
  EXPECT_EQ(stub_->BuildRig(&context, build, &operation).error_code(), grpc::StatusCode::NOT_FOUND);
  // Still serving.
  v1::ListRigsResponse listed;
  grpc::ClientContext list_context;
  EXPECT_TRUE(stub_->ListRigs(&list_context, {}, &listed).ok());
}

// The CLI's remote mode writes the same files as its local mode on the same rig (reports equal but for timings).
TEST_F(Server, RemoteAndLocalCommandsWriteTheSameFiles) {
  const std::string server = "127.0.0.1:" + std::to_string(server_->port());
  const fs::path out = dir_ / "remote";
  fs::create_directories(out);
  const std::string bar = (dir_ / "bar").string();
  std::string id = output_of({POSEWARP_CLI, "-q", "rig", "build", "--server", server, "--labels", bar + "/labels.nii.gz",
                              "--ct", bar + "/ct.nii.gz", "--label-map", bar + "/label_map.json"});
  if (!id.empty() && id.back() == '\n') id.pop_back();
  ASSERT_TRUE(is_hex_id(id)) << id;
  const std::string pose = (fs::path(POSEWARP_SOURCE_DIR) / "data/poses/bar_bend_90.json").string();
  // A mesh of the user's own, a small triangle at the middle of the bar (rest space).
  Result<api::VolumeHeader> grid = api::read_header(bar + "/labels.nii.gz");
  ASSERT_TRUE(grid.ok());
  const Index3& n = grid->geometry.size;
  const Vec3 c = grid->geometry.index_to_physical({n[0] / 2.0, n[1] / 2.0, n[2] / 2.0});
  std::ofstream(dir_ / "needle.obj") << "v " << c[0] << " " << c[1] << " " << c[2] << "\nv " << c[0] + 2 << " " << c[1]
                                     << " " << c[2] << "\nv " << c[0] << " " << c[1] + 2 << " " << c[2] << "\nf 1 2 3\n";
  for (const std::string mode : {"remote", "local"}) {
    const fs::path at = out / mode;
    std::vector<std::string> args{POSEWARP_CLI, "-q", "pose"};
    if (mode == "remote") {
      args.insert(args.end(), {"--server", server, id});
    } else {
      args.push_back((dir_ / "store" / "rigs" / (id + ".rig")).string());
    }
    args.insert(args.end(), {"--pose", pose, "--method", "dqs", "--labels-out", (at / "labels.nii.gz").string(),
                             "--ct-out", (at / "ct.nii.gz").string(), "--surfaces-out", (at / "surfaces").string(),
                             "--field-out", (at / "field.nii.gz").string(), "--surface", (dir_ / "needle.obj").string(),
                             "--grid-like", bar + "/labels.nii.gz", "--nearest-ct"});
    fs::create_directories(at);
    ASSERT_EQ(run(args), 0) << mode;
    // Animation frames (a BVH retargeted on the rig's skeleton, which the remote run downloads).
    std::vector<std::string> animate{POSEWARP_CLI, "-q", "animate"};
    if (mode == "remote") {
      animate.insert(animate.end(), {"--server", server, id});
    } else {
      animate.push_back((dir_ / "store" / "rigs" / (id + ".rig")).string());
    }
    const std::string poses = (fs::path(POSEWARP_SOURCE_DIR) / "data/poses").string();
    animate.insert(animate.end(), {"--bvh", poses + "/bar_wave.bvh", "--map", poses + "/bar_wave_map.json", "--frames",
                                   "0:1", "--out-dir", (at / "frames").string()});
    ASSERT_EQ(run(animate), 0) << mode;
  }
  for (const std::string file : {"labels.nii.gz", "ct.nii.gz", "field.nii.gz", "field_forward.nii.gz",
                                 "frames/frame_0000_labels.nii.gz", "frames/frame_0001_ct.nii.gz"}) {
    ASSERT_TRUE(fs::exists(out / "local" / file)) << file;
    EXPECT_EQ(file_text(out / "remote" / file), file_text(out / "local" / file)) << file;
  }
  int surfaces = 0;
  for (const auto& entry : fs::directory_iterator(out / "local" / "surfaces")) {
    EXPECT_EQ(file_text(entry.path()), file_text(out / "remote" / "surfaces" / entry.path().filename()));
    ++surfaces;
  }
  EXPECT_GT(surfaces, 1);
  EXPECT_TRUE(fs::exists(out / "remote" / "surfaces" / "needle.vtp"));
  // A rig path where an id belongs, and an unreachable server, are clear errors with the documented codes.
  EXPECT_EQ(run({POSEWARP_CLI, "pose", "--server", server, "bar.rig", "--pose", pose}) >> 8, 2);
  EXPECT_EQ(run({POSEWARP_CLI, "rig", "list", "--server", "127.0.0.1:1", "--retries", "0"}) >> 8, 1);
}

// MatchPosture on the bar: a target posed locally (the middle joint bent 30 degrees, the root moved), uploaded and
// matched on the server, gives the angle back with each bone on its target; the CLI's match through the server
// writes the same pose, report and posed labels as the local match on the store's rig; mistakes get their codes.
TEST_F(Server, AMatchOnTheServerFindsTheTargetsPoseAsTheLocalMatchDoes) {
  const std::string rig_id = bar_rig_id();
  ASSERT_TRUE(is_hex_id(rig_id));
  const std::string server = "127.0.0.1:" + std::to_string(server_->port());
  const fs::path at = dir_ / "match";
  fs::create_directories(at);
  const std::string rig_file = (dir_ / "store" / "rigs" / (rig_id + ".rig")).string();
  std::ofstream(at / "truth.json") << R"({"format": "posewarp.pose", "version": 1, "name": "truth",
    "root": {"translation_mm": [3, -2, 4]}, "joints": {"joint_2_3": {"angles_deg": {"flexion": 30}}}})";
  ASSERT_EQ(run({POSEWARP_CLI, "-q", "pose", rig_file, "--pose", (at / "truth.json").string(), "--labels-out",
                 (at / "target.nii.gz").string()}),
            0);
  v1::Volume target, ct;
  ASSERT_TRUE(upload(at / "target.nii.gz", v1::VOLUME_KIND_LABELS, &target).ok());
  v1::MatchPostureRequest request;
  request.set_rig_id(rig_id);
  request.set_target_labels_volume_id(target.id());
  v1::MatchPostureResponse answer;
  {
    grpc::ClientContext context;
    const grpc::Status status = stub_->MatchPosture(&context, request, &answer);
    ASSERT_TRUE(status.ok()) << status.error_message();
  }
  bool found_joint = false;
  for (const v1::SegmentMatch& s : answer.segments()) {
    EXPECT_TRUE(s.matched()) << s.segment() << ": " << s.skipped();
    if (s.volume_ml() > 5.0) {
      EXPECT_GT(s.dice(), 0.9) << s.segment();
    }
    if (s.joint() == "joint_2_3") {
      found_joint = true;
      EXPECT_NEAR(s.angles().flexion_deg(), 30.0, 2.0);
    }
  }
  EXPECT_TRUE(found_joint);
  ASSERT_EQ(answer.pose().root().translation_mm_size(), 3);
  EXPECT_NEAR(answer.pose().root().translation_mm(2), 4.0, 2.0);
  EXPECT_NE(answer.pose_json().find("joint_2_3"), std::string::npos);
  EXPECT_NE(answer.report_json().find("\"format\": \"posewarp.match\""), std::string::npos);
  Result<api::VolumeHeader> grid = api::read_header((at / "target.nii.gz").string());
  ASSERT_TRUE(grid.ok());
  EXPECT_EQ(answer.target_grid().size(0), grid->geometry.size[0]);

  // The CLI: through the server and in this process, the same files.
  for (const std::string mode : {"remote", "local"}) {
    fs::create_directories(at / mode);
    std::vector<std::string> args{POSEWARP_CLI, "-q", "match"};
    if (mode == "remote") {
      args.insert(args.end(), {"--server", server, rig_id});
    } else {
      args.push_back(rig_file);
    }
    const fs::path out = at / mode;
    args.insert(args.end(), {"--target-labels", (at / "target.nii.gz").string(), "-o", (out / "pose.json").string(),
                             "--labels-out", (out / "labels.nii.gz").string()});
    ASSERT_EQ(run(args), 0) << mode;
  }
  for (const std::string file : {"pose.json", "labels.nii.gz"}) {
    ASSERT_TRUE(fs::exists(at / "local" / file)) << file;
    EXPECT_EQ(file_text(at / "remote" / file), file_text(at / "local" / file)) << file;
  }

  // Mistakes: a target and a standard both, a CT as the target, a volume the store lacks, a posture nobody defined.
  ASSERT_TRUE(upload(dir_ / "bar" / "ct.nii.gz", v1::VOLUME_KIND_INTENSITY, &ct).ok());
  const auto refused = [&](v1::MatchPostureRequest bad) {
    grpc::ClientContext context;
    v1::MatchPostureResponse ignored;
    return stub_->MatchPosture(&context, bad, &ignored);
  };
  v1::MatchPostureRequest both = request;
  both.set_standard("limbs-straight");
  EXPECT_EQ(refused(both).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  v1::MatchPostureRequest wrong_kind = request;
  wrong_kind.set_target_labels_volume_id(ct.id());
  const grpc::Status swapped = refused(wrong_kind);
  EXPECT_EQ(swapped.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(swapped.error_message().find("VOLUME_KIND_INTENSITY"), std::string::npos) << swapped.error_message();
  v1::MatchPostureRequest missing = request;
  missing.set_target_labels_volume_id(std::string(64, 'a'));
  EXPECT_EQ(refused(missing).error_code(), grpc::StatusCode::NOT_FOUND);
  v1::MatchPostureRequest unknown;
  unknown.set_rig_id(rig_id);
  unknown.set_standard("t-pose");
  const grpc::Status no_posture = refused(unknown);
  EXPECT_EQ(no_posture.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(no_posture.error_message().find("arms-up"), std::string::npos) << no_posture.error_message();
}

// The preview stream flooded with 10,000 updates: the latest wins (the last update is answered, the skipped ones
// are counted), the topology comes once, and the server keeps serving.
TEST_F(Server, APreviewFloodedWithUpdatesAnswersTheLatest) {
  const std::string rig_id = bar_rig_id();
  grpc::ClientContext context;
  auto stream = stub_->Preview(&context);
  constexpr uint64_t kUpdates = 10000;
  std::thread writer([&] {
    for (uint64_t i = 1; i <= kUpdates; ++i) {
      v1::PreviewRequest update;
      if (i == 1) update.set_rig_id(rig_id);
      update.set_sequence(i);
      update.set_pose_json("{\"joints\": {\"joint_2_3\": {\"axis_angle\": {\"axis\": [1, 0, 0], \"degrees\": " +
                           std::to_string(static_cast<double>(i % 90)) + "}}}}");
      if (!stream->Write(update)) break;
    }
    stream->WritesDone();
  });
  v1::PreviewResponse answer;
  uint64_t answers = 0, dropped = 0, last = 0;
  int topology = 0;
  size_t surfaces = 0;
  while (stream->Read(&answer)) {
    ++answers;
    dropped += answer.dropped();
    EXPECT_GT(answer.sequence(), last);
    last = answer.sequence();
    topology += answer.topology_size();
    surfaces = static_cast<size_t>(answer.surfaces_size());
  }
  writer.join();
  const grpc::Status status = stream->Finish();
  ASSERT_TRUE(status.ok()) << status.error_message();
  EXPECT_EQ(last, kUpdates);                 // the newest update is always answered
  EXPECT_EQ(answers + dropped, kUpdates);    // every update answered or counted as skipped
  EXPECT_GT(dropped, 0u);                    // the flood outran the server
  EXPECT_EQ(topology, static_cast<int>(surfaces));  // topology once per surface
  EXPECT_GT(surfaces, 0u);
  // A bad update is answered with its code and the stream goes on; the server still serves.
  grpc::ClientContext bad_context;
  auto bad = stub_->Preview(&bad_context);
  v1::PreviewRequest update;
  update.set_rig_id(rig_id);
  update.set_sequence(1);
  update.set_pose_json("{\"joints\": {\"nobody\": {\"axis_angle\": {\"axis\": [1, 0, 0], \"degrees\": 5}}}}");
  ASSERT_TRUE(bad->Write(update));
  ASSERT_TRUE(bad->Read(&answer));
  EXPECT_EQ(answer.error_code(), static_cast<int>(grpc::StatusCode::INVALID_ARGUMENT));
  EXPECT_NE(answer.error_message().find("nobody"), std::string::npos) << answer.error_message();
  update.set_sequence(2);
  update.set_pose_json("{\"joints\": {}}");
  ASSERT_TRUE(bad->Write(update));
  ASSERT_TRUE(bad->Read(&answer));
  EXPECT_EQ(answer.error_code(), 0);
  EXPECT_EQ(answer.sequence(), 2u);
  bad->WritesDone();
  while (bad->Read(&answer)) {
  }
  EXPECT_TRUE(bad->Finish().ok());
  v1::ListRigsResponse listed;
  grpc::ClientContext list_context;
  EXPECT_TRUE(stub_->ListRigs(&list_context, {}, &listed).ok());
}

// Runs last in this binary (gtest runs tests in order): SIGTERM stops the server with exit 0.
TEST_F(Server, ZzSigtermStopsTheServerCleanly) {
  EXPECT_EQ(server_->stop(), 0);
}

}  // namespace
}  // namespace posewarp
