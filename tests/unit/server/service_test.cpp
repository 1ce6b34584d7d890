// PosewarpService as a library, served in process (gRPC's in-process channel) over a store of its own: the handlers'
// answers and refusals without starting the real server (tests/integration/server does that).
#include "service.h"

#include <grpcpp/grpcpp.h>
#include <gtest/gtest.h>

#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <memory>
#include <string>

#include "posewarp/api/files.h"
#include "posewarp/phantom/phantom.h"
#include "posewarp/v1/posewarp.grpc.pb.h"

namespace posewarp::server {
namespace {

namespace fs = std::filesystem;

// A service over a fresh store, with its stub on an in-process channel.
class InProcessService {
 public:
  explicit InProcessService(const std::string& token = "") {
    std::string pattern = (fs::temp_directory_path() / "posewarp-service-XXXXXX").string();
    directory_ = ::mkdtemp(pattern.data());
    if (!token.empty()) {
      std::ofstream(directory_ + "/tokens") << token << "\n";
      EXPECT_TRUE(tokens_.load(directory_ + "/tokens").ok());
    }
    Result<std::unique_ptr<RigStore>> store = RigStore::open(directory_ + "/store", {}, [](const std::string&) {});
    EXPECT_TRUE(store.ok()) << store.status().to_string();
    service_ = std::make_unique<PosewarpService>(std::move(store).value(), ServiceOptions{}, tokens_, metrics_);
    grpc::ServerBuilder builder;
    builder.RegisterService(service_.get());
    server_ = builder.BuildAndStart();
    stub_ = v1::Posewarp::NewStub(server_->InProcessChannel(grpc::ChannelArguments()));
  }
  ~InProcessService() {
    server_->Shutdown();
    service_.reset();
    std::error_code ignored;
    fs::remove_all(directory_, ignored);
  }
  v1::Posewarp::Stub& stub() { return *stub_; }

 private:
  std::string directory_;
  Tokens tokens_;
  Metrics metrics_;
  std::unique_ptr<PosewarpService> service_;
  std::unique_ptr<grpc::Server> server_;
  std::unique_ptr<v1::Posewarp::Stub> stub_;
};

std::unique_ptr<grpc::ClientContext> context(const std::string& token = "") {
  auto c = std::make_unique<grpc::ClientContext>();
  c->set_deadline(std::chrono::system_clock::now() + std::chrono::seconds(20));
  if (!token.empty()) c->AddMetadata("authorization", "Bearer " + token);
  return c;
}

// 16^3 uint8 labels: background, and two boxes labelled 1 and 2.
std::string label_samples() {
  std::string samples(16 * 16 * 16, '\0');
  for (int z = 2; z < 14; ++z) {
    for (int y = 4; y < 12; ++y) {
      for (int x = 4; x < 12; ++x) samples[static_cast<size_t>((z * 16 + y) * 16 + x)] = z < 8 ? 1 : 2;
    }
  }
  return samples;
}

v1::Grid grid16() {
  v1::Grid grid;
  for (int a = 0; a < 3; ++a) {
    grid.add_size(16);
    grid.add_spacing(2.0);
    grid.add_origin(-16.0);
  }
  for (int i = 0; i < 9; ++i) grid.add_direction(i % 4 == 0 ? 1.0 : 0.0);
  return grid;
}

// Sends `header` then `bytes` in one chunk (none when empty); the call's status, the answer in `volume`.
grpc::Status upload(v1::Posewarp::Stub& stub, v1::UploadVolumeHeader header, const std::string& bytes,
                    v1::Volume* volume) {
  auto c = context();
  std::unique_ptr<grpc::ClientWriter<v1::UploadVolumeRequest>> writer = stub.UploadVolume(c.get(), volume);
  v1::UploadVolumeRequest part;
  *part.mutable_header() = std::move(header);
  writer->Write(part);
  if (!bytes.empty()) {
    v1::UploadVolumeRequest chunk;
    chunk.set_chunk(bytes);
    writer->Write(chunk);
  }
  writer->WritesDone();
  return writer->Finish();
}

v1::UploadVolumeHeader raw_labels_header(const std::string& samples) {
  v1::UploadVolumeHeader header;
  header.set_kind(v1::VOLUME_KIND_LABELS);
  header.set_format(v1::FILE_FORMAT_RAW);
  header.set_size_bytes(samples.size());
  header.set_sha256(api::sha256_hex(samples));
  *header.mutable_raw_grid() = grid16();
  header.set_raw_pixel_type(v1::PIXEL_TYPE_UINT8);
  return header;
}

TEST(ServiceInProcess, AnEmptyStoreListsNoRigsAndAnUnknownRigIsNotFound) {
  InProcessService service;
  v1::ListRigsResponse rigs;
  ASSERT_TRUE(service.stub().ListRigs(context().get(), {}, &rigs).ok());
  EXPECT_EQ(rigs.rigs_size(), 0);
  v1::GetRigRequest request;
  request.set_rig_id(std::string(64, 'a'));
  v1::Rig rig;
  EXPECT_EQ(service.stub().GetRig(context().get(), request, &rig).error_code(), grpc::StatusCode::NOT_FOUND);
  v1::ListRigsRequest bad_page;
  bad_page.set_page_token("../etc");
  const grpc::Status refused = service.stub().ListRigs(context().get(), bad_page, &rigs);
  EXPECT_EQ(refused.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(refused.error_message().find("page_token"), std::string::npos) << refused.error_message();
}

TEST(ServiceInProcess, RawLabelsUploadOnceUnderOneIdWithTheirGrid) {
  InProcessService service;
  const std::string samples = label_samples();
  v1::Volume first, second;
  const grpc::Status status = upload(service.stub(), raw_labels_header(samples), samples, &first);
  ASSERT_TRUE(status.ok()) << status.error_message();
  EXPECT_TRUE(api::is_hex_id(first.id()));
  EXPECT_EQ(first.kind(), v1::VOLUME_KIND_LABELS);
  EXPECT_EQ(first.grid().SerializeAsString(), grid16().SerializeAsString());
  EXPECT_EQ(first.pixel_type(), "uint8");
  ASSERT_TRUE(upload(service.stub(), raw_labels_header(samples), samples, &second).ok());
  EXPECT_EQ(second.id(), first.id());
  EXPECT_GT(second.size_bytes(), 0u);
}

TEST(ServiceInProcess, AFileTheStoreHoldsIsAnsweredAfterItsHeader) {
  InProcessService service;
  const std::string samples = label_samples();
  v1::Volume raw;
  ASSERT_TRUE(upload(service.stub(), raw_labels_header(samples), samples, &raw).ok());
  // The same volume as a NIfTI file: stored once under the file's SHA-256, then known at its header.
  ImageGeometry geometry;
  geometry.size = {16, 16, 16};
  geometry.spacing = {2.0, 2.0, 2.0};
  geometry.origin = {-16.0, -16.0, -16.0};
  LabelVolume labels(geometry);
  for (size_t i = 0; i < samples.size(); ++i) labels.data()[i] = samples[i];
  Result<std::string> file = api::encode_volume(labels, api::VolumeFormat::kNifti, true);
  ASSERT_TRUE(file.ok()) << file.status().to_string();
  v1::UploadVolumeHeader header;
  header.set_kind(v1::VOLUME_KIND_LABELS);
  header.set_format(v1::FILE_FORMAT_NIFTI_GZ);
  header.set_size_bytes(file->size());
  header.set_sha256(api::sha256_hex(*file));
  v1::Volume first, again;
  ASSERT_TRUE(upload(service.stub(), header, *file, &first).ok());
  EXPECT_FALSE(first.already_stored());
  EXPECT_EQ(first.id(), header.sha256());
  // The header alone: the store holds the file, so its bytes are never asked for.
  ASSERT_TRUE(upload(service.stub(), header, "", &again).ok());
  EXPECT_TRUE(again.already_stored());
  EXPECT_EQ(again.id(), first.id());
  EXPECT_EQ(again.grid().SerializeAsString(), first.grid().SerializeAsString());
}

TEST(ServiceInProcess, UploadsWithoutAHeaderOrWithWrongBytesAreRefused) {
  InProcessService service;
  const std::string samples = label_samples();
  v1::Volume volume;
  {
    auto c = context();
    auto writer = service.stub().UploadVolume(c.get(), &volume);
    v1::UploadVolumeRequest chunk;
    chunk.set_chunk(samples);
    writer->Write(chunk);
    writer->WritesDone();
    const grpc::Status status = writer->Finish();
    EXPECT_EQ(status.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
    EXPECT_NE(status.error_message().find("header"), std::string::npos) << status.error_message();
  }
  v1::UploadVolumeHeader header = raw_labels_header(samples);
  header.set_sha256(std::string(64, '0'));
  const grpc::Status wrong = upload(service.stub(), header, samples, &volume);
  EXPECT_EQ(wrong.error_code(), grpc::StatusCode::DATA_LOSS);
  EXPECT_NE(wrong.error_message().find("sha256"), std::string::npos) << wrong.error_message();
  const grpc::Status short_upload = upload(service.stub(), raw_labels_header(samples), samples.substr(0, 100), &volume);
  EXPECT_EQ(short_upload.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(short_upload.error_message().find("4096"), std::string::npos) << short_upload.error_message();
  const grpc::Status nothing = upload(service.stub(), raw_labels_header(samples), "", &volume);
  EXPECT_EQ(nothing.error_code(), grpc::StatusCode::DATA_LOSS);
  EXPECT_NE(nothing.error_message().find("after 0 of 4096 bytes"), std::string::npos) << nothing.error_message();
}

TEST(ServiceInProcess, ABuildOfSwappedOrUnknownVolumesIsRefusedBeforeAnyWork) {
  InProcessService service;
  const std::string samples = label_samples();
  v1::Volume labels, intensity;
  ASSERT_TRUE(upload(service.stub(), raw_labels_header(samples), samples, &labels).ok());
  v1::UploadVolumeHeader as_intensity = raw_labels_header(samples);
  as_intensity.set_kind(v1::VOLUME_KIND_INTENSITY);
  ASSERT_TRUE(upload(service.stub(), as_intensity, samples, &intensity).ok());
  ASSERT_NE(intensity.id(), labels.id());
  v1::BuildRigRequest request;
  request.set_labels_volume_id(intensity.id());
  request.set_ct_volume_id(labels.id());
  v1::Operation operation;
  const grpc::Status swapped = service.stub().BuildRig(context().get(), request, &operation);
  EXPECT_EQ(swapped.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(swapped.error_message().find("swapped"), std::string::npos) << swapped.error_message();
  request.clear_ct_volume_id();
  const grpc::Status labels_wrong = service.stub().BuildRig(context().get(), request, &operation);
  EXPECT_EQ(labels_wrong.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(labels_wrong.error_message().find("VOLUME_KIND_INTENSITY"), std::string::npos)
      << labels_wrong.error_message();
  request.set_labels_volume_id(std::string(64, 'b'));
  const grpc::Status unknown = service.stub().BuildRig(context().get(), request, &operation);
  EXPECT_EQ(unknown.error_code(), grpc::StatusCode::NOT_FOUND);
  EXPECT_NE(unknown.error_message().find("labels_volume_id"), std::string::npos) << unknown.error_message();
  v1::GetOperationRequest get;
  get.set_operation_id(std::string(32, 'c'));
  EXPECT_EQ(service.stub().GetOperation(context().get(), get, &operation).error_code(), grpc::StatusCode::NOT_FOUND);
  get.clear_operation_id();
  EXPECT_EQ(service.stub().CancelOperation(context().get(), get, &operation).error_code(),
            grpc::StatusCode::INVALID_ARGUMENT);
}

TEST(ServiceInProcess, ATokenIsRequiredWhenTheServiceHasTokens) {
  InProcessService service("s3cret-token");
  v1::ListRigsResponse rigs;
  const grpc::Status without = service.stub().ListRigs(context().get(), {}, &rigs);
  EXPECT_EQ(without.error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_NE(without.error_message().find("bearer token"), std::string::npos) << without.error_message();
  EXPECT_EQ(service.stub().ListRigs(context("wrong").get(), {}, &rigs).error_code(), grpc::StatusCode::UNAUTHENTICATED);
  EXPECT_TRUE(service.stub().ListRigs(context("s3cret-token").get(), {}, &rigs).ok());
}

// The status a Pose stream ends with.
grpc::Status pose(v1::Posewarp::Stub& stub, const v1::PoseRequest& request) {
  auto c = context();
  auto reader = stub.Pose(c.get(), request);
  v1::PoseResponse message;
  while (reader->Read(&message)) {
  }
  return reader->Finish();
}

TEST(ServiceInProcess, APoseOfAnUnknownRigIsNotFoundAndAMalformedOneNamesItsField) {
  InProcessService service;
  v1::PoseRequest request;
  request.set_rig_id(std::string(64, 'd'));
  request.set_pose_json(R"({"format": "posewarp.pose", "version": 1, "name": "identity", "joints": {}})");
  const grpc::Status unknown = pose(service.stub(), request);
  EXPECT_EQ(unknown.error_code(), grpc::StatusCode::NOT_FOUND) << unknown.error_message();
  request.set_chunk_bytes(5);
  const grpc::Status chunk = pose(service.stub(), request);
  EXPECT_EQ(chunk.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(chunk.error_message().find("chunk_bytes"), std::string::npos) << chunk.error_message();
  request.set_chunk_bytes(0);
  request.set_pose_json("{");
  const grpc::Status json = pose(service.stub(), request);
  EXPECT_EQ(json.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(json.error_message().find("pose_json"), std::string::npos) << json.error_message();
}

TEST(ServiceInProcess, ABuiltRigIsWatchedToItsEndListedPosedAsTheStudyPreviewedAndDeleted) {
  InProcessService service;
  phantom::BarParams bar;
  bar.length_mm = 160.0;
  bar.bone_count = 3;
  Result<phantom::Phantom> phantom = phantom::make_bar(bar);
  ASSERT_TRUE(phantom.ok()) << phantom.status().to_string();
  Result<std::string> file = api::encode_volume(phantom->labels, api::VolumeFormat::kNifti, true);
  ASSERT_TRUE(file.ok()) << file.status().to_string();
  v1::UploadVolumeHeader header;
  header.set_kind(v1::VOLUME_KIND_LABELS);
  header.set_format(v1::FILE_FORMAT_NIFTI_GZ);
  header.set_size_bytes(file->size());
  header.set_sha256(api::sha256_hex(*file));
  v1::Volume labels;
  ASSERT_TRUE(upload(service.stub(), header, *file, &labels).ok());
  v1::BuildRigRequest build;
  build.set_labels_volume_id(labels.id());
  build.set_label_map_json(api::label_map_to_json(phantom->label_map));
  v1::Operation operation;
  ASSERT_TRUE(service.stub().BuildRig(context().get(), build, &operation).ok());
  v1::GetOperationRequest watch;
  watch.set_operation_id(operation.id());
  auto c = context();
  auto states = service.stub().WatchOperation(c.get(), watch);
  while (states->Read(&operation)) {
  }
  ASSERT_TRUE(states->Finish().ok());
  ASSERT_EQ(operation.state(), v1::Operation::SUCCEEDED) << operation.error_message();
  v1::ListRigsResponse rigs;
  ASSERT_TRUE(service.stub().ListRigs(context().get(), {}, &rigs).ok());
  ASSERT_EQ(rigs.rigs_size(), 1);
  EXPECT_EQ(rigs.rigs(0).id(), operation.rig_id());

  // The identity pose gives the study back: its labels, as int32 samples, after a header that says how many bytes.
  v1::PoseRequest request;
  request.set_rig_id(operation.rig_id());
  request.set_pose_json(R"({"format": "posewarp.pose", "version": 1, "name": "identity", "joints": {}})");
  request.set_want_labels(true);
  request.set_samples(v1::SAMPLE_TYPE_COMPUTED);
  auto p = context();
  auto reader = service.stub().Pose(p.get(), request);
  v1::PoseResponse message;
  ASSERT_TRUE(reader->Read(&message));
  ASSERT_TRUE(message.has_header());
  const int64_t voxels = phantom->labels.voxel_count();
  EXPECT_EQ(message.header().label_bytes(), static_cast<uint64_t>(voxels) * 4);
  std::string posed;
  bool reported = false;
  while (reader->Read(&message)) {
    if (message.has_labels()) posed += message.labels().data();
    reported = reported || message.has_report();
  }
  ASSERT_TRUE(reader->Finish().ok());
  EXPECT_TRUE(reported);
  ASSERT_EQ(posed.size(), static_cast<size_t>(voxels) * 4);
  EXPECT_EQ(std::memcmp(posed.data(), phantom->labels.data(), posed.size()), 0);

  // The same labels as runs: each chunk whole (value, count) pairs that decode where its offset says, in fewer bytes;
  // runs with a file format are refused.
  request.set_label_encoding(v1::LABEL_ENCODING_RUNS);
  auto r = context();
  auto runs = service.stub().Pose(r.get(), request);
  ASSERT_TRUE(runs->Read(&message) && message.has_header());
  EXPECT_EQ(message.header().label_encoding(), v1::LABEL_ENCODING_RUNS);
  EXPECT_EQ(message.header().label_bytes(), static_cast<uint64_t>(voxels) * 4);
  std::string decoded;
  size_t encoded = 0;
  while (runs->Read(&message)) {
    if (!message.has_labels()) continue;
    const std::string& data = message.labels().data();
    EXPECT_EQ(message.labels().offset(), decoded.size());
    ASSERT_EQ(data.size() % 8, 0u);
    encoded += data.size();
    for (size_t at = 0; at < data.size(); at += 8) {
      uint32_t count = 0;
      std::memcpy(&count, data.data() + at + 4, 4);
      ASSERT_GT(count, 0u);
      for (uint32_t n = 0; n < count; ++n) decoded.append(data, at, 4);
    }
  }
  ASSERT_TRUE(runs->Finish().ok());
  ASSERT_EQ(decoded.size(), posed.size());
  EXPECT_EQ(decoded, posed);
  EXPECT_LT(encoded * 10, posed.size());
  request.set_format(v1::FILE_FORMAT_NIFTI_GZ);
  auto refused_context = context();
  auto refused = service.stub().Pose(refused_context.get(), request);
  while (refused->Read(&message)) {
  }
  const grpc::Status why = refused->Finish();
  EXPECT_EQ(why.error_code(), grpc::StatusCode::INVALID_ARGUMENT);
  EXPECT_NE(why.error_message().find("label_encoding"), std::string::npos) << why.error_message();
  request.set_format(v1::FILE_FORMAT_RAW);
  request.clear_label_encoding();

  // A preview stream: each update answered in turn, a refused one with its code, and the stream goes on.
  auto v = context();
  auto preview = service.stub().Preview(v.get());
  v1::PreviewRequest update;
  update.set_rig_id(operation.rig_id());
  update.set_pose_json(request.pose_json());
  update.set_sequence(7);
  ASSERT_TRUE(preview->Write(update));
  v1::PreviewResponse answer;
  ASSERT_TRUE(preview->Read(&answer));
  EXPECT_EQ(answer.sequence(), 7u);
  EXPECT_EQ(answer.error_code(), 0) << answer.error_message();
  EXPECT_GT(answer.surfaces_size(), 0);
  EXPECT_EQ(answer.topology_size(), answer.surfaces_size());
  update.clear_rig_id();
  update.set_pose_json("{");
  update.set_sequence(8);
  ASSERT_TRUE(preview->Write(update));
  ASSERT_TRUE(preview->Read(&answer));
  EXPECT_EQ(answer.sequence(), 8u);
  EXPECT_EQ(answer.error_code(), static_cast<int32_t>(grpc::StatusCode::INVALID_ARGUMENT));
  preview->WritesDone();
  EXPECT_TRUE(preview->Finish().ok());

  v1::GetRigRequest rig;
  rig.set_rig_id(operation.rig_id());
  v1::DeleteRigResponse deleted;
  ASSERT_TRUE(service.stub().DeleteRig(context().get(), rig, &deleted).ok());
  v1::Rig gone;
  EXPECT_EQ(service.stub().GetRig(context().get(), rig, &gone).error_code(), grpc::StatusCode::NOT_FOUND);
}

}  // namespace
}  // namespace posewarp::server
