// The server under hostile clients, in the spirit of the CLI's bad-input catalogue: slow, stalled and vanishing
// readers, tiny chunks, gzip bombs and huge claims, poses past the memory budget, detached headers that name other
// files, volumes given for the wrong purpose, values and enums out of range. Each case checks the code and what the
// message names; afterwards the server is alive, its peak memory under its --memory-mb, and a reference pose
// unchanged (TearDown). One real server process per case, on a loopback port.
#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>
#include <unistd.h>
#include <zlib.h>

#include <chrono>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <string>
#include <thread>
#include <vector>

#include "posewarp/common/sha256.h"
#include "posewarp/v1/posewarp.grpc.pb.h"
#include "server_process.h"

namespace posewarp {
namespace {

using namespace testing_server;

constexpr int kMemoryMb = 1000;

class Hostile : public ::testing::Test {
 protected:
  static void SetUpTestSuite() {
    dir_ = fs::temp_directory_path() / ("posewarp-hostile-test-" + std::to_string(::getpid()));
    fs::remove_all(dir_);
    fs::create_directories(dir_);
    ASSERT_EQ(run({POSEWARP_CLI, "--quiet", "phantom", "bar", "-o", (dir_ / "bar").string()}), 0);
    server_ = new ServerProcess(dir_ / "store", {"--pose-slots", "2", "--stall-timeout-s", "2", "--memory-mb",
                                                 std::to_string(kMemoryMb), "--cache-mb", "128", "--uploads-per-client",
                                                 "3", "--upload-mb-per-client", "64", "--max-upload-mb", "48"});
    ASSERT_GT(server_->port(), 0);
    stub_ = v1::Posewarp::NewStub(server_->channel());
    v1::Volume labels, ct;
    ASSERT_TRUE(upload(*stub_, dir_ / "bar" / "labels.nii.gz", v1::VOLUME_KIND_LABELS, &labels).ok());
    ASSERT_TRUE(upload(*stub_, dir_ / "bar" / "ct.nii.gz", v1::VOLUME_KIND_INTENSITY, &ct).ok());
    labels_id_ = labels.id();
    ct_id_ = ct.id();
    v1::BuildRigRequest build;
    build.set_labels_volume_id(labels_id_);
    build.set_ct_volume_id(ct_id_);
    build.set_label_map_json(file_text(dir_ / "bar" / "label_map.json"));
    v1::Operation operation;
    grpc::ClientContext context;
    ASSERT_TRUE(stub_->BuildRig(&context, build, &operation).ok());
    const v1::Operation done = watch(*stub_, operation.id());
    ASSERT_EQ(done.state(), v1::Operation::SUCCEEDED) << done.error_message();
    rig_id_ = done.rig_id();
    reference_ = pose_remote(*stub_, bend());
    ASSERT_TRUE(reference_.status.ok()) << reference_.status.error_message();
  }
  static void TearDownTestSuite() {
    stub_.reset();
    delete server_;
    fs::remove_all(dir_);
  }

  // After every case: the server serves and poses as before, and its peak memory stayed under its ceiling.
  void TearDown() override {
    const PoseAnswer after = pose_remote(*stub_, bend());
    ASSERT_TRUE(after.status.ok()) << after.status.error_message();
    EXPECT_EQ(after.labels, reference_.labels);
    EXPECT_EQ(after.ct, reference_.ct);
    v1::ListRigsResponse listed;
    grpc::ClientContext context;
    ASSERT_TRUE(stub_->ListRigs(&context, {}, &listed).ok());
    EXPECT_EQ(listed.rigs_size(), 1);
    const double peak = peak_rss_mb();
    EXPECT_GT(peak, 0.0);
    EXPECT_LT(peak, kMemoryMb) << "the server's peak resident memory went past its --memory-mb";
  }

  static v1::PoseRequest bend() {
    v1::PoseRequest request;
    request.set_rig_id(rig_id_);
    request.set_pose_json(file_text(fs::path(POSEWARP_SOURCE_DIR) / "data/poses/bar_bend_90.json"));
    request.set_want_labels(true);
    request.set_want_ct(true);
    request.set_samples(v1::SAMPLE_TYPE_COMPUTED);
    return request;
  }
  // A grid of n^3 voxels of `spacing` mm centred on the bar: large outputs from a small rig.
  static v1::Grid cube(int n, double spacing) {
    v1::Grid grid;
    const v1::Grid& source = reference_.header.grid();
    for (int a = 0; a < 3; ++a) {
      const double centre = source.origin(a) + 0.5 * static_cast<double>(source.size(a) - 1) * source.spacing(a);
      grid.add_size(n);
      grid.add_spacing(spacing);
      grid.add_origin(centre - 0.5 * (n - 1) * spacing);
    }
    for (int e = 0; e < 9; ++e) grid.add_direction(e % 4 == 0 ? 1.0 : 0.0);
    return grid;
  }
  // The server's peak resident memory so far (VmHWM), MB.
  static double peak_rss_mb() {
    std::ifstream status("/proc/" + std::to_string(server_->pid()) + "/status");
    for (std::string line; std::getline(status, line);) {
      if (line.rfind("VmHWM:", 0) == 0) return std::atof(line.c_str() + 6) / 1024.0;
    }
    return -1.0;
  }
  // An upload of `bytes` as `format`, in chunks of `chunk` bytes.
  static grpc::Status upload_bytes(const std::string& bytes, v1::FileFormat format, v1::VolumeKind kind,
                                   size_t chunk = 1 << 20, v1::Volume* volume = nullptr) {
    v1::Volume answer;
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::minutes(2));
    auto writer = stub_->UploadVolume(&context, volume ? volume : &answer);
    v1::UploadVolumeRequest header;
    header.mutable_header()->set_kind(kind);
    header.mutable_header()->set_format(format);
    header.mutable_header()->set_size_bytes(bytes.size());
    header.mutable_header()->set_sha256(sha256_hex(bytes));
    writer->Write(header);
    for (size_t offset = 0; offset < bytes.size(); offset += chunk) {
      v1::UploadVolumeRequest part;
      part.set_chunk(bytes.substr(offset, chunk));
      if (!writer->Write(part)) break;
    }
    writer->WritesDone();
    return writer->Finish();
  }
  static grpc::Status pose_status(const v1::PoseRequest& request) { return pose_remote(*stub_, request).status; }

  static inline fs::path dir_;
  static inline ServerProcess* server_ = nullptr;
  static inline std::unique_ptr<v1::Posewarp::Stub> stub_;
  static inline std::string labels_id_, ct_id_, rig_id_;
  static inline PoseAnswer reference_;
};

// A NIfTI-1 header (n+1, qform identity, 1 mm) for `dims` voxels of `datatype` (2 uint8), then `voxel_bytes`
// zero bytes, all through gzip: a small file that inflates to whatever the header promises.
std::string gzip_nifti(const std::vector<int16_t>& dims, int16_t datatype, int64_t voxel_bytes) {
  std::string header(352, '\0');
  auto put = [&header](size_t offset, auto value) { std::memcpy(header.data() + offset, &value, sizeof value); };
  put(0, int32_t{348});
  put(40, static_cast<int16_t>(dims.size()));
  for (size_t d = 0; d < dims.size(); ++d) put(42 + 2 * d, dims[d]);
  put(70, datatype);
  put(72, int16_t{8});
  put(76, 1.0f);
  for (size_t d = 1; d <= 3; ++d) put(76 + 4 * d, 1.0f);
  put(108, 352.0f);
  put(252, int16_t{1});
  std::memcpy(header.data() + 344, "n+1\0", 4);
  std::string out(1 << 20, '\0');
  z_stream z{};
  deflateInit2(&z, 1, Z_DEFLATED, 15 + 16, 8, Z_DEFAULT_STRATEGY);
  std::string compressed;
  const std::string zeros(1 << 20, '\0');
  auto feed = [&](const std::string& data, size_t size, int flush) {
    z.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(data.data()));
    z.avail_in = static_cast<uInt>(size);
    do {
      z.next_out = reinterpret_cast<Bytef*>(out.data());
      z.avail_out = static_cast<uInt>(out.size());
      deflate(&z, flush);
      compressed.append(out.data(), out.size() - z.avail_out);
    } while (z.avail_out == 0);
  };
  feed(header, header.size(), Z_NO_FLUSH);
  for (int64_t left = voxel_bytes; left > 0; left -= static_cast<int64_t>(zeros.size())) {
    feed(zeros, static_cast<size_t>(std::min<int64_t>(left, static_cast<int64_t>(zeros.size()))), Z_NO_FLUSH);
  }
  feed(zeros, 0, Z_FINISH);
  deflateEnd(&z);
  return compressed;
}

// An upload that has sent its header (labels, .nii.gz, `size_bytes`, `sha256`) and nothing else yet. Its calls end
// within a minute whatever the server does, so a server that never ends them fails the test instead of hanging it.
struct OpenUpload {
  OpenUpload(v1::Posewarp::Stub& stub, uint64_t size_bytes, const std::string& sha256) {
    context.set_deadline(std::chrono::system_clock::now() + std::chrono::minutes(1));
    writer = stub.UploadVolume(&context, &volume);
    v1::UploadVolumeRequest header;
    header.mutable_header()->set_kind(v1::VOLUME_KIND_LABELS);
    header.mutable_header()->set_format(v1::FILE_FORMAT_NIFTI_GZ);
    header.mutable_header()->set_size_bytes(size_bytes);
    header.mutable_header()->set_sha256(sha256);
    header_sent = writer->Write(header);
  }
  // Sends nothing more: the server's answer.
  grpc::Status finish() {
    writer->WritesDone();
    return writer->Finish();
  }
  grpc::ClientContext context;
  v1::Volume volume;
  std::unique_ptr<grpc::ClientWriter<v1::UploadVolumeRequest>> writer;
  bool header_sent = false;
};

bool says(const grpc::Status& status, const std::string& fragment) {
  return status.error_message().find(fragment) != std::string::npos;
}

TEST_F(Hostile, ClientsThatStopReadingLoseTheirSlotsAndAWellBehavedPoseStillGetsAnswered) {
  // Two clients start large poses (labels, CT, fields on a 128^3 grid: tens of MB) with small receive windows, read
  // the header and then nothing: each would hold one of the two pose slots and its memory for as long as it likes.
  struct Stalled {
    std::shared_ptr<grpc::Channel> channel;
    std::unique_ptr<v1::Posewarp::Stub> stub;
    grpc::ClientContext context;
    std::unique_ptr<grpc::ClientReader<v1::PoseResponse>> reader;
  };
  std::vector<std::unique_ptr<Stalled>> stalled;
  for (int i = 0; i < 2; ++i) {
    auto s = std::make_unique<Stalled>();
    grpc::ChannelArguments arguments;
    arguments.SetInt(GRPC_ARG_HTTP2_BDP_PROBE, 0);
    arguments.SetInt(GRPC_ARG_HTTP2_STREAM_LOOKAHEAD_BYTES, 65536);
    arguments.SetInt("stalled-client", i);  // a connection of its own
    s->channel = grpc::CreateCustomChannel(server_->address(), grpc::InsecureChannelCredentials(), arguments);
    s->stub = v1::Posewarp::NewStub(s->channel);
    v1::PoseRequest request = bend();
    request.set_want_fields(true);
    request.set_grid(v1::GRID_POLICY_GIVEN);
    *request.mutable_given_grid() = cube(128, 1.0);
    request.set_chunk_bytes(65536);
    s->reader = s->stub->Pose(&s->context, request);
    v1::PoseResponse header;
    ASSERT_TRUE(s->reader->Read(&header));
    ASSERT_TRUE(header.has_header());
    stalled.push_back(std::move(s));
  }
  // A well-behaved client's pose is answered, whole, as it was before.
  v1::PoseRequest request = bend();
  const PoseAnswer answer = pose_remote(*stub_, request, std::chrono::seconds(60));
  ASSERT_TRUE(answer.status.ok()) << answer.status.error_message();
  EXPECT_EQ(answer.labels, reference_.labels);
  // Both stalled streams are cancelled by the server within its stall timeout, which frees their slots and memory.
  const auto stalls = [] {
    const std::string log = server_->log();
    size_t n = 0;
    for (size_t at = log.find("made no progress"); at != std::string::npos; at = log.find("made no progress", at + 1)) {
      ++n;
    }
    return n;
  };
  for (int i = 0; i < 600 && stalls() < 2; ++i) std::this_thread::sleep_for(std::chrono::milliseconds(50));
  EXPECT_EQ(stalls(), 2u) << server_->log();
  for (auto& s : stalled) {
    v1::PoseResponse part;
    while (s->reader->Read(&part)) {
    }
    EXPECT_FALSE(s->reader->Finish().ok());
  }
}

TEST_F(Hostile, TinyChunksAndStalledUploadsAreRefusedAndFreed) {
  v1::PoseRequest request = bend();
  for (const uint64_t chunk : {uint64_t{1}, uint64_t{65535}, uint64_t{4} << 20 | 1}) {
    request.set_chunk_bytes(chunk);
    const grpc::Status status = pose_status(request);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << chunk;
    EXPECT_TRUE(says(status, "chunk_bytes")) << status.error_message();
  }
  // An upload in one-byte messages is refused at its first chunk.
  const std::string fresh = gzip_nifti({20, 20, 20}, 2, 8000);  // a new (empty) label volume
  const grpc::Status tiny = upload_bytes(fresh, v1::FILE_FORMAT_NIFTI_GZ, v1::VOLUME_KIND_LABELS, 1);
  EXPECT_EQ(tiny.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_TRUE(says(tiny, "at least 4096 bytes")) << tiny.error_message();
  // Uploads that send their header and stop: the client's uploads are limited (--uploads-per-client 3), and the
  // stall watch ends each within seconds, which gives the places back.
  std::vector<std::unique_ptr<OpenUpload>> open;
  for (int i = 0; i < 3; ++i) {
    open.push_back(std::make_unique<OpenUpload>(*stub_, 10 << 20, std::string(64, 'a' + static_cast<char>(i))));
    ASSERT_TRUE(open.back()->header_sent);
  }
  std::this_thread::sleep_for(std::chrono::milliseconds(300));  // the server has read the three headers
  const grpc::Status fourth = upload_bytes(fresh, v1::FILE_FORMAT_NIFTI_GZ, v1::VOLUME_KIND_LABELS);
  EXPECT_EQ(fourth.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << fourth.error_message();
  EXPECT_TRUE(says(fourth, "--uploads-per-client")) << fourth.error_message();
  for (auto& o : open) EXPECT_FALSE(o->writer->Finish().ok());  // ended by the server's stall watch, not by us
  // The places are free again: the same upload now goes through. The client sees its cancelled call end before the
  // server's handler has unwound and given its place back, so a client asks again for a short while, as it would.
  grpc::Status after = upload_bytes(fresh, v1::FILE_FORMAT_NIFTI_GZ, v1::VOLUME_KIND_LABELS);
  for (int i = 0; i < 100 && says(after, "--uploads-per-client"); ++i) {
    std::this_thread::sleep_for(std::chrono::milliseconds(50));
    after = upload_bytes(fresh, v1::FILE_FORMAT_NIFTI_GZ, v1::VOLUME_KIND_LABELS);
  }
  EXPECT_TRUE(after.ok()) << after.error_message();
  // Bytes in flight: one client's open uploads may claim 64 MB together (--upload-mb-per-client 64).
  {
    OpenUpload first(*stub_, 40 << 20, std::string(64, 'd'));
    ASSERT_TRUE(first.header_sent);
    std::this_thread::sleep_for(std::chrono::milliseconds(300));
    const grpc::Status status = OpenUpload(*stub_, 40 << 20, std::string(64, 'c')).finish();
    EXPECT_EQ(status.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << status.error_message();
    EXPECT_TRUE(says(status, "--upload-mb-per-client")) << status.error_message();
    first.context.TryCancel();
    first.writer->Finish();
  }
  // A header that claims more than one file may hold is refused at once.
  const grpc::Status claim = OpenUpload(*stub_, uint64_t{4} << 30, std::string(64, 'e')).finish();
  EXPECT_EQ(claim.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED);
  EXPECT_TRUE(says(claim, "--max-upload-mb")) << claim.error_message();
}

TEST_F(Hostile, BombsAndHugeOutputsStayWithinTheMemoryCeiling) {
  // 800^3 voxels in 0.5 MB of gzip: refused by its header, before a byte is inflated.
  const grpc::Status bomb = upload_bytes(gzip_nifti({800, 800, 800}, 2, int64_t{800} * 800 * 800),
                                         v1::FILE_FORMAT_NIFTI_GZ, v1::VOLUME_KIND_LABELS);
  EXPECT_EQ(bomb.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << bomb.error_message();
  EXPECT_TRUE(says(bomb, "--max-volume-voxels")) << bomb.error_message();
  EXPECT_FALSE(says(bomb, "--max-voxels")) << bomb.error_message();
  // 600^3 is under the voxel limit, but reading it would take more than the whole memory budget.
  const grpc::Status big = upload_bytes(gzip_nifti({600, 600, 600}, 2, int64_t{600} * 600 * 600),
                                        v1::FILE_FORMAT_NIFTI_GZ, v1::VOLUME_KIND_LABELS);
  EXPECT_EQ(big.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << big.error_message();
  EXPECT_TRUE(says(big, "--memory-mb")) << big.error_message();
  // A pose with fields on a 600 x 600 x 500 grid: refused before anything is allocated.
  v1::PoseRequest huge = bend();
  huge.set_want_fields(true);
  huge.set_grid(v1::GRID_POLICY_GIVEN);
  *huge.mutable_given_grid() = cube(500, 0.5);
  huge.mutable_given_grid()->set_size(0, 600);
  huge.mutable_given_grid()->set_size(1, 600);
  const grpc::Status refused = pose_status(huge);
  EXPECT_EQ(refused.error_code(), grpc::StatusCode::RESOURCE_EXHAUSTED) << refused.error_message();
  EXPECT_TRUE(says(refused, "--memory-mb")) << refused.error_message();
  // Four poses of about 400 MB each at once, within a budget that holds one: they take turns, all are answered.
  std::vector<std::thread> clients;
  std::vector<grpc::Status> statuses(4);
  for (int i = 0; i < 4; ++i) {
    clients.emplace_back([&, i] {
      v1::PoseRequest request = bend();
      request.set_want_ct(false);
      request.set_want_fields(true);
      request.set_grid(v1::GRID_POLICY_GIVEN);
      *request.mutable_given_grid() = cube(270, 0.55);
      statuses[static_cast<size_t>(i)] = pose_remote(*stub_, request, std::chrono::minutes(3)).status;
    });
  }
  for (std::thread& t : clients) t.join();
  for (const grpc::Status& s : statuses) EXPECT_TRUE(s.ok()) << s.error_message();
  std::printf("peak resident memory of the server: %.0f MB (ceiling %d MB)\n", peak_rss_mb(), kMemoryMb);
}

TEST_F(Hostile, AnUploadReadsNoFileItDidNotSend) {
  const std::string other = labels_id_ + ".nii.gz";  // a stored volume's file name
  const auto stored_volumes = [&] {
    size_t n = 0;
    for (const auto& entry : fs::directory_iterator(dir_ / "store" / "volumes")) n += entry.is_regular_file();
    return n;
  };
  const size_t before = stored_volumes();
  for (const std::string& target :
       std::vector<std::string>{other, "../volumes/" + other, "/etc/passwd", "../index.sqlite", "upload.nii.gz"}) {
    const std::string mha =
        "ObjectType = Image\nNDims = 3\nDimSize = 40 40 130\nElementSpacing = 2 2 2\n"
        "ElementType = MET_UCHAR\nElementDataFile = " +
        target + "\n";
    const grpc::Status status = upload_bytes(mha, v1::FILE_FORMAT_MHA, v1::VOLUME_KIND_LABELS);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << target << ": " << status.error_message();
    EXPECT_TRUE(says(status, "inline")) << status.error_message();
    const std::string nrrd =
        "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 40 40 130\nencoding: gzip\n"
        "data file: " +
        target + "\n\n";
    const grpc::Status detached = upload_bytes(nrrd, v1::FILE_FORMAT_NRRD, v1::VOLUME_KIND_LABELS);
    EXPECT_EQ(detached.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << target << ": " << detached.error_message();
    EXPECT_TRUE(says(detached, "inline")) << detached.error_message();
    EXPECT_FALSE(says(detached, dir_.string())) << detached.error_message();
  }
  // Nothing was stored, and no staging directory is left behind.
  EXPECT_EQ(stored_volumes(), before);
  EXPECT_TRUE(fs::is_empty(dir_ / "store" / "staging"));
}

TEST_F(Hostile, VolumesGivenForTheWrongPurposeAreRefusedBeforeAnyWork) {
  // The CT uploaded as labels: thousands of values, not a segmentation.
  const grpc::Status ct_as_labels =
      upload_bytes(file_text(dir_ / "bar" / "ct.nii.gz"), v1::FILE_FORMAT_NIFTI_GZ, v1::VOLUME_KIND_LABELS);
  EXPECT_EQ(ct_as_labels.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << ct_as_labels.error_message();
  // Ids swapped in the build: named, refused at once (no operation).
  for (const bool both : {false, true}) {
    v1::BuildRigRequest build;
    build.set_labels_volume_id(ct_id_);
    if (both) build.set_ct_volume_id(labels_id_);
    build.set_label_map_json(file_text(dir_ / "bar" / "label_map.json"));
    v1::Operation operation;
    grpc::ClientContext context;
    const grpc::Status status = stub_->BuildRig(&context, build, &operation);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << status.error_message();
    EXPECT_TRUE(says(status, "labels_volume_id")) << status.error_message();
    if (both) {
      EXPECT_TRUE(says(status, "swapped")) << status.error_message();
    }
  }
  v1::BuildRigRequest build;
  build.set_labels_volume_id(labels_id_);
  build.set_ct_volume_id(labels_id_);
  v1::Operation operation;
  grpc::ClientContext context;
  EXPECT_EQ(stub_->BuildRig(&context, build, &operation).error_code(), grpc::StatusCode::INVALID_ARGUMENT);
}

TEST_F(Hostile, ValuesAndEnumsOutOfRangeAreRefusedNamingTheField) {
  struct Case {
    std::string name;
    std::function<void(v1::PoseRequest&)> change;
    std::string names;
  };
  const std::vector<Case> cases{
      {"method 99", [](v1::PoseRequest& r) { r.set_method(static_cast<v1::Method>(99)); }, "method"},
      {"grid policy 99", [](v1::PoseRequest& r) { r.set_grid(static_cast<v1::GridPolicy>(99)); }, "grid"},
      {"format 99", [](v1::PoseRequest& r) { r.set_format(static_cast<v1::FileFormat>(99)); }, "format"},
      {"samples 99", [](v1::PoseRequest& r) { r.set_samples(static_cast<v1::SampleType>(99)); }, "samples"},
      {"flexion 1e308",
       [](v1::PoseRequest& r) { r.set_pose_json(R"({"joints": {"joint_2_3": {"angles_deg": {"flexion": 1e308}}}})"); },
       "flexion"},
      {"root translation 1e300",
       [](v1::PoseRequest& r) { r.set_pose_json(R"({"joints": {}, "root": {"translation_mm": [1e300, 0, 0]}})"); },
       "translation"},
      {"given grid spacing 0",
       [](v1::PoseRequest& r) {
         r.set_grid(v1::GRID_POLICY_GIVEN);
         *r.mutable_given_grid() = cube(10, 1.0);
         r.mutable_given_grid()->set_spacing(1, 0.0);
       },
       "given_grid.spacing[1]"},
      {"given grid origin 1e300",
       [](v1::PoseRequest& r) {
         r.set_grid(v1::GRID_POLICY_GIVEN);
         *r.mutable_given_grid() = cube(10, 1.0);
         r.mutable_given_grid()->set_origin(2, 1e300);
       },
       "given_grid.origin[2]"},
      {"given grid without the policy", [](v1::PoseRequest& r) { *r.mutable_given_grid() = cube(10, 1.0); },
       "given_grid"},
  };
  for (const Case& c : cases) {
    v1::PoseRequest request = bend();
    c.change(request);
    const grpc::Status status = pose_status(request);
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << c.name << ": " << status.error_message();
    EXPECT_TRUE(says(status, c.names)) << c.name << ": " << status.error_message();
  }
  // An upload claiming no bytes is a bad argument, not a lack of resources.
  const grpc::Status empty = OpenUpload(*stub_, 0, std::string(64, '0')).finish();
  EXPECT_EQ(empty.error_code(), grpc::StatusCode::INVALID_ARGUMENT) << empty.error_message();
  EXPECT_TRUE(says(empty, "size_bytes")) << empty.error_message();
  // A built-in label map that does not exist: the message names no CLI flag.
  v1::BuildRigRequest build;
  build.set_labels_volume_id(labels_id_);
  build.set_preset("no-such-preset");
  v1::Operation operation;
  {
    grpc::ClientContext context;
    ASSERT_TRUE(stub_->BuildRig(&context, build, &operation).ok());
  }
  const v1::Operation done = watch(*stub_, operation.id());
  EXPECT_EQ(done.state(), v1::Operation::FAILED);
  EXPECT_EQ(done.error_message().find("--label-map"), std::string::npos) << done.error_message();
  // A preview update with a method out of range is answered with its code, and the stream goes on.
  grpc::ClientContext context;
  auto stream = stub_->Preview(&context);
  v1::PreviewRequest update;
  update.set_rig_id(rig_id_);
  update.set_pose_json(file_text(fs::path(POSEWARP_SOURCE_DIR) / "data/poses/bar_bend_90.json"));
  update.set_method(static_cast<v1::Method>(42));
  update.set_sequence(1);
  ASSERT_TRUE(stream->Write(update));
  v1::PreviewResponse answer;
  ASSERT_TRUE(stream->Read(&answer));
  EXPECT_EQ(answer.error_code(), static_cast<int>(grpc::StatusCode::INVALID_ARGUMENT));
  EXPECT_NE(answer.error_message().find("method"), std::string::npos) << answer.error_message();
  update.set_method(v1::METHOD_DQS);
  update.set_sequence(2);
  ASSERT_TRUE(stream->Write(update));
  ASSERT_TRUE(stream->Read(&answer));
  EXPECT_EQ(answer.error_code(), 0) << answer.error_message();
  EXPECT_GT(answer.surfaces_size(), 0);
  stream->WritesDone();
  EXPECT_TRUE(stream->Finish().ok());
}

}  // namespace
}  // namespace posewarp
