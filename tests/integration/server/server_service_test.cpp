// The real posewarp-server as an operator runs it: kill -9 during a build and inside a rig write, then a restart
// on the same store; damaged rig files quarantined; 16 clients at once; the build queue's bound; cancellation and
// deadlines freeing their worker; SIGTERM with a pose in flight; tokens, TLS and metrics; the rig RPCs.
#include <gtest/gtest.h>

#include <atomic>
#include <cstring>
#include <fstream>
#include <future>

#include <grpcpp/generic/generic_stub.h>

#include "posewarp/api/pose_engine.h"
#include "posewarp/api/rig_file.h"
#include "server_process.h"

namespace posewarp {
namespace {

using namespace testing_server;

class ServerService : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = fs::temp_directory_path() / ("posewarp-service-test-" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    ASSERT_EQ(run({POSEWARP_CLI, "--quiet", "phantom", "bar", "-o", (dir_ / "bar").string()}), 0);
  }
  static void TearDownTestSuite() { fs::remove_all(dir_); }

  // A fresh store per test.
  fs::path store(const std::string& name) const { return dir_ / ("store-" + name); }

  static v1::BuildRigRequest bar_build(v1::Posewarp::Stub& stub, const std::string& token = "") {
    v1::Volume labels, ct;
    EXPECT_TRUE(upload(stub, dir_ / "bar" / "labels.nii.gz", v1::VOLUME_KIND_LABELS, &labels, token).ok());
    EXPECT_TRUE(upload(stub, dir_ / "bar" / "ct.nii.gz", v1::VOLUME_KIND_INTENSITY, &ct, token).ok());
    v1::BuildRigRequest build;
    build.set_labels_volume_id(labels.id());
    build.set_ct_volume_id(ct.id());
    build.set_label_map_json(file_text(dir_ / "bar" / "label_map.json"));
    build.set_name("bar phantom");
    return build;
  }

  static std::string build_rig(v1::Posewarp::Stub& stub) {
    v1::BuildRigRequest build = bar_build(stub);
    v1::Operation operation;
    grpc::ClientContext context;
    EXPECT_TRUE(stub.BuildRig(&context, build, &operation).ok());
    const v1::Operation done = watch(stub, operation.id());
    EXPECT_EQ(done.state(), v1::Operation::SUCCEEDED) << done.error_message();
    return done.rig_id();
  }

  static v1::PoseRequest bend(const std::string& rig_id) {
    v1::PoseRequest request;
    request.set_rig_id(rig_id);
    request.set_pose_json(file_text(fs::path(POSEWARP_SOURCE_DIR) / "data/poses/bar_bend_90.json"));
    request.set_want_labels(true);
    request.set_want_ct(true);
    request.set_want_surfaces(true);
    return request;
  }

  static std::vector<std::string> files_in(const fs::path& directory) {
    std::vector<std::string> names;
    std::error_code ec;
    for (const auto& entry : fs::directory_iterator(directory, ec)) names.push_back(entry.path().filename().string());
    return names;
  }

  static inline fs::path dir_;
};

TEST_F(ServerService, AKillDuringARigWriteLeavesAStoreThatReopensCleanAndRebuilds) {
  const fs::path at = store("crash-write");
  std::string operation_id;
  {
    ServerProcess server(at, {}, {{"POSEWARP_TEST_PAUSE_IN_RIG_WRITE_S", "30"}});
    ASSERT_GT(server.port(), 0);
    auto stub = v1::Posewarp::NewStub(server.channel());
    v1::Operation operation;
    grpc::ClientContext context;
    ASSERT_TRUE(stub->BuildRig(&context, bar_build(*stub), &operation).ok());
    operation_id = operation.id();
    ASSERT_TRUE(server.wait_for_log("pausing", 120)) << server.log();
    // The half-written rig exists only as a partial file.
    bool partial = false;
    for (const std::string& name : files_in(at / "rigs")) partial |= name.find("partial") != std::string::npos;
    EXPECT_TRUE(partial);
    server.kill();
  }
  ServerProcess server(at);
  ASSERT_GT(server.port(), 0) << server.log();
  auto stub = v1::Posewarp::NewStub(server.channel());
  // The build the crash interrupted is FAILED (ABORTED), never left running; no rig; no partial file left.
  v1::Operation interrupted;
  {
    grpc::ClientContext context;
    v1::GetOperationRequest get;
    get.set_operation_id(operation_id);
    ASSERT_TRUE(stub->GetOperation(&context, get, &interrupted).ok());
  }
  EXPECT_EQ(interrupted.state(), v1::Operation::FAILED);
  EXPECT_EQ(interrupted.error_code(), static_cast<int>(grpc::StatusCode::ABORTED));
  EXPECT_NE(interrupted.error_message().find("server stopped during the build"), std::string::npos);
  {
    grpc::ClientContext context;
    v1::ListRigsResponse listed;
    ASSERT_TRUE(stub->ListRigs(&context, {}, &listed).ok());
    EXPECT_EQ(listed.rigs_size(), 0);
  }
  EXPECT_TRUE(server.wait_for_log("build(s) left running were marked failed", 10)) << server.log();
  EXPECT_TRUE(server.wait_for_log("partial file(s) of a writer that died", 10)) << server.log();
  EXPECT_TRUE(files_in(at / "rigs").empty());
  // Built again, it reads back whole and poses.
  const std::string rig_id = build_rig(*stub);
  EXPECT_TRUE(pose_remote(*stub, bend(rig_id)).status.ok());
  grpc::ClientContext context;
  v1::ListOperationsResponse operations;
  ASSERT_TRUE(stub->ListOperations(&context, {}, &operations).ok());
  ASSERT_EQ(operations.operations_size(), 2);
  EXPECT_EQ(operations.operations(0).state(), v1::Operation::SUCCEEDED);  // newest first
  EXPECT_EQ(operations.operations(1).id(), operation_id);
}

TEST_F(ServerService, OrphanAndDamagedRigFilesAreAdoptedOrQuarantinedNeverServed) {
  const fs::path at = store("orphans");
  std::string rig_id;
  {
    ServerProcess server(at);
    auto stub = v1::Posewarp::NewStub(server.channel());
    rig_id = build_rig(*stub);
    EXPECT_EQ(server.stop(), 0);
  }
  const fs::path rig_file = at / "rigs" / (rig_id + ".rig");
  const std::string good = file_text(rig_file);
  // The index loses its row (as a crash between the file and its row would leave it): the file is adopted.
  ASSERT_EQ(run({"sqlite3", (at / "index.sqlite").string(), "DELETE FROM rigs"}), 0);
  // A second, damaged rig file without a row: quarantined.
  const std::string damaged_id(64, 'a');
  {
    std::string bytes = good;
    bytes[bytes.size() / 2] ^= 0x5a;
    std::ofstream(at / "rigs" / (damaged_id + ".rig"), std::ios::binary) << bytes;
  }
  ServerProcess server(at);
  auto stub = v1::Posewarp::NewStub(server.channel());
  {
    grpc::ClientContext context;
    v1::ListRigsResponse listed;
    ASSERT_TRUE(stub->ListRigs(&context, {}, &listed).ok());
    ASSERT_EQ(listed.rigs_size(), 1);
    EXPECT_EQ(listed.rigs(0).id(), rig_id);
  }
  EXPECT_TRUE(fs::exists(at / "quarantine" / (damaged_id + ".rig")));
  EXPECT_TRUE(server.wait_for_log("checked and adopted", 10)) << server.log();
  EXPECT_TRUE(server.wait_for_log("moved to quarantine", 10)) << server.log();
  // A rig damaged on disk while indexed: the pose is refused with DATA_LOSS, the file quarantined, never served.
  {
    std::string bytes = good;
    bytes[bytes.size() / 3] ^= 0x5a;
    std::ofstream(rig_file, std::ios::binary | std::ios::trunc) << bytes;
  }
  const PoseAnswer refused = pose_remote(*stub, bend(rig_id));
  EXPECT_EQ(refused.status.error_code(), grpc::StatusCode::DATA_LOSS) << refused.status.error_message();
  EXPECT_EQ(refused.status.error_message().find(at.string()), std::string::npos);  // no server path
  EXPECT_TRUE(fs::exists(at / "quarantine" / (rig_id + ".rig")));
  EXPECT_FALSE(fs::exists(rig_file));
  EXPECT_EQ(pose_remote(*stub, bend(rig_id)).status.error_code(), grpc::StatusCode::NOT_FOUND);
}

TEST_F(ServerService, SixteenClientsPosingOneRigGetIdenticalResults) {
  ServerProcess server(store("sixteen"), {"--pose-slots", "2"});
  auto stub = v1::Posewarp::NewStub(server.channel());
  const std::string rig_id = build_rig(*stub);
  const PoseAnswer reference = pose_remote(*stub, bend(rig_id));
  ASSERT_TRUE(reference.status.ok());
  std::vector<std::future<PoseAnswer>> clients;
  for (int c = 0; c < 16; ++c) {
    clients.push_back(std::async(std::launch::async, [&] {
      auto own = v1::Posewarp::NewStub(server.channel());  // each client its own connection
      return pose_remote(*own, bend(rig_id));
    }));
  }
  for (auto& client : clients) {
    const PoseAnswer answer = client.get();
    ASSERT_TRUE(answer.status.ok()) << answer.status.error_message();
    EXPECT_EQ(answer.labels, reference.labels);
    EXPECT_EQ(answer.ct, reference.ct);
    EXPECT_EQ(answer.surfaces, reference.surfaces);
  }
}

TEST_F(ServerService, ASixthBuildPastTheQueueIsRefusedAndCancellingQueuedBuildsFreesThem) {
  // One build at a time, held inside its rig write, and a queue of 4.
  ServerProcess server(store("queue"), {"--build-queue", "4"}, {{"POSEWARP_TEST_PAUSE_IN_RIG_WRITE_S", "5"}});
  auto stub = v1::Posewarp::NewStub(server.channel());
  v1::BuildRigRequest build = bar_build(*stub);
  const std::string map = build.label_map_json();
  std::vector<v1::Operation> operations;
  for (int i = 0; i < 6; ++i) {
    build.set_label_map_json(map + std::string(static_cast<size_t>(i), ' '));  // different requests, same rig
    v1::Operation operation;
    grpc::ClientContext context;
    const grpc::Status status = stub->BuildRig(&context, build, &operation);
    if (i == 0) {
      ASSERT_TRUE(server.wait_for_log("pausing", 120)) << server.log();
    }
    if (i < 5) {
      ASSERT_TRUE(status.ok()) << i << ": " << status.error_message();
      operations.push_back(operation);
    } else {
      EXPECT_EQ(status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << status.error_message();
      EXPECT_NE(status.error_message().find("queue is full"), std::string::npos);
    }
  }
  // The same request again joins its operation instead of queueing a second build.
  {
    build.set_label_map_json(map + "   ");
    build.set_name("another name");
    v1::Operation again;
    grpc::ClientContext context;
    ASSERT_TRUE(stub->BuildRig(&context, build, &again).ok());
    EXPECT_EQ(again.id(), operations[3].id());
  }
  // Cancelling a queued build ends it at once and frees its place.
  {
    grpc::ClientContext context;
    v1::GetOperationRequest cancel;
    cancel.set_operation_id(operations[4].id());
    v1::Operation cancelled;
    ASSERT_TRUE(stub->CancelOperation(&context, cancel, &cancelled).ok());
    EXPECT_EQ(cancelled.state(), v1::Operation::CANCELLED);
    build.set_label_map_json(map + std::string(9, ' '));
    v1::Operation admitted;
    grpc::ClientContext retry;
    EXPECT_TRUE(stub->BuildRig(&retry, build, &admitted).ok());
  }
  // Every other build ends: the first builds, the queued ones find its rig in the store.
  for (int i = 0; i < 4; ++i) {
    const v1::Operation done = watch(*stub, operations[static_cast<size_t>(i)].id());
    EXPECT_EQ(done.state(), v1::Operation::SUCCEEDED) << i << ": " << done.error_message();
    EXPECT_EQ(done.rig_id(), watch(*stub, operations[0].id()).rig_id());
  }
}

TEST_F(ServerService, ACancelledOrExpiredPoseFreesItsSlotForTheNextCall) {
  const int metrics_port = free_port();
  ServerProcess server(store("cancel"), {"--pose-slots", "1", "--metrics-listen", "127.0.0.1:" + std::to_string(metrics_port)});
  auto stub = v1::Posewarp::NewStub(server.channel());
  const std::string rig_id = build_rig(*stub);
  // A deadline too short for any pose.
  const PoseAnswer expired = pose_remote(*stub, bend(rig_id), std::chrono::milliseconds(1));
  EXPECT_EQ(expired.status.error_code(), grpc::StatusCode::DEADLINE_EXCEEDED);
  // A client that cancels half-way through reading.
  {
    grpc::ClientContext context;
    auto reader = stub->Pose(&context, bend(rig_id));
    v1::PoseResponse part;
    ASSERT_TRUE(reader->Read(&part));  // the header: the pose is running or done
    context.TryCancel();
    while (reader->Read(&part)) {
    }
    EXPECT_EQ(reader->Finish().error_code(), grpc::StatusCode::CANCELLED);
  }
  // The one slot is free again within 5 s (well within one when the machine is not running other tests): the
  // metrics say so and the next pose runs.
  double running = -1;
  for (int i = 0; i < 100 && running != 0.0; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    running = metric(scrape_metrics(metrics_port), "posewarp_poses_running");
  }
  EXPECT_EQ(running, 0.0);
  const auto start = std::chrono::steady_clock::now();
  const PoseAnswer next = pose_remote(*stub, bend(rig_id));
  EXPECT_TRUE(next.status.ok()) << next.status.error_message();
  EXPECT_LT(std::chrono::steady_clock::now() - start, std::chrono::seconds(30));
  const std::string text = scrape_metrics(metrics_port);
  EXPECT_GE(metric(text, "posewarp_requests_total{method=\"Pose\",code=\"OK\"}"), 1.0) << text;
  EXPECT_GE(metric(text, "posewarp_requests_total{method=\"Pose\",code=\"DEADLINE_EXCEEDED\"}"), 1.0) << text;
  EXPECT_GE(metric(text, "posewarp_cache_hits_total"), 1.0) << text;
  EXPECT_GT(metric(text, "posewarp_cache_bytes"), 0.0) << text;
  EXPECT_NE(text.find("\nposewarp_kept_output_bytes "), std::string::npos) << text;
  EXPECT_NE(text.find("posewarp_request_seconds_bucket{method=\"Pose\",le=\"+Inf\"}"), std::string::npos);
}

TEST_F(ServerService, PoseOutputsKeptForTheNextPoseGoBackToTheSystemOnceIdle) {
  const int metrics_port = free_port();
  ServerProcess server(store("kept"),
                       {"--kept-output-idle-s", "3", "--metrics-listen", "127.0.0.1:" + std::to_string(metrics_port)});
  auto stub = v1::Posewarp::NewStub(server.channel());
  const std::string rig_id = build_rig(*stub);
  const PoseAnswer first = pose_remote(*stub, bend(rig_id));
  ASSERT_TRUE(first.status.ok()) << first.status.error_message();
  // 128^3 voxels of 1 mm around the bar: 8 MB of labels and 8 MB of CT, outputs large enough to be kept.
  v1::PoseRequest large = bend(rig_id);
  large.set_grid(v1::GRID_POLICY_GIVEN);
  v1::Grid* grid = large.mutable_given_grid();
  const v1::Grid& source = first.header.grid();
  for (int a = 0; a < 3; ++a) {
    grid->add_size(128);
    grid->add_spacing(1.0);
    grid->add_origin(source.origin(a) + 0.5 * static_cast<double>(source.size(a) - 1) * source.spacing(a) - 63.5);
  }
  for (int e = 0; e < 9; ++e) grid->add_direction(e % 4 == 0 ? 1.0 : 0.0);
  const PoseAnswer posed = pose_remote(*stub, large);
  ASSERT_TRUE(posed.status.ok()) << posed.status.error_message();
  const double kept = metric(scrape_metrics(metrics_port), "posewarp_kept_output_bytes");
  EXPECT_GE(kept, 2.0 * 128 * 128 * 128 * 4) << "both outputs kept for the next pose";
  // Nobody poses: within a few seconds of the idle time, everything kept has gone back.
  double now = kept;
  for (int i = 0; i < 100 && now != 0.0; ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(100));
    now = metric(scrape_metrics(metrics_port), "posewarp_kept_output_bytes");
  }
  EXPECT_EQ(now, 0.0);
}

TEST_F(ServerService, SigtermWithAPoseInFlightLetsItFinishAndExitsZero) {
  const fs::path at = store("sigterm");
  std::string rig_id;
  {
    ServerProcess server(at);
    auto stub = v1::Posewarp::NewStub(server.channel());
    rig_id = build_rig(*stub);
    EXPECT_EQ(server.stop(), 0);
  }
  ServerProcess server(at, {}, {{"POSEWARP_TEST_PAUSE_IN_POSE_S", "2"}});
  auto stub = v1::Posewarp::NewStub(server.channel());
  auto in_flight = std::async(std::launch::async, [&] { return pose_remote(*stub, bend(rig_id)); });
  ASSERT_TRUE(server.wait_for_log("pausing", 60));
  server.signal(SIGTERM);
  const PoseAnswer answer = in_flight.get();
  EXPECT_TRUE(answer.status.ok()) << answer.status.error_message();
  EXPECT_EQ(answer.labels.size(), answer.header.label_bytes());
  EXPECT_EQ(server.wait_exit(60), 0);
  // The store reopens clean: the rig is there and nothing needed repairing.
  ServerProcess again(at);
  auto stub2 = v1::Posewarp::NewStub(again.channel());
  EXPECT_TRUE(pose_remote(*stub2, bend(rig_id)).status.ok());
  EXPECT_EQ(again.log().find("store:"), std::string::npos) << again.log();
}

TEST_F(ServerService, TokensAreRequiredReloadedOnSighupAndHealthStaysOpen) {
  const fs::path tokens = dir_ / "tokens";
  std::ofstream(tokens) << "# posewarp tokens\nfirst-token\n";
  ServerProcess server(store("tokens"), {"--token-file", tokens.string()});
  auto channel = server.channel();
  auto stub = v1::Posewarp::NewStub(channel);
  auto list = [&](const std::string& authorization) {
    grpc::ClientContext context;
    if (!authorization.empty()) context.AddMetadata("authorization", authorization);
    v1::ListRigsResponse listed;
    return stub->ListRigs(&context, {}, &listed).error_code();
  };
  EXPECT_EQ(list(""), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_EQ(list("Bearer wrong"), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_EQ(list("Bearer first-token"), grpc::StatusCode::OK);
  v1::Volume volume;
  EXPECT_EQ(upload(*stub, dir_ / "bar" / "labels.nii.gz", v1::VOLUME_KIND_LABELS, &volume).error_code(),
            grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_TRUE(files_in(store("tokens") / "volumes").empty());  // refused before any work
  // Health needs no token.
  {
    grpc::ClientContext context;
    grpc::Slice empty("");
    grpc::ByteBuffer request(&empty, 1), response;
    grpc::GenericStub generic(channel);
    std::promise<grpc::Status> done;
    generic.UnaryCall(&context, "/grpc.health.v1.Health/Check", {}, &request, &response,
                      [&](grpc::Status s) { done.set_value(s); });
    EXPECT_TRUE(done.get_future().get().ok());
    grpc::Slice slice;
    ASSERT_TRUE(response.DumpToSingleSlice(&slice).ok());
    EXPECT_EQ(std::string(reinterpret_cast<const char*>(slice.begin()), slice.size()), std::string("\x08\x01", 2));
  }
  // A new token file, re-read on SIGHUP: the old token stops working, the new one works.
  std::ofstream(tokens, std::ios::trunc) << "second-token\n";
  server.signal(SIGHUP);
  ASSERT_TRUE(server.wait_for_log("token file re-read", 30)) << server.log();
  EXPECT_EQ(list("Bearer first-token"), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_EQ(list("Bearer second-token"), grpc::StatusCode::OK);
  // Tokens never reach the log.
  EXPECT_EQ(server.log().find("first-token"), std::string::npos);
  EXPECT_EQ(server.log().find("second-token"), std::string::npos);
}

TEST_F(ServerService, TlsServesOnlyClientsThatTrustItsCertificate) {
  const fs::path key = dir_ / "server.key", cert = dir_ / "server.crt";
  ASSERT_EQ(run({"openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-keyout", key.string(), "-out",
                 cert.string(), "-days", "1", "-subj", "/CN=localhost", "-addext", "subjectAltName=IP:127.0.0.1"}),
            0);
  ServerProcess server(store("tls"), {"--tls-cert", cert.string(), "--tls-key", key.string()});
  ASSERT_GT(server.port(), 0) << server.log();
  grpc::SslCredentialsOptions trusted;
  trusted.pem_root_certs = file_text(cert);
  auto stub = v1::Posewarp::NewStub(server.channel(grpc::SslCredentials(trusted)));
  grpc::ClientContext context;
  v1::ListRigsResponse listed;
  EXPECT_TRUE(stub->ListRigs(&context, {}, &listed).ok());
  // A plaintext client gets nowhere.
  grpc::ChannelArguments arguments;
  auto plain = v1::Posewarp::NewStub(
      grpc::CreateCustomChannel(server.address(), grpc::InsecureChannelCredentials(), arguments));
  grpc::ClientContext plain_context;
  plain_context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(5));
  EXPECT_EQ(plain->ListRigs(&plain_context, {}, &listed).error_code(), grpc::StatusCode::UNAVAILABLE);
}

TEST_F(ServerService, RigsDownloadUploadDeleteAndAssetsRoundTrip) {
  ServerProcess server(store("rigs"));
  auto stub = v1::Posewarp::NewStub(server.channel());
  const std::string rig_id = build_rig(*stub);
  // DownloadRig gives the stored file, whole.
  std::string bytes, sha;
  {
    grpc::ClientContext context;
    v1::GetRigRequest get;
    get.set_rig_id(rig_id);
    auto reader = stub->DownloadRig(&context, get);
    v1::RigChunk chunk;
    while (reader->Read(&chunk)) {
      if (chunk.offset() == 0) sha = chunk.sha256();
      EXPECT_EQ(chunk.offset(), bytes.size());
      bytes += chunk.data();
    }
    ASSERT_TRUE(reader->Finish().ok());
  }
  EXPECT_EQ(bytes, file_text(store("rigs") / "rigs" / (rig_id + ".rig")));
  EXPECT_EQ(sha, sha256_hex(bytes));
  // GetRigAssets: the skeleton first, then every rest surface, as raw arrays and as VTP.
  for (const v1::AssetFormat format : {v1::ASSET_FORMAT_RAW, v1::ASSET_FORMAT_VTP}) {
    grpc::ClientContext context;
    v1::GetRigAssetsRequest get;
    get.set_rig_id(rig_id);
    get.set_format(format);
    auto reader = stub->GetRigAssets(&context, get);
    v1::RigAsset asset;
    ASSERT_TRUE(reader->Read(&asset));
    EXPECT_GT(asset.skeleton().joints_size(), 0);
    int surfaces = 0;
    while (reader->Read(&asset)) {
      ++surfaces;
      if (format == v1::ASSET_FORMAT_VTP) {
        EXPECT_NE(asset.vtp().data().find("<VTKFile"), std::string::npos);
      } else {
        EXPECT_GT(asset.surface().vertices_size(), 0);
        EXPECT_EQ(asset.surface().triangles_size() % 3, 0);
      }
    }
    EXPECT_TRUE(reader->Finish().ok());
    EXPECT_GT(surfaces, 0);
  }
  // Deleted, it is gone; uploaded back, it poses as before. A damaged file is refused with DATA_LOSS.
  {
    grpc::ClientContext context;
    v1::GetRigRequest del;
    del.set_rig_id(rig_id);
    v1::DeleteRigResponse deleted;
    ASSERT_TRUE(stub->DeleteRig(&context, del, &deleted).ok());
  }
  EXPECT_EQ(pose_remote(*stub, bend(rig_id)).status.error_code(), grpc::StatusCode::NOT_FOUND);
  std::string damaged = bytes;
  damaged[damaged.size() / 2] ^= 0x21;
  v1::Rig rig;
  EXPECT_EQ(upload_rig(*stub, damaged, sha256_hex(damaged), &rig, "uploaded").error_code(), grpc::StatusCode::DATA_LOSS);
  EXPECT_EQ(upload_rig(*stub, bytes, sha256_hex(damaged), &rig, "uploaded").error_code(), grpc::StatusCode::DATA_LOSS);
  ASSERT_TRUE(upload_rig(*stub, bytes, sha, &rig, "uploaded").ok());
  EXPECT_EQ(rig.id(), rig_id);
  EXPECT_EQ(rig.name(), "uploaded");
  EXPECT_GT(rig.stage_seconds_size(), 0);
  EXPECT_TRUE(pose_remote(*stub, bend(rig_id)).status.ok());
}

// A rig from an earlier posewarp (the format 1 fixture: no engine tables, no skin vertices) is completed on its first
// load and written back to the store: the stored file then holds them under the same id, GetRig gives its new size,
// and a restarted server poses it the same from what the first one wrote, adding nothing.
TEST_F(ServerService, AnOlderRigIsCompletedOnItsFirstLoadAndKeptSoInTheStore) {
  const std::string bytes = file_text(fs::path(POSEWARP_SOURCE_DIR) / "tests/data/rig_format_1/bar.rig");
  const fs::path where = store("older");
  std::string rig_id;
  PoseAnswer first;
  {
    ServerProcess server(where);
    auto stub = v1::Posewarp::NewStub(server.channel());
    v1::Rig rig;
    ASSERT_TRUE(upload_rig(*stub, bytes, sha256_hex(bytes), &rig, "older").ok());
    rig_id = rig.id();
    EXPECT_EQ(rig.size_bytes(), bytes.size());
    first = pose_remote(*stub, bend(rig_id));
    ASSERT_TRUE(first.status.ok()) << first.status.error_message();
    EXPECT_NE(server.log().find("written back to the store"), std::string::npos) << server.log();
  }
  const fs::path file = where / "rigs" / (rig_id + ".rig");
  Result<api::Rig> kept = api::load_rig(file.string());
  ASSERT_TRUE(kept.ok()) << kept.status().to_string();
  EXPECT_EQ(kept->id(), rig_id);
  EXPECT_EQ(kept->rest_owner.size(), kept->labels.size());
  EXPECT_EQ(static_cast<int64_t>(kept->skin_vertex.size()), kept->mesh.vertex_count());
  ServerProcess again(where, {}, {}, where.string() + "-again.log");
  auto stub = v1::Posewarp::NewStub(again.channel());
  {
    grpc::ClientContext context;
    v1::GetRigRequest get;
    get.set_rig_id(rig_id);
    v1::Rig info;
    ASSERT_TRUE(stub->GetRig(&context, get, &info).ok());
    EXPECT_EQ(info.size_bytes(), fs::file_size(file));
    EXPECT_EQ(info.name(), "older");
  }
  const PoseAnswer second = pose_remote(*stub, bend(rig_id));
  ASSERT_TRUE(second.status.ok()) << second.status.error_message();
  EXPECT_EQ(second.labels, first.labels);
  EXPECT_EQ(second.ct, first.ct);
  EXPECT_EQ(again.log().find("written back"), std::string::npos) << again.log();
}

TEST_F(ServerService, RawSamplesUploadAsTheSameVolumeAsTheirFile) {
  ServerProcess server(store("raw"));
  auto stub = v1::Posewarp::NewStub(server.channel());
  v1::Volume from_file;
  ASSERT_TRUE(upload(*stub, dir_ / "bar" / "labels.nii.gz", v1::VOLUME_KIND_LABELS, &from_file).ok());
  Result<LabelVolume> labels = api::read_label_volume((dir_ / "bar" / "labels.nii.gz").string());
  ASSERT_TRUE(labels.ok());
  std::string samples(static_cast<size_t>(labels->voxel_count()), '\0');
  for (int64_t i = 0; i < labels->voxel_count(); ++i) samples[static_cast<size_t>(i)] = static_cast<char>(labels->data()[i]);
  auto send = [&](const std::string& bytes, v1::Volume* volume) {
    grpc::ClientContext context;
    auto writer = stub->UploadVolume(&context, volume);
    v1::UploadVolumeRequest part;
    part.mutable_header()->set_kind(v1::VOLUME_KIND_LABELS);
    part.mutable_header()->set_format(v1::FILE_FORMAT_RAW);
    part.mutable_header()->set_size_bytes(bytes.size());
    part.mutable_header()->set_sha256(sha256_hex(bytes));
    *part.mutable_header()->mutable_raw_grid() = from_file.grid();
    part.mutable_header()->set_raw_pixel_type(v1::PIXEL_TYPE_UINT8);
    writer->Write(part);
    v1::UploadVolumeRequest chunk;
    chunk.set_chunk(bytes);
    writer->Write(chunk);
    writer->WritesDone();
    return writer->Finish();
  };
  v1::Volume raw;
  ASSERT_TRUE(send(samples, &raw).ok());
  EXPECT_EQ(raw.grid().SerializeAsString(), from_file.grid().SerializeAsString());
  // Too few samples for the grid: refused at the header, naming the fields that disagree.
  const grpc::Status short_upload = send(samples.substr(0, samples.size() / 2), &raw);
  EXPECT_EQ(short_upload.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(short_upload.error_message().find("size_bytes"), std::string::npos) << short_upload.error_message();
  EXPECT_NE(short_upload.error_message().find("raw_grid"), std::string::npos) << short_upload.error_message();
}

// A client that finds the server down (restarting) tries again and succeeds once it is back; a study sent again is
// answered after its header.
TEST_F(ServerService, TheCliRetriesAnUnavailableServerAndSkipsVolumesItHolds) {
  const int port = free_port();
  const std::string address = "127.0.0.1:" + std::to_string(port);
  std::string id;
  {
    ServerProcess first(store("retry"), {"--listen", address});
    ASSERT_EQ(first.port(), port);
    auto stub = v1::Posewarp::NewStub(first.channel());
    id = build_rig(*stub);
    v1::Volume again;
    ASSERT_TRUE(upload(*stub, dir_ / "bar" / "labels.nii.gz", v1::VOLUME_KIND_LABELS, &again).ok());
    EXPECT_TRUE(again.already_stored());
    EXPECT_EQ(again.pixel_type(), "uint8");
    EXPECT_EQ(again.grid().size_size(), 3);
    ASSERT_EQ(first.stop(), 0);
  }
  // The pose starts while nothing listens; the server comes back a second later on the same store and port.
  auto posed = std::async(std::launch::async, [&] {
    return run({POSEWARP_CLI, "pose", "--server", address, id, "--pose",
                (fs::path(POSEWARP_SOURCE_DIR) / "data/poses/bar_bend_90.json").string(), "--labels-out",
                (dir_ / "retried.nii.gz").string(), "--retries", "5"});
  });
  std::this_thread::sleep_for(std::chrono::seconds(1));
  ServerProcess second(store("retry"), {"--listen", address});
  ASSERT_EQ(second.port(), port);
  EXPECT_EQ(posed.get(), 0);
  EXPECT_TRUE(fs::exists(dir_ / "retried.nii.gz"));
}

// What a client can ask of a pose: the study's own sample types (the default), file bytes, displacement fields and
// its own meshes; each equal to the engine's answer in process.
TEST_F(ServerService, PoseOptionsGiveWhatTheEngineGivesInProcess) {
  ServerProcess server(store("options"));
  auto stub = v1::Posewarp::NewStub(server.channel());
  const std::string rig_id = build_rig(*stub);
  Result<api::Rig> rig = api::load_rig((store("options") / "rigs" / (rig_id + ".rig")).string());
  ASSERT_TRUE(rig.ok());
  Result<api::PoseEngine> engine = api::PoseEngine::create(std::move(rig).value());
  ASSERT_TRUE(engine.ok());
  // A user's mesh: two triangles on four vertices of the rig's first rest surface.
  const SurfaceMesh& skin = engine->rig().surfaces.front();
  SurfaceMesh mine;
  mine.name = "needle";
  mine.vertices = skin.vertices.topRows(4);
  mine.triangles.resize(2, 3);
  mine.triangles << 0, 1, 2, 0, 1, 3;
  api::PoseRequest local;
  local.pose = *api::pose_from_json(bend(rig_id).pose_json(), "test");
  local.want_fields = true;
  local.extra_surfaces = {mine};
  Result<api::PoseResult> expected = engine->pose(local);
  ASSERT_TRUE(expected.ok()) << expected.status().to_string();
  const int64_t voxels = expected->labels->voxel_count();

  // Default: the study's types (uint8 labels, int16 CT here), CT rounded as a file stores it.
  v1::PoseRequest request = bend(rig_id);
  const PoseAnswer stored = pose_remote(*stub, request);
  ASSERT_TRUE(stored.status.ok()) << stored.status.error_message();
  const PixelType label_type = expected->labels->source_type(), ct_type = expected->ct->source_type();
  ASSERT_EQ(stored.labels.size(), static_cast<size_t>(voxels * pixel_type_bytes(label_type)));
  ASSERT_EQ(stored.ct.size(), static_cast<size_t>(voxels * pixel_type_bytes(ct_type)));
  std::string want(stored.labels.size(), '\0');
  ASSERT_TRUE(convert_samples(expected->labels->data(), voxels, label_type, want.data()));
  EXPECT_TRUE(stored.labels == want);
  want.assign(stored.ct.size(), '\0');
  ASSERT_TRUE(convert_samples(expected->ct->data(), voxels, ct_type, want.data()));
  EXPECT_TRUE(stored.ct == want);
  EXPECT_LT(pixel_type_bytes(label_type), 4);  // fewer bytes than the computed int32

  // NIfTI bytes: the file reads back as the posed labels on the output grid.
  request.set_format(v1::FILE_FORMAT_NIFTI_GZ);
  const PoseAnswer nifti = pose_remote(*stub, request);
  ASSERT_TRUE(nifti.status.ok()) << nifti.status.error_message();
  EXPECT_EQ(nifti.header.label_bytes(), 0u);
  std::ofstream(dir_ / "posed.nii.gz", std::ios::binary) << nifti.labels;
  Result<LabelVolume> read = api::read_label_volume((dir_ / "posed.nii.gz").string());
  ASSERT_TRUE(read.ok()) << read.status().to_string();
  EXPECT_EQ(read->voxels(), expected->labels->voxels());
  EXPECT_EQ(read->source_type(), label_type);

  // Fields and a user's mesh.
  request.set_format(v1::FILE_FORMAT_RAW);
  request.set_want_fields(true);
  v1::Surface* sent = request.add_meshes();
  sent->set_name(mine.name);
  for (int i = 0; i < 12; ++i) sent->add_vertices(mine.vertices(i / 3, i % 3));
  for (int i = 0; i < 6; ++i) sent->add_triangles(mine.triangles(i / 3, i % 3));
  const PoseAnswer fields = pose_remote(*stub, request);
  ASSERT_TRUE(fields.status.ok()) << fields.status.error_message();
  ASSERT_EQ(fields.inverse_field.size(), expected->inverse_field.size() * sizeof(float));
  EXPECT_EQ(std::memcmp(fields.inverse_field.data(), expected->inverse_field.data(), fields.inverse_field.size()), 0);
  ASSERT_EQ(fields.forward_field.size(), expected->forward_field.size() * sizeof(float));
  EXPECT_EQ(std::memcmp(fields.forward_field.data(), expected->forward_field.data(), fields.forward_field.size()), 0);
  EXPECT_EQ(fields.header.forward_field_bytes(), fields.forward_field.size());
  ASSERT_EQ(fields.surfaces, static_cast<int>(expected->surfaces.size()));
  EXPECT_EQ(fields.last_surface.name(), "needle");
  const SurfaceMesh& posed = expected->surfaces.back();
  ASSERT_EQ(fields.last_surface.vertices_size(), posed.vertices.size());
  for (int i = 0; i < fields.last_surface.vertices_size(); ++i) {
    EXPECT_EQ(fields.last_surface.vertices(i), posed.vertices(i / 3, i % 3));
  }

  // Refused, with what to do: a mesh naming a vertex it does not have, a format not offered.
  request.mutable_meshes(0)->set_triangles(0, 9);
  const PoseAnswer bad_mesh = pose_remote(*stub, request);
  EXPECT_EQ(bad_mesh.status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(bad_mesh.status.error_message().find("needle"), std::string::npos) << bad_mesh.status.error_message();
  request.clear_meshes();
  request.set_format(v1::FILE_FORMAT_MHA);
  EXPECT_EQ(pose_remote(*stub, request).status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
}

}  // namespace
}  // namespace posewarp

namespace posewarp {
namespace {

using namespace testing_server;

// The CLI's remote rig commands with a token: build, info, export (the stored file, byte for byte), delete.
TEST(ServerCli, RigCommandsWorkRemotelyWithATokenAndFailWithoutOne) {
  const fs::path dir = fs::temp_directory_path() / ("posewarp-cli-remote-" + std::to_string(::getpid()));
  fs::remove_all(dir);
  fs::create_directories(dir);
  ASSERT_EQ(run({POSEWARP_CLI, "--quiet", "phantom", "bar", "-o", (dir / "bar").string()}), 0);
  std::ofstream(dir / "tokens") << "cli-token\n";
  std::ofstream(dir / "token") << "cli-token\n";
  ServerProcess server(dir / "store", {"--token-file", (dir / "tokens").string()});
  const std::string address = server.address();
  const std::string token = (dir / "token").string();
  EXPECT_NE(run({POSEWARP_CLI, "rig", "list", "--server", address}), 0);
  std::string id = output_of({POSEWARP_CLI, "-q", "rig", "build", "--server", address, "--token-file", token,
                              "--labels", (dir / "bar" / "labels.nii.gz").string(), "--label-map",
                              (dir / "bar" / "label_map.json").string(), "--name", "bar"});
  if (!id.empty() && id.back() == '\n') id.pop_back();
  ASSERT_TRUE(is_hex_id(id)) << id;
  EXPECT_NE(output_of({POSEWARP_CLI, "rig", "list", "--server", address, "--token-file", token}).find(id),
            std::string::npos);
  const std::string info = output_of({POSEWARP_CLI, "rig", "info", id, "--json", "--server", address, "--token-file", token});
  EXPECT_NE(info.find("\"joints\""), std::string::npos) << info;
  EXPECT_NE(info.find("\"name\": \"bar\""), std::string::npos) << info;
  EXPECT_NE(info.find("\"range_deg\""), std::string::npos) << info;  // each joint's range, measured at build
  const std::string text = output_of({POSEWARP_CLI, "rig", "info", id, "--server", address, "--token-file", token});
  EXPECT_NE(text.find("turns before its bones meet another bone"), std::string::npos) << text;
  ASSERT_EQ(run({POSEWARP_CLI, "rig", "export", id, "--server", address, "--token-file", token, "--rig-out",
                 (dir / "exported.rig").string()}),
            0);
  EXPECT_EQ(file_text(dir / "exported.rig"), file_text(dir / "store" / "rigs" / (id + ".rig")));
  ASSERT_EQ(run({POSEWARP_CLI, "rig", "delete", id, "--server", address, "--token-file", token}), 0);
  EXPECT_EQ(run({POSEWARP_CLI, "rig", "info", id, "--server", address, "--token-file", token}) >> 8, 2);  // NOT_FOUND
  fs::remove_all(dir);
}

}  // namespace
}  // namespace posewarp
