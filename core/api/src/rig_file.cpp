// Rig artifact writer and reader: sectioned, checksummed, little-endian binary.
#include "posewarp/api/rig_file.h"
#include "posewarp/common/atomic_file.h"
#include "posewarp/common/exception_wall.h"
#include "posewarp/common/input_file.h"
#include "posewarp/common/json.h"
#include "posewarp/common/parallel.h"
#include "posewarp/labels/label_map.h"
#include "posewarp/mapping/tet_locator.h"
#include "posewarp/rig/skeleton.h"
#include "posewarp/surface/surface_mesh.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstdio>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <map>

#include "table_sections.h"
#include "volume_sections.h"
#include "rig_json.h"

namespace posewarp::api {
namespace {

namespace fs = std::filesystem;

constexpr char kMagic[8] = {'P', 'O', 'S', 'E', 'W', 'A', 'R', 'P'};

constexpr uint32_t tag(const char (&name)[5]) {
  return static_cast<uint32_t>(static_cast<unsigned char>(name[0])) |
         static_cast<uint32_t>(static_cast<unsigned char>(name[1])) << 8 |
         static_cast<uint32_t>(static_cast<unsigned char>(name[2])) << 16 |
         static_cast<uint32_t>(static_cast<unsigned char>(name[3])) << 24;
}

constexpr uint32_t kGeometry = tag("GEOM");
constexpr uint32_t kLabelMap = tag("LMAP");
constexpr uint32_t kSkeleton = tag("SKEL");
constexpr uint32_t kParams = tag("PARM");
constexpr uint32_t kVertices = tag("VERT");
constexpr uint32_t kTets = tag("TETS");
constexpr uint32_t kTetClass = tag("TCLS");
constexpr uint32_t kWeights = tag("WGHT");
constexpr uint32_t kCentres = tag("CORS");
constexpr uint32_t kProvenance = tag("PROV");
constexpr uint32_t kLabelVolume = tag("LVOL");
constexpr uint32_t kSurfaces = tag("SURF");
constexpr uint32_t kCtVolume = tag("CTVO");
constexpr uint32_t kRestOwner = tag("OWNR");
constexpr uint32_t kBodyRegion = tag("REGN");
constexpr uint32_t kBoneSubstitute = tag("SUBS");
constexpr uint32_t kSkinVertices = tag("SKIN");
constexpr uint32_t kEngineSummary = tag("ENGN");
constexpr uint32_t kEnd = tag("END!");

// Sections holding a volume's worth of values: read after the checks that bound their sizes.
bool is_bulk(uint32_t t) {
  return t == kLabelVolume || t == kCtVolume || t == kRestOwner || t == kBodyRegion || t == kBoneSubstitute;
}

// The sections this version reads into the rig's members (any other is kept as it is).
bool is_known(uint32_t t) {
  for (const uint32_t known : {kGeometry, kLabelMap, kSkeleton, kParams, kVertices, kTets, kTetClass, kWeights,
                               kCentres, kProvenance, kSurfaces, kSkinVertices, kEngineSummary}) {
    if (t == known) return true;
  }
  return is_bulk(t);
}

uint64_t checksum(std::string_view payload) {
  return std::stoull(hash_bytes(payload.data(), payload.size()), nullptr, 16);
}

// A 64-bit hash as the rig file writes it in hex (hash_bytes, the content hash).
std::string hex64(uint64_t value) {
  char hex[17];
  std::snprintf(hex, sizeof(hex), "%016llx", static_cast<unsigned long long>(value));
  return hex;
}

std::string tag_name(uint32_t t) {
  std::string name(4, ' ');
  for (int i = 0; i < 4; ++i) name[static_cast<size_t>(i)] = static_cast<char>((t >> (8 * i)) & 0xff);
  return name;
}

// Appends plain-old-data to a payload.
class Writer {
 public:
  template <typename T>
  void put(const T& value) {
    const auto* p = reinterpret_cast<const char*>(&value);
    bytes_.append(p, sizeof(T));
  }
  void put_bytes(const void* data, size_t size) { bytes_.append(static_cast<const char*>(data), size); }
  void put_string(const std::string& s) {
    put<uint64_t>(s.size());
    bytes_.append(s);
  }
  std::string take() { return std::move(bytes_); }

 private:
  std::string bytes_;
};

class Reader {
 public:
  Reader(std::string_view bytes, std::string section) : bytes_(bytes), section_(std::move(section)) {}
  template <typename T>
  Status get(T& value) {
    return get_bytes(&value, sizeof(T));
  }
  Status get_bytes(void* out, size_t size) {
    if (offset_ + size > bytes_.size()) {
      return data_loss_error("rig section " + section_ + " ends early; the file is damaged");
    }
    if (size == 0) return ok_status();  // an empty array has no storage: memcpy(nullptr, ..., 0) is undefined
    std::memcpy(out, bytes_.data() + offset_, size);
    offset_ += size;
    return ok_status();
  }
  Status get_string(std::string& s) {
    std::string_view view;
    POSEWARP_RETURN_IF_ERROR(get_view(view));
    s.assign(view);
    return ok_status();
  }
  // A string's bytes where they lie in the payload.
  Status get_view(std::string_view& s) {
    uint64_t size = 0;
    POSEWARP_RETURN_IF_ERROR(get(size));
    if (size > bytes_.size() - offset_) return data_loss_error("rig section " + section_ + " has a bad string length");
    s = bytes_.substr(offset_, size);
    offset_ += size;
    return ok_status();
  }
  // Reads rows x cols elements into an Eigen matrix of the given scalar type.
  template <typename Matrix>
  Status get_matrix(Matrix& m) {
    uint64_t rows = 0, cols = 0;
    POSEWARP_RETURN_IF_ERROR(get(rows));
    POSEWARP_RETURN_IF_ERROR(get(cols));
    // rows * cols * size can overflow for crafted counts: bound each factor by what is left before multiplying.
    // A matrix with a fixed column count takes exactly that many: Eigen would size the storage by its own count
    // and the read by the file's (a heap overflow found by fuzzing).
    if (Matrix::ColsAtCompileTime != Eigen::Dynamic && cols != static_cast<uint64_t>(Matrix::ColsAtCompileTime)) {
      return data_loss_error("rig section " + section_ + " declares an array of " + std::to_string(cols) +
                             " columns where " + std::to_string(Matrix::ColsAtCompileTime) + " belong");
    }
    const uint64_t left = bytes_.size() - offset_;
    const uint64_t element = sizeof(typename Matrix::Scalar);
    const bool fits = cols <= 64 && (cols == 0 || rows <= left / element / cols);
    const uint64_t bytes = fits ? rows * cols * element : 0;
    if (!fits || bytes > left) {
      return data_loss_error("rig section " + section_ + " declares a " + std::to_string(rows) + " x " +
                             std::to_string(cols) + " array larger than the section");
    }
    m.resize(static_cast<Eigen::Index>(rows), static_cast<Eigen::Index>(cols));
    return get_bytes(m.data(), bytes);
  }

 private:
  std::string_view bytes_;
  std::string section_;
  size_t offset_ = 0;
};

template <typename Matrix>
void put_matrix(Writer& w, const Matrix& m) {
  w.put<uint64_t>(static_cast<uint64_t>(m.rows()));
  w.put<uint64_t>(static_cast<uint64_t>(m.cols()));
  w.put_bytes(m.data(), static_cast<size_t>(m.size()) * sizeof(typename Matrix::Scalar));
}

// The sections of a rig in file order; provenance last (it is not part of the content hash).
std::vector<std::pair<uint32_t, std::string>> sections_of(const Rig& rig) {
  std::vector<std::pair<uint32_t, std::string>> sections;
  {
    Writer w;
    const ImageGeometry& g = rig.source_geometry;
    for (int a = 0; a < 3; ++a) w.put<int64_t>(g.size[static_cast<size_t>(a)]);
    for (int a = 0; a < 3; ++a) w.put<double>(g.spacing[static_cast<size_t>(a)]);
    for (int a = 0; a < 3; ++a) w.put<double>(g.origin[static_cast<size_t>(a)]);
    for (int e = 0; e < 9; ++e) w.put<double>(g.direction[static_cast<size_t>(e)]);
    w.put_string(rig.labels_hash);
    w.put_string(rig.ct_hash);
    sections.emplace_back(kGeometry, w.take());
  }
  sections.emplace_back(kLabelMap, labels::label_map_to_json(rig.label_map));
  sections.emplace_back(kSkeleton, detail::skeleton_to_json(rig.skeleton));
  sections.emplace_back(kParams, rig.params_json);
  {
    // Row-major copies so the file layout does not depend on Eigen's storage order.
    Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> vertices = rig.mesh.vertices;
    Writer w;
    w.put<int32_t>(rig.mesh.segment_count);
    put_matrix(w, vertices);
    sections.emplace_back(kVertices, w.take());
  }
  {
    Eigen::Matrix<int32_t, Eigen::Dynamic, 4, Eigen::RowMajor> tets = rig.mesh.tets;
    Writer w;
    put_matrix(w, tets);
    sections.emplace_back(kTets, w.take());
  }
  {
    Eigen::Matrix<int32_t, Eigen::Dynamic, 1> classes = rig.mesh.tet_class;
    Writer w;
    put_matrix(w, classes);
    sections.emplace_back(kTetClass, w.take());
  }
  {
    Writer w;
    w.put<int32_t>(rig.weights.influences);
    w.put<int32_t>(rig.weights.segment_count);
    put_matrix(w, rig.weights.segment);
    put_matrix(w, rig.weights.weight);
    sections.emplace_back(kWeights, w.take());
  }
  {
    Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> centres = rig.centres.centre;
    Writer w;
    put_matrix(w, centres);
    w.put<uint64_t>(rig.centres.rigid.size());
    w.put_bytes(rig.centres.rigid.data(), rig.centres.rigid.size());
    sections.emplace_back(kCentres, w.take());
  }
  if (!rig.surfaces.empty()) {
    Writer w;
    w.put<uint64_t>(rig.surfaces.size());
    for (size_t i = 0; i < rig.surfaces.size(); ++i) {
      const surface::SurfaceMesh& m = rig.surfaces[i];
      w.put_string(m.name);
      w.put<int32_t>(m.label);
      Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> vertices = m.vertices;
      Eigen::Matrix<int32_t, Eigen::Dynamic, 3, Eigen::RowMajor> triangles = m.triangles;
      put_matrix(w, vertices);
      put_matrix(w, triangles);
      const mapping::Embedding& e = rig.embeddings[i];
      Eigen::Matrix<int32_t, Eigen::Dynamic, 1> tet = e.tet;
      Eigen::Matrix<double, Eigen::Dynamic, 4, Eigen::RowMajor> bary = e.barycentric;
      put_matrix(w, tet);
      put_matrix(w, bary);
    }
    sections.emplace_back(kSurfaces, w.take());
  }
  if (!rig.labels.empty()) sections.emplace_back(kLabelVolume, internal::volume_section(rig.labels));
  if (rig.ct) sections.emplace_back(kCtVolume, internal::intensity_section(*rig.ct));
  if (!rig.rest_owner.empty()) sections.emplace_back(kRestOwner, internal::owner_section(rig.rest_owner));
  if (!rig.body_region.empty()) sections.emplace_back(kBodyRegion, internal::region_section(rig.body_region));
  if (rig.bone_substitute) {
    sections.emplace_back(kBoneSubstitute,
                          internal::substitute_section(*rig.bone_substitute, rig.labels.voxel_count()));
  }
  if (!rig.skin_vertex.empty()) {
    std::string packed((rig.skin_vertex.size() + 7) / 8, '\0');  // a bit per vertex
    for (size_t v = 0; v < rig.skin_vertex.size(); ++v) {
      if (rig.skin_vertex[v]) packed[v / 8] = static_cast<char>(packed[v / 8] | (1 << (v % 8)));
    }
    Writer w;
    w.put<uint64_t>(rig.skin_vertex.size());
    w.put_string(packed);
    sections.emplace_back(kSkinVertices, w.take());
  }
  if (!rig.tet_region.empty()) sections.emplace_back(kEngineSummary, internal::summary_section(rig));
  for (const auto& unknown : rig.unknown_sections) sections.push_back(unknown);
  {
    nlohmann::json prov;
    prov["software_version"] = rig.provenance.software_version;
    prov["labels_source"] = rig.provenance.labels_source;
    prov["ct_source"] = rig.provenance.ct_source;
    nlohmann::json stages = nlohmann::json::array();
    for (const auto& [stage, seconds] : rig.provenance.stage_seconds) stages.push_back({stage, seconds});
    prov["stage_seconds"] = stages;
    prov["stats"] = rig.provenance.stats_json.empty() ? nlohmann::json::object()
                                                      : nlohmann::json::parse(rig.provenance.stats_json);
    sections.emplace_back(kProvenance, prov.dump());
  }
  return sections;
}

std::string hash_of_sections(const std::vector<std::pair<uint32_t, std::string>>& sections) {
  std::string digest;
  for (const auto& [t, payload] : sections) {
    if (t == kProvenance) continue;
    digest += tag_name(t) + hash_bytes(payload.data(), payload.size());
  }
  return hash_bytes(digest.data(), digest.size());
}

// Reads the GEOM section: the source grid and the hashes of the label and CT volumes it came from.
Status read_geometry_section(std::string_view payload, const std::string& name, Rig& rig) {
  Reader r(payload, name);
  ImageGeometry& g = rig.source_geometry;
  for (int a = 0; a < 3; ++a) POSEWARP_RETURN_IF_ERROR(r.get(g.size[static_cast<size_t>(a)]));
  for (int a = 0; a < 3; ++a) POSEWARP_RETURN_IF_ERROR(r.get(g.spacing[static_cast<size_t>(a)]));
  for (int a = 0; a < 3; ++a) POSEWARP_RETURN_IF_ERROR(r.get(g.origin[static_cast<size_t>(a)]));
  for (int e = 0; e < 9; ++e) POSEWARP_RETURN_IF_ERROR(r.get(g.direction[static_cast<size_t>(e)]));
  POSEWARP_RETURN_IF_ERROR(r.get_string(rig.labels_hash));
  return r.get_string(rig.ct_hash);
}

// Reads the CORS section: every vertex's centre of rotation and whether one segment moves it rigidly.
Status read_centres_section(std::string_view payload, const std::string& name, Rig& rig) {
  Reader r(payload, name);
  Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> centres;
  POSEWARP_RETURN_IF_ERROR(r.get_matrix(centres));
  rig.centres.centre = centres;
  uint64_t count = 0;
  POSEWARP_RETURN_IF_ERROR(r.get(count));
  if (count != static_cast<uint64_t>(centres.rows())) return data_loss_error("rig centres section is inconsistent");
  rig.centres.rigid.resize(count);
  return r.get_bytes(rig.centres.rigid.data(), count);
}

// Reads the SURF section: each rest surface with its embedding in the rest tets, appended to the rig.
Status read_surfaces_section(std::string_view payload, const std::string& name, Rig& rig) {
  Reader r(payload, name);
  uint64_t count = 0;
  POSEWARP_RETURN_IF_ERROR(r.get(count));
  if (count > 100000) return data_loss_error("rig surfaces section is damaged");
  for (uint64_t i = 0; i < count; ++i) {
    surface::SurfaceMesh m;
    POSEWARP_RETURN_IF_ERROR(r.get_string(m.name));
    POSEWARP_RETURN_IF_ERROR(r.get(m.label));
    Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor> vertices;
    Eigen::Matrix<int32_t, Eigen::Dynamic, 3, Eigen::RowMajor> triangles;
    POSEWARP_RETURN_IF_ERROR(r.get_matrix(vertices));
    POSEWARP_RETURN_IF_ERROR(r.get_matrix(triangles));
    m.vertices = vertices;
    m.triangles = triangles;
    mapping::Embedding e;
    Eigen::Matrix<int32_t, Eigen::Dynamic, 1> tet;
    Eigen::Matrix<double, Eigen::Dynamic, 4, Eigen::RowMajor> bary;
    POSEWARP_RETURN_IF_ERROR(r.get_matrix(tet));
    POSEWARP_RETURN_IF_ERROR(r.get_matrix(bary));
    if (tet.rows() != vertices.rows() || bary.rows() != vertices.rows()) {
      return data_loss_error("rig surface '" + m.name + "' and its embedding disagree");
    }
    e.tet = tet;
    e.barycentric = bary;
    e.inside.assign(static_cast<size_t>(tet.rows()), 1);
    rig.surfaces.push_back(std::move(m));
    rig.embeddings.push_back(std::move(e));
  }
  return ok_status();
}

// Reads the PROV section: software version, sources, stage timings and statistics, as JSON.
Status read_provenance_section(std::string_view payload, Rig& rig) {
  const Result<nlohmann::json> parsed = parse_json<nlohmann::json>(payload, "rig provenance section");
  if (!parsed.ok()) return data_loss_error(parsed.status().message());
  try {
    const nlohmann::json& prov = *parsed;
    rig.provenance.software_version = prov.value("software_version", "");
    rig.provenance.labels_source = prov.value("labels_source", "");
    rig.provenance.ct_source = prov.value("ct_source", "");
    for (const auto& stage : prov.value("stage_seconds", nlohmann::json::array())) {
      rig.provenance.stage_seconds.emplace_back(stage.at(0).get<std::string>(), stage.at(1).get<double>());
    }
    rig.provenance.stats_json = prov.value("stats", nlohmann::json::object()).dump();
  } catch (const nlohmann::json::exception& error) {
    return data_loss_error(std::string("rig provenance section is malformed: ") + error.what());
  }
  return ok_status();
}

// A matrix read in the file's layout (Stored, row-major) and kept, once whole, in the rig's (target).
template <typename Stored, typename Target>
Status read_matrix(Reader& r, Target& target) {
  Stored stored;
  POSEWARP_RETURN_IF_ERROR(r.get_matrix(stored));
  target = stored;
  return ok_status();
}

// The voxels of the rig's grid, -1 for a grid that is not one (GEOM is read unchecked: its sizes may overflow).
int64_t grid_voxels(const Rig& rig) {
  return rig.source_geometry.validate().ok() ? rig.source_geometry.voxel_count() : -1;
}

// A section holding a volume's worth of values: each writes its own member of the rig, so they parse in parallel.
Status parse_bulk_section(Rig& rig, uint32_t t, std::string_view payload, uint32_t format) {
  const std::string name = tag_name(t);
  if (t == kLabelVolume) return internal::read_volume_section(payload, name, format, rig.labels);
  if (t == kCtVolume) return internal::read_intensity_section(payload, name, format, *rig.ct);
  const int64_t voxels = grid_voxels(rig);  // GEOM was read before the bulk sections
  const Index3 grid = voxels >= 0 ? rig.source_geometry.size : Index3{0, 0, 0};
  if (t == kRestOwner) return internal::read_owner_section(payload, grid, rig.rest_owner);
  if (t == kBodyRegion) return internal::read_region_section(payload, grid, rig.body_region);
  return internal::read_substitute_section(payload, voxels, *rig.bone_substitute);
}

// Reads one section's payload into the rig; a section of an unknown tag is kept as it is.
Status parse_section(Rig& rig, uint32_t t, std::string_view payload) {
  const std::string name = tag_name(t);
  if (t == kGeometry) return read_geometry_section(payload, name, rig);
  if (t == kLabelMap) {
    Result<labels::LabelMap> map = labels::label_map_from_json(payload, "in the rig file");
    if (!map.ok()) return data_loss_error(map.status().message());
    rig.label_map = std::move(map).value();
    return ok_status();
  }
  if (t == kSkeleton) {
    POSEWARP_ASSIGN_OR_RETURN(rig.skeleton, detail::skeleton_from_json(std::string(payload)));
    return ok_status();
  }
  if (t == kParams) {
    rig.params_json = std::string(payload);
    return ok_status();
  }
  if (t == kSkinVertices) {
    Reader r(payload, name);
    uint64_t count = 0;
    std::string_view packed;
    POSEWARP_RETURN_IF_ERROR(r.get(count));
    POSEWARP_RETURN_IF_ERROR(r.get_view(packed));
    if (count > uint64_t{8} * packed.size() || packed.size() != (count + 7) / 8) {
      return data_loss_error("rig section " + name + " declares " + std::to_string(count) + " vertices for " +
                             std::to_string(packed.size()) + " bytes; the file is damaged");
    }
    rig.skin_vertex.resize(static_cast<size_t>(count));
    for (size_t v = 0; v < rig.skin_vertex.size(); ++v) {
      rig.skin_vertex[v] = static_cast<uint8_t>((static_cast<unsigned char>(packed[v / 8]) >> (v % 8)) & 1);
    }
    return ok_status();
  }
  if (t == kVertices) {
    Reader r(payload, name);
    POSEWARP_RETURN_IF_ERROR(r.get(rig.mesh.segment_count));
    return read_matrix<Eigen::Matrix<double, Eigen::Dynamic, 3, Eigen::RowMajor>>(r, rig.mesh.vertices);
  }
  if (t == kTets) {
    Reader r(payload, name);
    return read_matrix<Eigen::Matrix<int32_t, Eigen::Dynamic, 4, Eigen::RowMajor>>(r, rig.mesh.tets);
  }
  if (t == kTetClass) {
    Reader r(payload, name);
    return read_matrix<Eigen::Matrix<int32_t, Eigen::Dynamic, 1>>(r, rig.mesh.tet_class);
  }
  if (t == kWeights) {
    Reader r(payload, name);
    POSEWARP_RETURN_IF_ERROR(r.get(rig.weights.influences));
    POSEWARP_RETURN_IF_ERROR(r.get(rig.weights.segment_count));
    POSEWARP_RETURN_IF_ERROR(r.get_matrix(rig.weights.segment));
    return r.get_matrix(rig.weights.weight);
  }
  if (t == kCentres) return read_centres_section(payload, name, rig);
  if (t == kSurfaces) return read_surfaces_section(payload, name, rig);
  if (t == kProvenance) return read_provenance_section(payload, rig);
  if (t == kEngineSummary) return internal::read_summary_section(payload, rig);
  rig.unknown_sections.emplace_back(t, std::string(payload));
  return ok_status();
}

// Structural checks after loading: arrays agree with each other.
Status check_consistency(const Rig& rig) {
  const int64_t v = rig.mesh.vertex_count();
  if (rig.mesh.tets.rows() != rig.mesh.tet_class.rows()) return data_loss_error("rig mesh: tets and classes disagree");
  if (rig.weights.segment.rows() != v || rig.weights.weight.rows() != v ||
      rig.weights.segment.cols() != rig.weights.influences || rig.weights.weight.cols() != rig.weights.influences) {
    return data_loss_error("rig weights do not match the mesh's " + std::to_string(v) + " vertices");
  }
  if (rig.centres.centre.rows() != v) return data_loss_error("rig centres do not match the mesh's vertices");
  if (rig.mesh.tets.size() > 0 && (rig.mesh.tets.minCoeff() < 0 || rig.mesh.tets.maxCoeff() >= v)) {
    return data_loss_error("rig mesh refers to vertices that do not exist");
  }
  for (const mapping::Embedding& e : rig.embeddings) {
    if (e.tet.size() > 0 && (e.tet.minCoeff() < 0 || e.tet.maxCoeff() >= rig.mesh.tet_count())) {
      return data_loss_error("rig surface embedding refers to tets that do not exist");
    }
    if (!e.barycentric.allFinite()) return data_loss_error("rig surface embedding has NaN or infinite coordinates");
  }
  for (const surface::SurfaceMesh& m : rig.surfaces) {
    if (m.triangles.size() > 0 && (m.triangles.minCoeff() < 0 || m.triangles.maxCoeff() >= m.vertices.rows())) {
      return data_loss_error("rig surface '" + m.name + "' has triangles on vertices that do not exist");
    }
    if (!m.vertices.allFinite()) return data_loss_error("rig surface '" + m.name + "' has NaN or infinite vertices");
  }
  if (rig.labels.empty()) return data_loss_error("rig has no label volume (section LVOL is missing)");
  if (!rig.labels.geometry().same_grid(rig.source_geometry, 1e-6)) {
    return data_loss_error("rig label volume is not on the rig's source grid");
  }
  if (rig.ct && !rig.ct->geometry().same_grid(rig.source_geometry, 1e-6)) {
    return data_loss_error("rig CT volume is not on the rig's source grid");
  }
  if (static_cast<int>(rig.skeleton.segments.size()) != rig.mesh.segment_count) {
    return data_loss_error("rig skeleton and mesh disagree on the number of segments");
  }
  // Every index the posing code follows, against its range (a crafted section with valid checksums would otherwise
  // read out of bounds in skinning).
  const int segments = rig.mesh.segment_count;
  if (rig.mesh.tet_class.size() > 0 &&
      (rig.mesh.tet_class.minCoeff() < kSoftTissueClass || rig.mesh.tet_class.maxCoeff() >= kFirstBoneClass + segments)) {
    return data_loss_error("rig mesh has tets of a class that is neither soft tissue nor one of its " +
                           std::to_string(segments) + " bone segments");
  }
  if (rig.weights.segment_count != segments) return data_loss_error("rig weights name another number of segments");
  if (rig.weights.segment.size() > 0 &&
      (rig.weights.segment.minCoeff() < -1 || rig.weights.segment.maxCoeff() >= segments)) {
    return data_loss_error("rig weights name a segment that does not exist");
  }
  if (rig.weights.weight.size() > 0 && (!rig.weights.weight.allFinite() || rig.weights.weight.minCoeff() < 0.0f ||
                                        rig.weights.weight.maxCoeff() > 1.0f + 1e-4f)) {
    return data_loss_error("rig weights hold values outside [0, 1]");
  }
  if (!rig.mesh.vertices.allFinite()) return data_loss_error("rig mesh has NaN or infinite vertices");
  POSEWARP_RETURN_IF_ERROR(internal::check_engine_tables(rig));
  for (const rig::Joint& joint : rig.skeleton.joints) {
    if (!joint.centre_mm.allFinite() || !joint.frame.allFinite()) {
      return data_loss_error("rig joint '" + joint.name + "' has a NaN or infinite centre or frame");
    }
  }
  return ok_status();
}

}  // namespace

std::string hash_bytes(const void* data, size_t size, uint64_t seed) {
  // FNV-1a over 8-byte words, then the tail bytes; a final avalanche.
  uint64_t h = 0xcbf29ce484222325ULL ^ seed;
  const auto* bytes = static_cast<const unsigned char*>(data);
  size_t i = 0;
  for (; i + 8 <= size; i += 8) {
    uint64_t word;
    std::memcpy(&word, bytes + i, 8);
    h = (h ^ word) * 0x100000001b3ULL;
    h ^= h >> 29;
  }
  for (; i < size; ++i) h = (h ^ bytes[i]) * 0x100000001b3ULL;
  h ^= size;
  h = (h ^ (h >> 30)) * 0xbf58476d1ce4e5b9ULL;
  h = (h ^ (h >> 27)) * 0x94d049bb133111ebULL;
  h ^= h >> 31;
  return hex64(h);
}

std::string content_hash(const Rig& rig) { return hash_of_sections(sections_of(rig)); }

std::string rig_to_bytes(const Rig& rig) {
  const std::vector<std::pair<uint32_t, std::string>> sections = sections_of(rig);
  std::string file(kMagic, sizeof(kMagic));
  auto put32 = [&file](uint32_t value) { file.append(reinterpret_cast<const char*>(&value), 4); };
  auto put64 = [&file](uint64_t value) { file.append(reinterpret_cast<const char*>(&value), 8); };
  put32(kRigFormatVersion);
  put32(0);
  for (const auto& [t, payload] : sections) {
    put32(t);
    put32(0);
    put64(payload.size());
    put64(checksum(payload));
    file += payload;
  }
  put32(kEnd);
  put32(0);
  put64(0);
  put64(std::stoull(hash_of_sections(sections), nullptr, 16));
  return file;
}

Status save_rig(const Rig& rig, const std::string& path) {
  return guarded("writing rig file '" + path + "'",
                 [&] { return write_file_atomically(path, rig_to_bytes(rig), "rig file"); });
}

// A rig holds the source volumes: a 20M-voxel study is a few hundred MB; 8 GB is far beyond any.
constexpr int64_t kMaxRigBytes = int64_t{8} << 30;

Result<Rig> load_rig(const std::string& path) {
  std::string unused;
  return load_rig(path, unused);
}

Result<Rig> load_rig(const std::string& path, std::string& stored_content_hash) {
  POSEWARP_ASSIGN_OR_RETURN(const std::string file, read_text_input(path, "rig file", kMaxRigBytes));
  POSEWARP_ASSIGN_OR_RETURN(Rig rig, rig_from_bytes(file, "'" + path + "'"));
  // A rig that reads ends with its end marker (tag, flags, size 0, the hash where a section's checksum is).
  uint64_t hash = 0;
  std::memcpy(&hash, file.data() + file.size() - 8, 8);
  stored_content_hash = hex64(hash);
  return rig;
}

namespace {

Status section_damaged(const std::string& where, uint32_t t) {
  return data_loss_error(where + ": section " + tag_name(t) +
                         " fails its checksum; the file is damaged. Rebuild the rig");
}

}  // namespace

static Result<Rig> rig_from_bytes_unguarded(std::string_view file, const std::string& where) {
  if (file.size() < 16 || std::memcmp(file.data(), kMagic, sizeof(kMagic)) != 0) {
    return invalid_argument_error(where + " is not a posewarp rig file (build one with `posewarp rig build`)");
  }
  uint32_t version = 0;
  std::memcpy(&version, file.data() + 8, 4);
  if (version > kRigFormatVersion) {
    return failed_precondition_error(where + " was written by a newer posewarp (rig format " + std::to_string(version) +
                                     "; this one reads up to " + std::to_string(kRigFormatVersion) +
                                     "). Upgrade posewarp, or rebuild the rig with this version");
  }
  Rig rig;
  size_t offset = 16;
  bool ended = false;
  std::string digest;  // hash_of_sections's input, from the sections' checksums (the same hash of the same bytes)
  struct Bulk {
    uint32_t tag;
    std::string_view payload;
    uint64_t sum;
  };
  // GEOM (which the tables' sizes depend on) and sections of an unknown tag (kept in file order) are read in turn;
  // every other section is checked and parsed on every thread after the end marker, each into its own member of the
  // rig, the large ones (a volume's worth of values) after the checks that bound what they allocate.
  std::vector<Bulk> small, bulk;
  bool content_checked = true;
  while (offset < file.size()) {
    if (offset + 24 > file.size()) break;
    uint32_t t = 0;
    uint64_t size = 0, sum = 0;
    std::memcpy(&t, file.data() + offset, 4);
    std::memcpy(&size, file.data() + offset + 8, 8);
    std::memcpy(&sum, file.data() + offset + 16, 8);
    offset += 24;
    if (t == kEnd) {
      ended = true;
      content_checked = std::stoull(hash_bytes(digest.data(), digest.size()), nullptr, 16) == sum;
      break;
    }
    if (size > file.size() - offset) break;
    const std::string_view bytes = file.substr(offset, size);
    offset += size;
    if (t != kProvenance) {
      digest += tag_name(t) + hex64(sum);
    }
    if (t == kGeometry || !is_known(t)) {
      if (checksum(bytes) != sum) return section_damaged(where, t);
      Status parsed = parse_section(rig, t, bytes);
      if (!parsed.ok()) return parsed.with_context(where);
      continue;
    }
    std::vector<Bulk>& later = is_bulk(t) ? bulk : small;
    if (std::any_of(later.begin(), later.end(), [t](const Bulk& section) { return section.tag == t; })) {
      return data_loss_error(where + " holds section " + tag_name(t) + " twice; the file is damaged. Rebuild the rig");
    }
    later.push_back({t, bytes, sum});
  }
  // The tables hold one value per voxel of the grid GEOM names; that grid is the label volume's, whose section can
  // hold at most 1032 voxels per compressed byte: a grid beyond that is damage, refused before any table is made.
  auto has = [&bulk](uint32_t t) {
    return std::find_if(bulk.begin(), bulk.end(), [t](const Bulk& section) { return section.tag == t; });
  };
  const bool tables = has(kRestOwner) != bulk.end() || has(kBodyRegion) != bulk.end() ||
                      has(kBoneSubstitute) != bulk.end();
  Status bounded = ok_status();
  const int64_t voxels = grid_voxels(rig);
  if (tables && has(kLabelVolume) == bulk.end()) {
    bounded = data_loss_error(where + ": rig has no label volume (section LVOL is missing)");
  } else if (tables && (voxels < 0 || static_cast<uint64_t>(voxels) >
                                          (has(kLabelVolume)->payload.size() + 64) * 1032)) {  // 1-byte samples at best
    bounded = data_loss_error(where +
                              ": its grid has more voxels than its label volume can hold; the file is "
                              "damaged. Rebuild the rig");
  }
  // A damaged file is reported as before the sections were read in parallel: the first small section that fails,
  // then the content check, then the tables' bounds, then the first large section that fails.
  const bool read_bulk = content_checked && bounded.ok();
  if (read_bulk && has(kCtVolume) != bulk.end()) rig.ct.emplace();
  if (read_bulk && has(kBoneSubstitute) != bulk.end()) rig.bone_substitute.emplace();
  std::vector<Bulk> sections = small;
  if (read_bulk) sections.insert(sections.end(), bulk.begin(), bulk.end());
  std::vector<Status> parsed(sections.size(), ok_status());
  parallel_for(0, static_cast<int64_t>(sections.size()), 1, [&](int64_t begin, int64_t end) {
    for (int64_t b = begin; b < end; ++b) {
      const Bulk& section = sections[static_cast<size_t>(b)];
      parsed[static_cast<size_t>(b)] = checksum(section.payload) != section.sum ? section_damaged(where, section.tag)
                                       : is_bulk(section.tag)
                                           ? parse_bulk_section(rig, section.tag, section.payload, version)
                                           : parse_section(rig, section.tag, section.payload);
    }
  });
  for (size_t b = 0; b < small.size(); ++b) {
    if (!parsed[b].ok()) return parsed[b].with_context(where);
  }
  if (!content_checked)
    return data_loss_error(where + " fails its content check; the file is damaged. Rebuild the rig");
  if (!bounded.ok()) return bounded;
  for (size_t b = small.size(); b < parsed.size(); ++b) {
    if (!parsed[b].ok()) return parsed[b].with_context(where);
  }
  if (!ended) {
    return data_loss_error(where + " is truncated (" + std::to_string(file.size()) +
                           " bytes, no end marker); the write did not finish. Rebuild the rig");
  }
  if (offset != file.size()) {
    return data_loss_error(where + " has " + std::to_string(file.size() - offset) +
                           " bytes after its end marker (two rigs joined, or a damaged copy); copy the rig again");
  }
  Status consistent = check_consistency(rig);
  if (!consistent.ok()) return consistent.with_context(where);
  return rig;
}

Result<Rig> rig_from_bytes(std::string_view file, const std::string& where) {
  return guarded("reading " + where, [&] { return rig_from_bytes_unguarded(file, where); });
}

}  // namespace posewarp::api
