// Centres of rotation: tets bucketed by bone pair and clustered on a weight grid, then summed per vertex (eq. 6-7).
#include "posewarp/common/exception_wall.h"
#include "posewarp/cor/rotation_centres.h"

#include <Eigen/Core>
#include <Eigen/Geometry>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <cmath>
#include <cstdint>
#include <exception>
#include <new>
#include <string>
#include <string_view>
#include <utility>
#include <vector>

#include "posewarp/common/parallel.h"

namespace posewarp::cor {
namespace {

constexpr int64_t kVertexChunk = 256;  // vertices per progress/cancel step
constexpr int64_t kTetChunk = 16384;   // tets per chunk of the bucketing passes (fixed, so results are deterministic)
// A blended vertex whose eq. 7 denominator is below this fraction of the mesh volume shares no bone pair with
// any tet (or only with tets whose similarity underflows): it keeps the vertex as centre.
constexpr double kUnsupportedFraction = 1e-14;
constexpr double kClusterShare = 0.1;  // share of the progress bar spent bucketing and clustering tets

enum VertexState : uint8_t { kRigid = 0, kBlended = 1, kCentred = 2, kUnsupported = 3 };

struct SegmentWeight {
  int32_t segment;
  double weight;
};

std::string number_text(double value) {
  std::string s = std::to_string(value);
  while (s.size() > 1 && s.back() == '0') s.pop_back();
  if (!s.empty() && s.back() == '.') s.pop_back();
  return s;
}

// The nonzero weights of vertex v, in row order.
void vertex_support(const SkinWeights& weights, int64_t v, std::vector<SegmentWeight>* out) {
  out->clear();
  for (int c = 0; c < weights.influences; ++c) {
    const float value = weights.weight(v, c);
    if (value > 0.0f) out->push_back({weights.segment(v, c), static_cast<double>(value)});
  }
}

// One segment dominates, or there is no pair of bones to blend between.
bool rigid_by_weights(const std::vector<SegmentWeight>& support, double rigid_threshold) {
  if (support.size() < 2) return true;
  double largest = 0.0;
  for (const SegmentWeight& sw : support) largest = std::max(largest, sw.weight);
  return largest >= rigid_threshold;
}

// Eq. 7's tet weight (w_t1 + w_t2 + w_t3 + w_t4) / 4, nonzero entries only, sorted by segment.
void tet_support(const TetMesh& mesh, const SkinWeights& weights, int64_t t, std::vector<SegmentWeight>* out) {
  out->clear();
  for (int corner = 0; corner < 4; ++corner) {
    const int64_t v = mesh.tets(t, corner);
    for (int c = 0; c < weights.influences; ++c) {
      const float value = weights.weight(v, c);
      if (!(value > 0.0f)) continue;
      const int32_t segment = weights.segment(v, c);
      auto it =
          std::find_if(out->begin(), out->end(), [segment](const SegmentWeight& sw) { return sw.segment == segment; });
      if (it == out->end()) {
        out->push_back({segment, 0.25 * value});
      } else {
        it->weight += 0.25 * value;
      }
    }
  }
  std::sort(out->begin(), out->end(),
            [](const SegmentWeight& a, const SegmentWeight& b) { return a.segment < b.segment; });
}

double weight_of(const std::vector<SegmentWeight>& support, int32_t segment) {
  for (const SegmentWeight& sw : support) {
    if (sw.segment == segment) return sw.weight;
  }
  return 0.0;
}

// Volume (mm^3, unsigned) and centroid (mm, relative to `origin`) of tet t.
struct TetGeometry {
  double volume;
  Eigen::Vector3d centroid;
};

TetGeometry tet_geometry(const TetMesh& mesh, int64_t t, const Eigen::Vector3d& origin) {
  Eigen::Vector3d p[4];
  for (int corner = 0; corner < 4; ++corner) p[corner] = mesh.vertices.row(mesh.tets(t, corner)).transpose() - origin;
  const double det = (p[1] - p[0]).dot((p[2] - p[0]).cross(p[3] - p[0]));
  return {std::abs(det) / 6.0, 0.25 * (p[0] + p[1] + p[2] + p[3])};
}

// Centre of the vertices' bounding box: centroids are summed relative to it, which keeps the sums well conditioned
// for meshes far from the physical origin.
Eigen::Vector3d bounding_box_centre(const TetMesh& mesh) {
  if (mesh.vertex_count() == 0) return Eigen::Vector3d::Zero();
  return 0.5 * (mesh.vertices.colwise().minCoeff() + mesh.vertices.colwise().maxCoeff()).transpose();
}

// Numbers the unordered bone pairs (i < j) that blended vertices use, in (i, j) order. Dense table for the
// realistic segment counts, sorted keys beyond that.
class PairIndex {
 public:
  explicit PairIndex(int segment_count) : segment_count_(segment_count) {
    if (dense()) table_.assign(static_cast<size_t>(segment_count) * static_cast<size_t>(segment_count), -1);
  }

  void mark(int32_t i, int32_t j) {
    if (dense()) {
      table_[key(i, j)] = 0;
    } else if (keys_.empty() || keys_.back() != key(i, j)) {
      keys_.push_back(key(i, j));
    }
  }

  void finish() {
    if (dense()) {
      keys_.clear();
      for (size_t k = 0; k < table_.size(); ++k) {
        if (table_[k] == 0) {
          table_[k] = static_cast<int32_t>(keys_.size());
          keys_.push_back(static_cast<int64_t>(k));
        }
      }
    } else {
      std::sort(keys_.begin(), keys_.end());
      keys_.erase(std::unique(keys_.begin(), keys_.end()), keys_.end());
    }
  }

  // Bucket of the pair (i < j), or -1.
  int32_t find(int32_t i, int32_t j) const {
    const int64_t k = key(i, j);
    if (dense()) return table_[static_cast<size_t>(k)];
    const auto it = std::lower_bound(keys_.begin(), keys_.end(), k);
    return it != keys_.end() && *it == k ? static_cast<int32_t>(it - keys_.begin()) : -1;
  }

  int64_t size() const { return static_cast<int64_t>(keys_.size()); }

  // The pair (i < j) of a bucket.
  std::pair<int32_t, int32_t> segments(int32_t bucket) const {
    const int64_t k = keys_[static_cast<size_t>(bucket)];
    return {static_cast<int32_t>(k / segment_count_), static_cast<int32_t>(k % segment_count_)};
  }

 private:
  static constexpr int kDenseLimit = 2048;
  bool dense() const { return segment_count_ <= kDenseLimit; }
  int64_t key(int32_t i, int32_t j) const { return static_cast<int64_t>(i) * segment_count_ + j; }

  int segment_count_;
  std::vector<int32_t> table_;  // segment_count^2: -1 unused, else the bucket
  std::vector<int64_t> keys_;   // i * segment_count + j per bucket
};

// Tet clusters of all pair buckets, structure of arrays; bucket b owns [offset[b], offset[b + 1]).
// For bucket (i, j) and cluster k: (x[k], y[k]) is the cluster's representative (w_ti, w_tj), its mean weighted
// by V_t w_ti w_tj; mass[k] = sum V_t w_ti w_tj (mm^3); moment[k] = sum V_t w_ti w_tj c_t (mm^4, relative to the
// bounding-box centre).
struct PairClusters {
  std::vector<int64_t> offset;
  std::vector<double> x, y, mass, moment_x, moment_y, moment_z;
};

// Writes the centre of vertex v from eq. 7's sums (moments relative to `origin`); returns its state.
VertexState finish_vertex(const TetMesh& mesh, int64_t v, double denominator, const Eigen::Vector3d& numerator,
                          double unsupported_below, const Eigen::Vector3d& origin, RotationCentres* out) {
  const Eigen::Vector3d centre = origin + numerator / denominator;
  if (denominator > unsupported_below && centre.allFinite()) {
    out->centre.row(v) = centre.transpose();
    out->rigid[static_cast<size_t>(v)] = 0;
    return kCentred;
  }
  out->centre.row(v) = mesh.vertices.row(v);
  out->rigid[static_cast<size_t>(v)] = 1;
  return kUnsupported;
}

Status validate_inputs(const TetMesh& mesh, const SkinWeights& weights) {
  const int64_t vertex_count = mesh.vertex_count();
  const int64_t tet_count = mesh.tet_count();
  if (vertex_count > 0 && mesh.vertices.cols() != 3) {
    return invalid_argument_error("mesh vertices must be #V x 3, got " + std::to_string(mesh.vertices.cols()) +
                                  " columns");
  }
  if (tet_count > 0 && mesh.tets.cols() != 4) {
    return invalid_argument_error("mesh tets must be #T x 4, got " + std::to_string(mesh.tets.cols()) + " columns");
  }
  if (vertex_count > 0 && !mesh.vertices.allFinite()) {
    return invalid_argument_error("mesh vertices hold NaN or infinite coordinates; rebuild the mesh");
  }
  if (tet_count > 0 && (mesh.tets.minCoeff() < 0 || mesh.tets.maxCoeff() >= vertex_count)) {
    return invalid_argument_error("a tet refers to a vertex outside 0.." + std::to_string(vertex_count - 1) +
                                  "; the tets and vertices do not belong to one mesh");
  }
  if (tet_count > static_cast<int64_t>(UINT32_MAX)) {
    return invalid_argument_error("the mesh has " + std::to_string(tet_count) +
                                  " tets, more than the 2^32 - 1 "
                                  "this stage indexes; mesh the body more coarsely");
  }
  if (weights.segment_count != mesh.segment_count) {
    return invalid_argument_error("skin weights are over " + std::to_string(weights.segment_count) +
                                  " segments but the mesh has " + std::to_string(mesh.segment_count) +
                                  "; compute the weights on this mesh");
  }
  if (weights.segment.rows() != vertex_count || weights.weight.rows() != vertex_count) {
    return invalid_argument_error("skin weights have " + std::to_string(weights.segment.rows()) + " segment rows and " +
                                  std::to_string(weights.weight.rows()) + " weight rows but the mesh has " +
                                  std::to_string(vertex_count) + " vertices; compute the weights on this mesh");
  }
  if (vertex_count == 0) return ok_status();
  if (weights.influences < 1 || weights.segment.cols() != weights.influences ||
      weights.weight.cols() != weights.influences) {
    return invalid_argument_error("skin weights must have `influences` >= 1 columns in both arrays (influences " +
                                  std::to_string(weights.influences) + ", segment columns " +
                                  std::to_string(weights.segment.cols()) + ", weight columns " +
                                  std::to_string(weights.weight.cols()) + ")");
  }
  for (int64_t v = 0; v < vertex_count; ++v) {
    for (int c = 0; c < weights.influences; ++c) {
      const int32_t segment = weights.segment(v, c);
      const float value = weights.weight(v, c);
      const std::string where = "vertex " + std::to_string(v) + " slot " + std::to_string(c);
      if (segment < -1 || segment >= weights.segment_count) {
        return invalid_argument_error(where + " names segment " + std::to_string(segment) + ", outside -1.." +
                                      std::to_string(weights.segment_count - 1));
      }
      if (!std::isfinite(value) || value < 0.0f || value > 1.001f) {
        return invalid_argument_error(where + " has weight " + number_text(value) + "; weights must lie in [0, 1]");
      }
      if (segment == -1 && value > 0.0f) {
        return invalid_argument_error(where + " has weight " + number_text(value) + " on the unused segment -1");
      }
      for (int d = 0; d < c && segment >= 0; ++d) {
        if (weights.segment(v, d) == segment) {
          return invalid_argument_error(where + " repeats segment " + std::to_string(segment) +
                                        "; each segment may appear once per vertex");
        }
      }
    }
  }
  return ok_status();
}

Status validate_all(const TetMesh& mesh, const SkinWeights& weights, const CorParams& params) {
  POSEWARP_RETURN_IF_ERROR(validate(params));
  return validate_inputs(mesh, weights);
}

void fill_stats(const std::vector<uint8_t>& state, int64_t clusters, int64_t pair_buckets,
                std::chrono::steady_clock::time_point start, CorStats* stats) {
  if (stats == nullptr) return;
  *stats = CorStats{};
  for (const uint8_t s : state) {
    if (s == kRigid) ++stats->rigid_vertices;
    if (s == kCentred) ++stats->centred_vertices;
    if (s == kUnsupported) ++stats->unsupported_vertices;
  }
  stats->clusters = clusters;
  stats->pair_buckets = pair_buckets;
  stats->seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
}

// Marks each vertex kBlended or kRigid (eq. 7 is not needed where one segment dominates) and numbers the bone pairs
// the blended ones use.
PairIndex classify_vertices(const SkinWeights& weights, const CorParams& params, std::vector<uint8_t>* state) {
  const int64_t vertex_count = weights.vertex_count();
  state->assign(static_cast<size_t>(vertex_count), kRigid);
  PairIndex pairs(std::max(1, weights.segment_count));
  std::vector<SegmentWeight> support;
  for (int64_t v = 0; v < vertex_count; ++v) {
    vertex_support(weights, v, &support);
    if (rigid_by_weights(support, params.rigid_threshold)) continue;
    (*state)[static_cast<size_t>(v)] = kBlended;
    for (size_t a = 0; a < support.size(); ++a) {
      for (size_t b = a + 1; b < support.size(); ++b) {
        pairs.mark(std::min(support[a].segment, support[b].segment), std::max(support[a].segment, support[b].segment));
      }
    }
  }
  pairs.finish();
  return pairs;
}

// Every tet in each used pair of its support, as (weight-grid cell << 32 | tet); bucket b owns
// entries [offset[b], offset[b + 1]), sorted by cell, then tet.
struct TetBuckets {
  std::vector<int64_t> offset;
  std::vector<uint64_t> entries;
  double total_volume = 0.0;  // mm^3
};

TetBuckets bucket_tets(const TetMesh& mesh, const SkinWeights& weights, const PairIndex& pairs,
                       const Eigen::Vector3d& origin, int quantization) {
  const int64_t tet_count = mesh.tet_count();
  const int64_t bucket_count = pairs.size();
  auto for_tet_pairs = [&](int64_t t, std::vector<SegmentWeight>* support, auto&& visit) {
    tet_support(mesh, weights, t, support);
    for (size_t a = 0; a < support->size(); ++a) {
      for (size_t b = a + 1; b < support->size(); ++b) {
        const int32_t bucket = pairs.find((*support)[a].segment, (*support)[b].segment);
        if (bucket >= 0) visit(bucket, (*support)[a].weight, (*support)[b].weight);
      }
    }
  };

  // Count per (chunk, bucket); chunks of fixed size and prefix sums in chunk order put each bucket's entries in tet
  // order whatever the thread count.
  const int64_t tet_chunks = (tet_count + kTetChunk - 1) / kTetChunk;
  std::vector<int64_t> chunk_counts(static_cast<size_t>(tet_chunks * bucket_count), 0);
  std::vector<double> chunk_volume(static_cast<size_t>(tet_chunks), 0.0);
  parallel_for(0, tet_chunks, 1, [&](int64_t chunk_begin, int64_t chunk_end) {
    std::vector<SegmentWeight> support;
    for (int64_t chunk = chunk_begin; chunk < chunk_end; ++chunk) {
      int64_t* counts = chunk_counts.data() + chunk * bucket_count;
      double volume = 0.0;
      for (int64_t t = chunk * kTetChunk; t < std::min(tet_count, (chunk + 1) * kTetChunk); ++t) {
        volume += tet_geometry(mesh, t, origin).volume;
        for_tet_pairs(t, &support, [&](int32_t bucket, double, double) { ++counts[bucket]; });
      }
      chunk_volume[static_cast<size_t>(chunk)] = volume;
    }
  });

  TetBuckets buckets;
  for (const double volume : chunk_volume) buckets.total_volume += volume;
  buckets.offset.assign(static_cast<size_t>(bucket_count + 1), 0);
  std::vector<int64_t> write_at(chunk_counts.size(), 0);
  for (int64_t b = 0; b < bucket_count; ++b) {
    int64_t at = buckets.offset[static_cast<size_t>(b)];
    for (int64_t chunk = 0; chunk < tet_chunks; ++chunk) {
      write_at[static_cast<size_t>(chunk * bucket_count + b)] = at;
      at += chunk_counts[static_cast<size_t>(chunk * bucket_count + b)];
    }
    buckets.offset[static_cast<size_t>(b + 1)] = at;
  }
  std::vector<int64_t>().swap(chunk_counts);

  buckets.entries.resize(static_cast<size_t>(buckets.offset.back()));
  auto cell_of = [quantization](double w) {
    return static_cast<uint64_t>(std::clamp<long>(std::lround(w * quantization), 0L, static_cast<long>(quantization)));
  };
  parallel_for(0, tet_chunks, 1, [&](int64_t chunk_begin, int64_t chunk_end) {
    std::vector<SegmentWeight> support;
    for (int64_t chunk = chunk_begin; chunk < chunk_end; ++chunk) {
      int64_t* at = write_at.data() + chunk * bucket_count;
      for (int64_t t = chunk * kTetChunk; t < std::min(tet_count, (chunk + 1) * kTetChunk); ++t) {
        for_tet_pairs(t, &support, [&](int32_t bucket, double wi, double wj) {
          const uint64_t cell = cell_of(wi) * static_cast<uint64_t>(quantization + 1) + cell_of(wj);
          buckets.entries[static_cast<size_t>(at[bucket]++)] = (cell << 32) | static_cast<uint64_t>(t);
        });
      }
    }
  });
  parallel_for(0, bucket_count, 1, [&](int64_t b_begin, int64_t b_end) {
    for (int64_t b = b_begin; b < b_end; ++b) {
      std::sort(buckets.entries.begin() + buckets.offset[static_cast<size_t>(b)],
                buckets.entries.begin() + buckets.offset[static_cast<size_t>(b + 1)]);
    }
  });
  return buckets;
}

// One cluster per distinct cell of each bucket: its mass, moment and representative weights.
PairClusters cluster_tets(const TetMesh& mesh, const SkinWeights& weights, const PairIndex& pairs,
                          const Eigen::Vector3d& origin, int quantization, const TetBuckets& buckets) {
  const int64_t bucket_count = pairs.size();
  auto cell = [&](int64_t e) { return buckets.entries[static_cast<size_t>(e)] >> 32; };
  auto starts_cluster = [&](int64_t b, int64_t e) {
    return e == buckets.offset[static_cast<size_t>(b)] || cell(e) != cell(e - 1);
  };

  PairClusters clusters;
  clusters.offset.assign(static_cast<size_t>(bucket_count + 1), 0);
  for (int64_t b = 0; b < bucket_count; ++b) {
    int64_t count = 0;
    for (int64_t e = buckets.offset[static_cast<size_t>(b)]; e < buckets.offset[static_cast<size_t>(b + 1)]; ++e) {
      if (starts_cluster(b, e)) ++count;
    }
    clusters.offset[static_cast<size_t>(b + 1)] = clusters.offset[static_cast<size_t>(b)] + count;
  }
  const size_t cluster_total = static_cast<size_t>(clusters.offset.back());
  for (std::vector<double>* column :
       {&clusters.x, &clusters.y, &clusters.mass, &clusters.moment_x, &clusters.moment_y, &clusters.moment_z}) {
    column->assign(cluster_total, 0.0);
  }

  parallel_for(0, bucket_count, 1, [&](int64_t b_begin, int64_t b_end) {
    std::vector<SegmentWeight> support;
    for (int64_t b = b_begin; b < b_end; ++b) {
      const auto [segment_i, segment_j] = pairs.segments(static_cast<int32_t>(b));
      size_t k = static_cast<size_t>(clusters.offset[static_cast<size_t>(b)]);
      double wx = 0.0, wy = 0.0;  // sums of mass * w_ti and mass * w_tj over the cluster
      for (int64_t e = buckets.offset[static_cast<size_t>(b)]; e < buckets.offset[static_cast<size_t>(b + 1)]; ++e) {
        const int64_t t = static_cast<int64_t>(buckets.entries[static_cast<size_t>(e)] & 0xffffffffu);
        const TetGeometry geometry = tet_geometry(mesh, t, origin);
        tet_support(mesh, weights, t, &support);
        const double wi = weight_of(support, segment_i), wj = weight_of(support, segment_j);
        const double mass = geometry.volume * wi * wj;
        clusters.mass[k] += mass;
        clusters.moment_x[k] += mass * geometry.centroid.x();
        clusters.moment_y[k] += mass * geometry.centroid.y();
        clusters.moment_z[k] += mass * geometry.centroid.z();
        wx += mass * wi;
        wy += mass * wj;
        if (e + 1 == buckets.offset[static_cast<size_t>(b + 1)] || starts_cluster(b, e + 1)) {
          // Close the cluster: mass-weighted mean weights, or the cell centre for degenerate (zero-volume) tets.
          const uint64_t c = cell(e);
          const bool massive = clusters.mass[k] > 0.0;
          clusters.x[k] = massive ? wx / clusters.mass[k]
                                  : static_cast<double>(c / static_cast<uint64_t>(quantization + 1)) / quantization;
          clusters.y[k] = massive ? wy / clusters.mass[k]
                                  : static_cast<double>(c % static_cast<uint64_t>(quantization + 1)) / quantization;
          ++k;
          wx = wy = 0.0;
        }
      }
    }
  });
  return clusters;
}

Result<RotationCentres> compute_clustered(const TetMesh& mesh, const SkinWeights& weights, const CorParams& params,
                                          const ProgressHooks& hooks, CorStats* stats) {
  const auto start = std::chrono::steady_clock::now();
  StageProgress progress(hooks, "cor");
  const int64_t vertex_count = mesh.vertex_count();
  const Eigen::Vector3d origin = bounding_box_centre(mesh);

  std::vector<uint8_t> state;
  const PairIndex pairs = classify_vertices(weights, params, &state);
  POSEWARP_RETURN_IF_ERROR(progress.check_cancel());
  double total_volume = 0.0;
  PairClusters clusters;
  {
    const TetBuckets buckets = bucket_tets(mesh, weights, pairs, origin, params.quantization);
    POSEWARP_RETURN_IF_ERROR(progress.check_cancel());
    total_volume = buckets.total_volume;
    clusters = cluster_tets(mesh, weights, pairs, origin, params.quantization, buckets);
  }
  POSEWARP_RETURN_IF_ERROR(progress.check_cancel());
  progress.update(kClusterShare);

  // Eq. 7 per blended vertex: for each pair (i, j) of its support, the (i, j) and (j, i) terms of eq. 6 against
  // every cluster of that pair's bucket. Pairs outside the vertex's support contribute 0 to s, so this is s once.
  RotationCentres out;
  out.centre = mesh.vertices;
  out.rigid.assign(static_cast<size_t>(vertex_count), 1);
  const double inv_sigma2 = 1.0 / (params.sigma * params.sigma);
  const double unsupported_below = kUnsupportedFraction * total_volume;
  const int64_t vertex_chunks = (vertex_count + kVertexChunk - 1) / kVertexChunk;
  std::atomic<bool> cancelled{false};
  std::atomic<int64_t> chunks_done{0};
  parallel_for(0, vertex_chunks, 1, [&](int64_t chunk_begin, int64_t chunk_end) {
    std::vector<SegmentWeight> support;
    for (int64_t chunk = chunk_begin; chunk < chunk_end; ++chunk) {
      if (cancelled.load() || progress.cancel_requested()) {
        cancelled.store(true);
        return;
      }
      for (int64_t v = chunk * kVertexChunk; v < std::min(vertex_count, (chunk + 1) * kVertexChunk); ++v) {
        if (state[static_cast<size_t>(v)] != kBlended) continue;
        vertex_support(weights, v, &support);
        double denominator = 0.0;
        Eigen::Vector3d numerator = Eigen::Vector3d::Zero();
        for (size_t a = 0; a < support.size(); ++a) {
          for (size_t b = a + 1; b < support.size(); ++b) {
            SegmentWeight lo = support[a], hi = support[b];
            if (lo.segment > hi.segment) std::swap(lo, hi);
            const int32_t bucket = pairs.find(lo.segment, hi.segment);
            if (bucket < 0) continue;
            double den = 0.0, nx = 0.0, ny = 0.0, nz = 0.0;
            const size_t k_end = static_cast<size_t>(clusters.offset[static_cast<size_t>(bucket) + 1]);
            for (size_t k = static_cast<size_t>(clusters.offset[static_cast<size_t>(bucket)]); k < k_end; ++k) {
              const double d = lo.weight * clusters.y[k] - clusters.x[k] * hi.weight;
              const double kernel = std::exp(-d * d * inv_sigma2);
              den += kernel * clusters.mass[k];
              nx += kernel * clusters.moment_x[k];
              ny += kernel * clusters.moment_y[k];
              nz += kernel * clusters.moment_z[k];
            }
            const double pair_weight = 2.0 * lo.weight * hi.weight;  // ordered pairs (i, j) and (j, i)
            denominator += pair_weight * den;
            numerator += pair_weight * Eigen::Vector3d(nx, ny, nz);
          }
        }
        state[static_cast<size_t>(v)] = finish_vertex(mesh, v, denominator, numerator, unsupported_below, origin, &out);
      }
      const int64_t done = chunks_done.fetch_add(1) + 1;
      progress.update(kClusterShare + (1.0 - kClusterShare) * static_cast<double>(done) / vertex_chunks);
    }
  });
  if (cancelled.load()) {
    const Status status = progress.check_cancel();
    return status.ok() ? cancelled_error("cancelled during stage 'cor' at the caller's request") : status;
  }
  fill_stats(state, static_cast<int64_t>(clusters.x.size()), pairs.size(), start, stats);
  progress.finish();
  return out;
}

Result<RotationCentres> compute_brute_force(const TetMesh& mesh, const SkinWeights& weights, const CorParams& params) {
  const int64_t vertex_count = mesh.vertex_count();
  const int64_t tet_count = mesh.tet_count();
  const Eigen::Vector3d origin = bounding_box_centre(mesh);

  std::vector<TetGeometry> geometry;
  std::vector<int64_t> support_offset(static_cast<size_t>(tet_count + 1), 0);
  std::vector<SegmentWeight> support_all, support;
  geometry.reserve(static_cast<size_t>(tet_count));
  double total_volume = 0.0;
  for (int64_t t = 0; t < tet_count; ++t) {
    geometry.push_back(tet_geometry(mesh, t, origin));
    total_volume += geometry.back().volume;
    tet_support(mesh, weights, t, &support);
    support_all.insert(support_all.end(), support.begin(), support.end());
    support_offset[static_cast<size_t>(t + 1)] = static_cast<int64_t>(support_all.size());
  }

  RotationCentres out;
  out.centre = mesh.vertices;
  out.rigid.assign(static_cast<size_t>(vertex_count), 1);
  const double inv_sigma2 = 1.0 / (params.sigma * params.sigma);
  const double unsupported_below = kUnsupportedFraction * total_volume;
  parallel_for(0, vertex_count, 16, [&](int64_t v_begin, int64_t v_end) {
    std::vector<SegmentWeight> wp;
    std::vector<double> wt;
    for (int64_t v = v_begin; v < v_end; ++v) {
      vertex_support(weights, v, &wp);
      if (rigid_by_weights(wp, params.rigid_threshold)) continue;
      wt.assign(wp.size(), 0.0);
      double denominator = 0.0;
      Eigen::Vector3d numerator = Eigen::Vector3d::Zero();
      for (int64_t t = 0; t < tet_count; ++t) {
        for (size_t a = 0; a < wp.size(); ++a) {
          wt[a] = 0.0;
          for (int64_t e = support_offset[static_cast<size_t>(t)]; e < support_offset[static_cast<size_t>(t + 1)];
               ++e) {
            if (support_all[static_cast<size_t>(e)].segment == wp[a].segment)
              wt[a] = support_all[static_cast<size_t>(e)].weight;
          }
        }
        double s = 0.0;  // eq. 6 over ordered pairs i != j
        for (size_t i = 0; i < wp.size(); ++i) {
          for (size_t j = 0; j < wp.size(); ++j) {
            if (i == j) continue;
            const double d = wp[i].weight * wt[j] - wt[i] * wp[j].weight;
            s += wp[i].weight * wp[j].weight * wt[i] * wt[j] * std::exp(-d * d * inv_sigma2);
          }
        }
        const TetGeometry& g = geometry[static_cast<size_t>(t)];
        denominator += s * g.volume;
        numerator += s * g.volume * g.centroid;
      }
      finish_vertex(mesh, v, denominator, numerator, unsupported_below, origin, &out);
    }
  });
  return out;
}

// What the exception wall says the centres were being computed for.
std::string computing_centres(const TetMesh& mesh) {
  return "computing centres of rotation for " + std::to_string(mesh.vertex_count()) + " vertices and " +
         std::to_string(mesh.tet_count()) + " tets";
}
constexpr std::string_view kCentresAdvice = "free memory or mesh the body more coarsely";

}  // namespace

Status validate(const CorParams& params) {
  if (!(params.sigma > 0.0 && params.sigma <= 1.0)) {
    return invalid_argument_error("cor sigma must be in (0, 1], got " + number_text(params.sigma) +
                                  "; Sujar et al. use a value below 0.1, the default is 0.1");
  }
  if (!(params.rigid_threshold > 0.5 && params.rigid_threshold <= 1.0)) {
    return invalid_argument_error("cor rigid_threshold must be in (0.5, 1], got " +
                                  number_text(params.rigid_threshold) +
                                  "; use the default 0.999, or 1 to give every blended vertex a centre");
  }
  if (params.quantization < 4 || params.quantization > 4096) {
    return invalid_argument_error("cor quantization must be in 4..4096 grid steps per unit weight, got " +
                                  std::to_string(params.quantization) + "; the default is 64");
  }
  return ok_status();
}

Result<RotationCentres> rotation_centres(const TetMesh& mesh, const SkinWeights& weights, const CorParams& params,
                                         const ProgressHooks& hooks, CorStats* stats) {
  POSEWARP_RETURN_IF_ERROR(validate_all(mesh, weights, params));
  return guarded(computing_centres(mesh), kCentresAdvice, [&] { return compute_clustered(mesh, weights, params, hooks, stats); });
}

Result<RotationCentres> rotation_centres_brute_force(const TetMesh& mesh, const SkinWeights& weights,
                                                     const CorParams& params) {
  POSEWARP_RETURN_IF_ERROR(validate_all(mesh, weights, params));
  return guarded(computing_centres(mesh), kCentresAdvice, [&] { return compute_brute_force(mesh, weights, params); });
}

}  // namespace posewarp::cor
