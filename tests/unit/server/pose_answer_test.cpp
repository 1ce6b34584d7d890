// The C++ clients' reading of a Pose stream (clients/common): labels sent as runs decoded where each chunk's offset
// says, and a stream that no well-behaved server sends refused as DATA_LOSS, from scripted streams.
#include "posewarp_client/pose_answer.h"

#include <gtest/gtest.h>

#include <cstdint>
#include <deque>
#include <string>
#include <utility>
#include <vector>

namespace posewarp::client {
namespace {

// A Pose stream that gives the parts it was made with, in order, then OK.
class ScriptedStream : public grpc::ClientReaderInterface<v1::PoseResponse> {
 public:
  explicit ScriptedStream(std::vector<v1::PoseResponse> parts) : parts_(parts.begin(), parts.end()) {}
  bool Read(v1::PoseResponse* part) override {
    if (parts_.empty()) return false;
    *part = std::move(parts_.front());
    parts_.pop_front();
    return true;
  }
  bool NextMessageSize(uint32_t* size) override {
    *size = parts_.empty() ? 0 : static_cast<uint32_t>(parts_.front().ByteSizeLong());
    return !parts_.empty();
  }
  grpc::Status Finish() override { return grpc::Status::OK; }
  void WaitForInitialMetadata() override {}

 private:
  std::deque<v1::PoseResponse> parts_;
};

v1::PoseResponse runs_header(uint64_t label_bytes, v1::PixelType type) {
  v1::PoseResponse part;
  part.mutable_header()->set_label_bytes(label_bytes);
  part.mutable_header()->set_label_sample_type(type);
  part.mutable_header()->set_label_encoding(v1::LABEL_ENCODING_RUNS);
  return part;
}

// A chunk of runs: (value of `sample` bytes, little-endian; count uint32 little-endian) pairs.
v1::PoseResponse runs_chunk(uint64_t offset, const std::vector<std::pair<int64_t, uint32_t>>& runs, size_t sample,
                            uint64_t total = 0) {
  v1::PoseResponse part;
  part.mutable_labels()->set_offset(offset);
  part.mutable_labels()->set_total_bytes(total);
  std::string* data = part.mutable_labels()->mutable_data();
  for (const auto& [value, count] : runs) {
    for (size_t b = 0; b < sample; ++b) data->push_back(static_cast<char>(value >> (8 * b)));
    for (int b = 0; b < 4; ++b) data->push_back(static_cast<char>(count >> (8 * b)));
  }
  return part;
}

grpc::Status read(std::vector<v1::PoseResponse> parts, PoseAnswer* answer) {
  grpc::ClientContext context;
  ScriptedStream stream(std::move(parts));
  return read_pose(context, stream, answer);
}

TEST(PoseAnswer, LabelRunsDecodeWhereEachChunkSays) {
  PoseAnswer answer;
  grpc::Status status =
      read({runs_header(10, v1::PIXEL_TYPE_UINT8), runs_chunk(0, {{5, 4}, {7, 3}}, 1, 10), runs_chunk(7, {{9, 3}}, 1)},
           &answer);
  ASSERT_TRUE(status.ok()) << status.error_message();
  EXPECT_EQ(answer.labels, std::string("\5\5\5\5\7\7\7\t\t\t"));

  // Two-byte samples, little-endian.
  status = read({runs_header(6, v1::PIXEL_TYPE_INT16), runs_chunk(0, {{-2, 2}, {0x1234, 1}}, 2, 6)}, &answer);
  ASSERT_TRUE(status.ok()) << status.error_message();
  EXPECT_EQ(answer.labels, std::string("\xfe\xff\xfe\xff\x34\x12", 6));
}

TEST(PoseAnswer, MalformedRunsAreDataLoss) {
  const std::vector<std::vector<v1::PoseResponse>> streams = {
      {runs_header(10, v1::PIXEL_TYPE_UINT8), runs_chunk(0, {{5, 11}}, 1, 10)},          // past the size
      {runs_header(10, v1::PIXEL_TYPE_UINT8), runs_chunk(0, {{5, 0}, {5, 10}}, 1, 10)},  // a run of none
      {runs_header(10, v1::PIXEL_TYPE_UINT8), runs_chunk(0, {{5, 4}}, 1, 10), runs_chunk(5, {{7, 6}}, 1)},  // a gap
      {runs_header(10, v1::PIXEL_TYPE_UNSPECIFIED), runs_chunk(0, {{5, 10}}, 1, 10)},  // no sample type
      {runs_header(10, v1::PIXEL_TYPE_UINT8), runs_chunk(0, {{5, 4}}, 1, 10)},         // ends short
  };
  for (size_t s = 0; s < streams.size(); ++s) {
    PoseAnswer answer;
    EXPECT_EQ(read(streams[s], &answer).error_code(), grpc::StatusCode::DATA_LOSS) << "stream " << s;
  }
  // A chunk that is not whole pairs.
  std::vector<v1::PoseResponse> torn = {runs_header(10, v1::PIXEL_TYPE_UINT8), runs_chunk(0, {{5, 10}}, 1, 10)};
  torn[1].mutable_labels()->mutable_data()->pop_back();
  PoseAnswer answer;
  EXPECT_EQ(read(torn, &answer).error_code(), grpc::StatusCode::DATA_LOSS);
}

TEST(PoseAnswer, SizesPastTheLimitOrBytesPastTheSizeAreDataLossBeforeAnyAllocation) {
  // A header that announces more than any answer holds: refused on the header, nothing reserved for it.
  v1::PoseResponse huge;
  huge.mutable_header()->set_ct_bytes(kMaxAnswerVolumeBytes + 1);
  PoseAnswer answer;
  EXPECT_EQ(read({huge}, &answer).error_code(), grpc::StatusCode::DATA_LOSS);
  // A file's first chunk that announces as much.
  v1::PoseResponse file;
  file.mutable_ct()->set_total_bytes(uint64_t{1} << 62);
  file.mutable_ct()->set_data("x");
  EXPECT_EQ(read({v1::PoseResponse(), file}, &answer).error_code(), grpc::StatusCode::DATA_LOSS);
  // Raw samples past the size the header gave.
  v1::PoseResponse header, chunk;
  header.mutable_header()->set_ct_bytes(4);
  chunk.mutable_ct()->set_data("12345");
  EXPECT_EQ(read({header, chunk}, &answer).error_code(), grpc::StatusCode::DATA_LOSS);
  // Within both, the same parts make an answer.
  chunk.mutable_ct()->set_data("1234");
  ASSERT_TRUE(read({header, chunk}, &answer).ok());
  EXPECT_EQ(answer.ct, "1234");
  // The assembler's own limit, as the fuzzer sets it.
  PoseAssembler small(&answer, 8);
  EXPECT_TRUE(small.add(header));
  header.mutable_header()->set_ct_bytes(9);
  EXPECT_FALSE(small.add(header));
}

}  // namespace
}  // namespace posewarp::client
