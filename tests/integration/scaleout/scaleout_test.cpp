// Scale-out as an operator deploys it, on loopback: a PostgreSQL cluster of the test's own, posewarp-server
// replicas sharing one store directory and that database, and nginx with docker/nginx/posewarp.conf.template in
// front. Clients are the real posewarp CLI. Skipped with a message where PostgreSQL or nginx is not installed.
#include <gtest/gtest.h>

#include <atomic>
#include <future>
#include <set>

#include "../support/cluster.h"
#include "server_process.h"

namespace posewarp {
namespace {

using namespace testing_server;
using testing_support::NginxProxy;
using testing_support::PostgresCluster;

constexpr int kPhantoms = 4;

class ScaleOut : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = fs::temp_directory_path() / ("posewarp-scaleout-test-" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    if (testing_support::postgres_bin_dir().empty() || testing_support::nginx_binary().empty()) {
      skip_ =
          "PostgreSQL 15 (initdb, pg_ctl) or nginx is not installed (scripts/setup installs postgresql-15 and "
          "nginx-core)";
      return;
    }
    // Bars that differ in their CT noise: as many different rigs.
    for (int k = 0; k < kPhantoms + 3; ++k) {
      ASSERT_EQ(
          run({POSEWARP_CLI, "--quiet", "phantom", "bar", "--seed", std::to_string(k + 1), "-o", phantom(k).string()}),
          0);
    }
  }
  static void TearDownTestSuite() {
    if (std::getenv("POSEWARP_TEST_KEEP") == nullptr) fs::remove_all(dir_);
  }

  void SetUp() override {
    if (!skip_.empty()) GTEST_SKIP() << skip_;
    const std::string name = ::testing::UnitTest::GetInstance()->current_test_info()->name();
    here_ = dir_ / name;
    fs::create_directories(here_);
    database_ = std::make_unique<PostgresCluster>(here_ / "postgres");
    ASSERT_TRUE(database_->ok()) << database_->error();
  }

  static fs::path phantom(int k) { return dir_ / ("bar" + std::to_string(k)); }

  // A replica on the shared store and database, its metrics on a port of its own.
  std::unique_ptr<ServerProcess> replica(const std::string& name, std::vector<std::string> extra = {},
                                         std::map<std::string, std::string> env = {}) {
    const int metrics_port = free_port();
    metrics_ports_[name] = metrics_port;
    extra.insert(extra.end(), {"--database", database_->conninfo(), "--replica", name, "--metrics-listen",
                               "127.0.0.1:" + std::to_string(metrics_port)});
    auto server = std::make_unique<ServerProcess>(here_ / "store", extra, env, here_ / (name + ".log"));
    EXPECT_GT(server->port(), 0) << server->log();
    return server;
  }
  double replica_metric(const std::string& name, const std::string& metric_name) {
    return metric(scrape_metrics(metrics_ports_.at(name)), metric_name);
  }

  // posewarp rig build --server: the rig id it prints.
  static std::string cli_build(const std::string& server, int k) {
    std::string out =
        output_of({POSEWARP_CLI, "--quiet", "rig", "build", "--server", server, "--retries", "8", "--labels",
                   (phantom(k) / "labels.nii.gz").string(), "--ct", (phantom(k) / "ct.nii.gz").string(), "--label-map",
                   (phantom(k) / "label_map.json").string(), "--name", "bar" + std::to_string(k)});
    while (!out.empty() && (out.back() == '\n' || out.back() == ' ')) out.pop_back();
    return out;
  }
  // posewarp pose --server into `out`: the exit code.
  static int cli_pose(const std::string& server, const std::string& rig_id, const fs::path& out,
                      const std::string& method = "cor") {
    fs::create_directories(out);
    return run({POSEWARP_CLI, "--quiet", "pose", rig_id, "--server", server, "--retries", "8", "--method", method,
                "--pose", (fs::path(POSEWARP_SOURCE_DIR) / "data/poses/bar_bend_90.json").string(), "--labels-out",
                (out / "labels.nii.gz").string(), "--ct-out", (out / "ct.nii.gz").string(), "--report",
                (out / "report.json").string()});
  }

  // The Python client's pose (labels and CT), retries on: the exit code of its interpreter.
  static int python_pose(const std::string& server, const std::string& rig_id) {
    const std::string script =
        "import sys; from posewarp import Client\n"
        "with Client(sys.argv[1], retries=8) as c:\n"
        "    r = c.pose(sys.argv[2], sys.argv[3])\n"
        "    sys.exit(0 if r.labels is not None and r.ct is not None else 1)\n";
    const std::string command = "PYTHONPATH='" + std::string(POSEWARP_PYTHONPATH) + "' /usr/bin/python3 -c \"" +
                                script + "\" '" + server + "' '" + rig_id + "' '" +
                                (fs::path(POSEWARP_SOURCE_DIR) / "data/poses/bar_bend_90.json").string() +
                                "' >/dev/null 2>&1";
    const int status = std::system(command.c_str());
    return WIFEXITED(status) ? WEXITSTATUS(status) : -1;
  }

  static grpc::StatusCode list_code(v1::Posewarp::Stub& stub, int* count = nullptr) {
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(20));
    v1::ListRigsResponse listed;
    const grpc::Status status = stub.ListRigs(&context, {}, &listed);
    if (count != nullptr) *count = listed.rigs_size();
    return status.error_code();
  }

  static inline fs::path dir_;
  static inline std::string skip_;
  fs::path here_;
  std::unique_ptr<PostgresCluster> database_;
  std::map<std::string, int> metrics_ports_;
};

TEST_F(ScaleOut, EightClientsThroughNginxGetOneServersAnswersWithEachRigOnOneReplica) {
  auto r1 = replica("r1");
  auto r2 = replica("r2");
  NginxProxy nginx(here_ / "nginx", POSEWARP_SOURCE_DIR, {r1->address(), r2->address()});
  ASSERT_TRUE(nginx.ok()) << nginx.error();
  ASSERT_EQ(run({POSEWARP_CLI, "health", "--server", nginx.address(), "--retries", "8"}), 0);

  // 8 clients, two per rig: each builds its rig (the two builds of a rig may reach different replicas) and poses
  // it twice with two methods.
  constexpr int kClients = 8;
  std::vector<std::string> rig_of_client(kClients);
  std::vector<std::future<int>> clients;
  for (int c = 0; c < kClients; ++c) {
    clients.push_back(std::async(std::launch::async, [&, c] {
      const std::string rig_id = cli_build(nginx.address(), c % kPhantoms);
      rig_of_client[c] = rig_id;
      if (rig_id.size() != 64) return -1;
      int failures = 0;
      for (const char* method : {"cor", "lbs"}) {
        failures += cli_pose(nginx.address(), rig_id, here_ / ("client" + std::to_string(c)) / method, method) != 0;
      }
      return failures;
    }));
  }
  for (auto& client : clients) EXPECT_EQ(client.get(), 0);
  std::set<std::string> rigs(rig_of_client.begin(), rig_of_client.end());
  ASSERT_EQ(rigs.size(), static_cast<size_t>(kPhantoms));
  // Each rig built once, though two clients asked for it at once, perhaps of different replicas.
  EXPECT_EQ(std::max(0.0, replica_metric("r1", "posewarp_rigs_built_total")) +
                std::max(0.0, replica_metric("r2", "posewarp_rigs_built_total")),
            kPhantoms)
      << r1->log() << r2->log();

  // Affinity: each rig's 4 poses all on one replica.
  const std::string m1 = scrape_metrics(metrics_ports_["r1"]), m2 = scrape_metrics(metrics_ports_["r2"]);
  int on_r1 = 0;
  for (const std::string& rig_id : rigs) {
    const std::string name = "posewarp_rig_poses_total{rig=\"" + rig_id.substr(0, 16) + "\"}";
    const double a = metric(m1, name), b = metric(m2, name);
    EXPECT_TRUE((a == 4 && b < 0) || (a < 0 && b == 4)) << rig_id << ": r1 " << a << ", r2 " << b;
    on_r1 += a > 0;
  }
  std::printf("rigs posed on r1: %d of %d\n", on_r1, kPhantoms);

  // Every answer equals a lone server's for the same rig file.
  ServerProcess lone(here_ / "lone-store", {}, {}, here_ / "lone.log");
  auto lone_stub = v1::Posewarp::NewStub(lone.channel());
  for (const std::string& rig_id : rigs) {
    const fs::path rig_file = here_ / (rig_id + ".rig");
    ASSERT_EQ(run({POSEWARP_CLI, "rig", "export", rig_id, "--server", nginx.address(), "--rig-out", rig_file.string()}),
              0);
    v1::Rig uploaded;
    const std::string bytes = file_text(rig_file);
    ASSERT_TRUE(upload_rig(*lone_stub, bytes, sha256_hex(bytes), &uploaded).ok());
    ASSERT_EQ(uploaded.id(), rig_id);
    for (const char* method : {"cor", "lbs"}) {
      const fs::path alone = here_ / "lone" / rig_id / method;
      ASSERT_EQ(cli_pose(lone.address(), rig_id, alone, method), 0);
      for (int c = 0; c < kClients; ++c) {
        if (rig_of_client[c] != rig_id) continue;
        const fs::path got = here_ / ("client" + std::to_string(c)) / method;
        EXPECT_EQ(file_text(got / "labels.nii.gz"), file_text(alone / "labels.nii.gz")) << c << " " << method;
        EXPECT_EQ(file_text(got / "ct.nii.gz"), file_text(alone / "ct.nii.gz")) << c << " " << method;
      }
    }
  }

  // A replica that starts sees every rig at once.
  auto r3 = replica("r3");
  auto r3_stub = v1::Posewarp::NewStub(r3->channel());
  int listed = 0;
  EXPECT_EQ(list_code(*r3_stub, &listed), grpc::StatusCode::OK);
  EXPECT_EQ(listed, kPhantoms);
  // A rig deleted through one replica is gone from every replica's cache (both had it warm or could load it).
  const std::string gone = *rigs.begin();
  ASSERT_EQ(run({POSEWARP_CLI, "rig", "delete", gone, "--server", nginx.address()}), 0);
  for (ServerProcess* server : {r1.get(), r2.get(), r3.get()}) {
    auto stub = v1::Posewarp::NewStub(server->channel());
    v1::PoseRequest request;
    request.set_rig_id(gone);
    request.set_pose_json(file_text(fs::path(POSEWARP_SOURCE_DIR) / "data/poses/bar_bend_90.json"));
    request.set_want_labels(true);
    EXPECT_EQ(pose_remote(*stub, request).status.error_code(), grpc::StatusCode::NOT_FOUND) << server->address();
  }
  EXPECT_TRUE(r1->wait_for_log("deleted by another replica", 10) || r2->wait_for_log("deleted by another replica", 10))
      << r1->log() << r2->log();
}

TEST_F(ScaleOut, TheSameBuildAskedOfBothReplicasAtOnceIsBuiltOnce) {
  auto r1 = replica("r1");
  auto r2 = replica("r2");
  auto s1 = v1::Posewarp::NewStub(r1->channel());
  auto s2 = v1::Posewarp::NewStub(r2->channel());
  const fs::path bar = phantom(kPhantoms);
  v1::Volume labels, ct;
  ASSERT_TRUE(upload(*s1, bar / "labels.nii.gz", v1::VOLUME_KIND_LABELS, &labels).ok());
  ASSERT_TRUE(upload(*s2, bar / "ct.nii.gz", v1::VOLUME_KIND_INTENSITY, &ct).ok());
  v1::BuildRigRequest build;
  build.set_labels_volume_id(labels.id());
  build.set_ct_volume_id(ct.id());
  build.set_label_map_json(file_text(bar / "label_map.json"));
  auto start = [&](v1::Posewarp::Stub* stub) {
    return std::async(std::launch::async, [stub, &build] {
      grpc::ClientContext context;
      v1::Operation operation;
      EXPECT_TRUE(stub->BuildRig(&context, build, &operation).ok());
      return watch(*stub, operation.id());
    });
  };
  auto first = start(s1.get());
  auto second = start(s2.get());
  const v1::Operation a = first.get(), b = second.get();
  EXPECT_EQ(a.state(), v1::Operation::SUCCEEDED) << a.error_message();
  EXPECT_EQ(b.state(), v1::Operation::SUCCEEDED) << b.error_message();
  EXPECT_EQ(a.rig_id(), b.rig_id());
  EXPECT_NE(a.id(), b.id());
  const double built = std::max(0.0, replica_metric("r1", "posewarp_rigs_built_total")) +
                       std::max(0.0, replica_metric("r2", "posewarp_rigs_built_total"));
  EXPECT_EQ(built, 1) << r1->log() << r2->log();
  EXPECT_EQ(database_->query("SELECT count(*) FROM rigs"), "1");
  EXPECT_EQ(database_->query("SELECT count(*) FROM build_claims"), "0");
  // Both replicas pose it.
  EXPECT_TRUE(pose_remote(*s1,
                          [&] {
                            v1::PoseRequest r;
                            r.set_rig_id(a.rig_id());
                            r.set_pose_json(file_text(fs::path(POSEWARP_SOURCE_DIR) / "data/poses/bar_bend_90.json"));
                            r.set_want_labels(true);
                            return r;
                          }())
                  .status.ok());
}

TEST_F(ScaleOut, AReplicaKilledUnderLoadCostsRetriesNotAnswersAndItsBuildEnds) {
  // Short leases, so that the killed replica's build is over within seconds.
  auto r1 = replica("r1", {"--lease-seconds", "3"}, {{"POSEWARP_TEST_PAUSE_IN_RIG_WRITE_S", "600"}});
  auto r2 = replica("r2", {"--lease-seconds", "3"});
  NginxProxy nginx(here_ / "nginx", POSEWARP_SOURCE_DIR, {r1->address(), r2->address()});
  ASSERT_TRUE(nginx.ok()) << nginx.error();
  // Rigs built by r2 (r1 would hold its writes), then posed through nginx: some hash to r1, some to r2.
  std::vector<std::string> rigs;
  for (int k = 0; k < kPhantoms; ++k) rigs.push_back(cli_build(r2->address(), k));
  for (const std::string& id : rigs) ASSERT_EQ(id.size(), 64u);
  // A build that r1 runs and holds inside its rig write, as long as it lives.
  auto s1 = v1::Posewarp::NewStub(r1->channel());
  const fs::path bar = phantom(kPhantoms + 1);
  v1::Volume labels;
  ASSERT_TRUE(upload(*s1, bar / "labels.nii.gz", v1::VOLUME_KIND_LABELS, &labels).ok());
  v1::BuildRigRequest build;
  build.set_labels_volume_id(labels.id());
  build.set_label_map_json(file_text(bar / "label_map.json"));
  v1::Operation operation;
  {
    grpc::ClientContext context;
    ASSERT_TRUE(s1->BuildRig(&context, build, &operation).ok());
  }
  ASSERT_TRUE(r1->wait_for_log("pausing", 120)) << r1->log();

  // 6 CLI clients and 2 Python clients (clients/python), each posing 4 times.
  constexpr int kClients = 8, kPoses = 4;
  std::atomic<int> done{0};
  std::vector<std::future<int>> clients;
  for (int c = 0; c < kClients; ++c) {
    clients.push_back(std::async(std::launch::async, [&, c] {
      int failures = 0;
      for (int p = 0; p < kPoses; ++p) {
        const fs::path out = here_ / ("client" + std::to_string(c)) / std::to_string(p);
        const std::string& rig_id = rigs[(c + p) % rigs.size()];
        const bool python = c >= 6 && std::string(POSEWARP_PYTHONPATH).size() > 0;  // a tree with the Python stubs
        failures += (python ? python_pose(nginx.address(), rig_id) : cli_pose(nginx.address(), rig_id, out)) != 0;
        ++done;
      }
      return failures;
    }));
  }
  while (done < kClients) std::this_thread::sleep_for(std::chrono::milliseconds(20));
  r1->kill();
  for (auto& client : clients) EXPECT_EQ(client.get(), 0) << nginx.error_log();
  EXPECT_EQ(done, kClients * kPoses);

  // The build r1 was running is failed by r2 once its lease runs out, never left running.
  auto s2 = v1::Posewarp::NewStub(r2->channel());
  v1::Operation after;
  for (int i = 0; i < 100; ++i) {
    grpc::ClientContext context;
    v1::GetOperationRequest get;
    get.set_operation_id(operation.id());
    ASSERT_TRUE(s2->GetOperation(&context, get, &after).ok());
    if (after.state() != v1::Operation::RUNNING && after.state() != v1::Operation::QUEUED) break;
    std::this_thread::sleep_for(std::chrono::milliseconds(200));
  }
  EXPECT_EQ(after.state(), v1::Operation::FAILED);
  EXPECT_EQ(after.error_code(), static_cast<int>(grpc::StatusCode::ABORTED)) << after.error_message();
  // Asked again, r2 takes the build over (the claim's lease ran out with it) and finishes it.
  {
    grpc::ClientContext context;
    ASSERT_TRUE(s2->BuildRig(&context, build, &operation).ok());
  }
  const v1::Operation rebuilt = watch(*s2, operation.id());
  EXPECT_EQ(rebuilt.state(), v1::Operation::SUCCEEDED) << rebuilt.error_message();

  // Nothing in the store is damaged: a new replica lists every rig and each downloads whole (checksums checked).
  auto r3 = replica("r3");
  auto s3 = v1::Posewarp::NewStub(r3->channel());
  int listed = 0;
  EXPECT_EQ(list_code(*s3, &listed), grpc::StatusCode::OK);
  EXPECT_EQ(listed, kPhantoms + 1);
  rigs.push_back(rebuilt.rig_id());
  for (const std::string& id : rigs) {
    EXPECT_EQ(run({POSEWARP_CLI, "rig", "export", id, "--server", r3->address(), "--rig-out",
                   (here_ / (id + ".rig")).string()}),
              0);
  }
  EXPECT_FALSE(fs::exists(here_ / "store" / "quarantine") && !fs::is_empty(here_ / "store" / "quarantine"));
}

TEST_F(ScaleOut, APostgresRestartIsUnavailableWhileDownAndRecoversWithoutRestartingReplicas) {
  auto r1 = replica("r1");
  auto r2 = replica("r2");
  auto s1 = v1::Posewarp::NewStub(r1->channel());
  auto s2 = v1::Posewarp::NewStub(r2->channel());
  const std::string rig_id = cli_build(r1->address(), 0);
  ASSERT_EQ(rig_id.size(), 64u);
  ASSERT_EQ(list_code(*s2), grpc::StatusCode::OK);

  v1::PoseRequest warm;
  warm.set_rig_id(rig_id);
  warm.set_pose_json(file_text(fs::path(POSEWARP_SOURCE_DIR) / "data/poses/bar_bend_90.json"));
  warm.set_want_labels(true);
  ASSERT_TRUE(pose_remote(*s1, warm).status.ok());

  ASSERT_TRUE(database_->stop());
  for (auto* stub : {s1.get(), s2.get()}) EXPECT_EQ(list_code(*stub), grpc::StatusCode::UNAVAILABLE);
  // A rig in a replica's cache goes on posing without the index.
  EXPECT_TRUE(pose_remote(*s1, warm).status.ok());
  const std::string message = [&] {
    grpc::ClientContext context;
    v1::ListRigsResponse listed;
    return s1->ListRigs(&context, {}, &listed).error_message();
  }();
  EXPECT_NE(message.find("database"), std::string::npos) << message;
  ASSERT_TRUE(database_->start());
  // Back without restarting either replica: listings, a new build and poses.
  for (auto* stub : {s1.get(), s2.get()}) {
    grpc::StatusCode code = grpc::StatusCode::UNAVAILABLE;
    for (int i = 0; i < 50 && code != grpc::StatusCode::OK; ++i) {
      code = list_code(*stub);
      if (code != grpc::StatusCode::OK) std::this_thread::sleep_for(std::chrono::milliseconds(200));
    }
    EXPECT_EQ(code, grpc::StatusCode::OK);
  }
  const std::string second = cli_build(r2->address(), 1);
  EXPECT_EQ(second.size(), 64u);
  EXPECT_EQ(cli_pose(r1->address(), second, here_ / "after"), 0);
  // A deletion after the restart still reaches the other replica (its listener reconnected).
  EXPECT_EQ(cli_pose(r2->address(), rig_id, here_ / "warm"), 0);
  ASSERT_EQ(run({POSEWARP_CLI, "rig", "delete", rig_id, "--server", r1->address()}), 0);
  EXPECT_TRUE(r2->wait_for_log("deleted by another replica", 15)) << r2->log();
}

}  // namespace
}  // namespace posewarp
