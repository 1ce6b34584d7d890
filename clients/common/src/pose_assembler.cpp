// A Pose answer put together from its stream's parts (pose_assembler.h).
#include "posewarp_client/pose_assembler.h"

#include <algorithm>
#include <cstring>

namespace posewarp::client {

size_t sample_bytes(v1::PixelType type) {
  switch (type) {
    case v1::PIXEL_TYPE_UINT8:
    case v1::PIXEL_TYPE_INT8: return 1;
    case v1::PIXEL_TYPE_UINT16:
    case v1::PIXEL_TYPE_INT16: return 2;
    case v1::PIXEL_TYPE_UINT32:
    case v1::PIXEL_TYPE_INT32:
    case v1::PIXEL_TYPE_FLOAT32: return 4;
    case v1::PIXEL_TYPE_FLOAT64: return 8;
    default: return 0;
  }
}

bool PoseAssembler::Incoming::add(const v1::VolumeChunk& chunk, uint64_t limit) {
  if (chunk.offset() != bytes->size()) return false;
  if (chunk.total_bytes() > 0) expected = chunk.total_bytes();
  if (expected > limit) return false;
  if (bytes->empty() && expected > 0) bytes->reserve(static_cast<size_t>(expected));
  if (run_sample == 0) {
    if (bytes->size() + chunk.data().size() > std::max(expected, bytes->size())) return false;  // past its size
    *bytes += chunk.data();
    return true;
  }
  const std::string& runs = chunk.data();
  const size_t pair = run_sample + 4;
  if (runs.size() % pair != 0) return false;
  for (size_t at = 0; at < runs.size(); at += pair) {
    uint32_t count = 0;
    for (size_t b = 0; b < 4; ++b)
      count |= static_cast<uint32_t>(static_cast<unsigned char>(runs[at + run_sample + b])) << (8 * b);
    if (count == 0 || bytes->size() + uint64_t{count} * run_sample > expected) return false;
    const size_t end = bytes->size();
    bytes->resize(end + size_t{count} * run_sample);
    char* out = bytes->data() + end;
    if (run_sample == 1) {
      std::memset(out, runs[at], count);
    } else {
      for (uint32_t c = 0; c < count; ++c) std::memcpy(out + size_t{c} * run_sample, runs.data() + at, run_sample);
    }
  }
  return true;
}

PoseAssembler::PoseAssembler(PoseAnswer* answer, uint64_t max_volume_bytes)
    : answer_(answer),
      limit_(max_volume_bytes),
      labels_{&answer->labels},
      ct_{&answer->ct},
      inverse_{&answer->inverse_field},
      forward_{&answer->forward_field} {
  *answer_ = PoseAnswer{};
}

bool PoseAssembler::add(const v1::PoseResponse& part) {
  switch (part.part_case()) {
    case v1::PoseResponse::kHeader: {
      const v1::PoseHeader& header = answer_->header = part.header();
      labels_.expected = header.label_bytes();
      ct_.expected = header.ct_bytes();
      inverse_.expected = header.inverse_field_bytes();
      forward_.expected = header.forward_field_bytes();
      for (const Incoming* volume : {&labels_, &ct_, &inverse_, &forward_}) {
        if (volume->expected > limit_) return false;
      }
      if (header.label_encoding() == v1::LABEL_ENCODING_RUNS) {
        labels_.run_sample = sample_bytes(header.label_sample_type());
        return labels_.run_sample > 0 || labels_.expected == 0;  // runs of samples of a known type
      }
      return true;
    }
    case v1::PoseResponse::kLabels: return labels_.add(part.labels(), limit_);
    case v1::PoseResponse::kCt: return ct_.add(part.ct(), limit_);
    case v1::PoseResponse::kInverseField: return inverse_.add(part.inverse_field(), limit_);
    case v1::PoseResponse::kForwardField: return forward_.add(part.forward_field(), limit_);
    case v1::PoseResponse::kSurface: answer_->surfaces.push_back(part.surface()); return true;
    case v1::PoseResponse::kReport: answer_->report = part.report(); return true;
    default: return true;
  }
}

uint64_t PoseAssembler::received() const {
  return answer_->labels.size() + answer_->ct.size();
}

uint64_t PoseAssembler::expected() const {
  return labels_.expected + ct_.expected;
}

bool PoseAssembler::complete() const {
  return labels_.complete() && ct_.complete() && inverse_.complete() && forward_.complete();
}

}  // namespace posewarp::client
