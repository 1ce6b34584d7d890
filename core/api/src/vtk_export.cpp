// VTK XML (inline base64 binary) writers for the rig's mesh and skeleton; no VTK library needed.
#include "posewarp/api/vtk_export.h"
#include "posewarp/common/atomic_file.h"
#include "posewarp/rig/skeleton.h"

#include <cstring>
#include <vector>


namespace posewarp::api {
namespace {

std::string base64(const std::string& bytes) {
  static constexpr char kTable[] = "ABCDEFGHIJKLMNOPQRSTUVWXYZabcdefghijklmnopqrstuvwxyz0123456789+/";
  std::string out;
  out.reserve((bytes.size() + 2) / 3 * 4);
  size_t i = 0;
  for (; i + 2 < bytes.size(); i += 3) {
    const uint32_t v = (static_cast<uint8_t>(bytes[i]) << 16) | (static_cast<uint8_t>(bytes[i + 1]) << 8) |
                       static_cast<uint8_t>(bytes[i + 2]);
    out += kTable[(v >> 18) & 63];
    out += kTable[(v >> 12) & 63];
    out += kTable[(v >> 6) & 63];
    out += kTable[v & 63];
  }
  if (i < bytes.size()) {
    uint32_t v = static_cast<uint8_t>(bytes[i]) << 16;
    if (i + 1 < bytes.size()) v |= static_cast<uint8_t>(bytes[i + 1]) << 8;
    out += kTable[(v >> 18) & 63];
    out += kTable[(v >> 12) & 63];
    out += i + 1 < bytes.size() ? kTable[(v >> 6) & 63] : '=';
    out += '=';
  }
  return out;
}

// One <DataArray> in VTK's inline binary form: base64 of (UInt64 byte count, raw little-endian values).
template <typename T>
std::string data_array(const char* type, const std::string& name, int components, const std::vector<T>& values) {
  std::string raw(8 + values.size() * sizeof(T), '\0');
  const uint64_t bytes = values.size() * sizeof(T);
  std::memcpy(raw.data(), &bytes, 8);
  if (!values.empty()) std::memcpy(raw.data() + 8, values.data(), bytes);
  std::string xml = "<DataArray type=\"" + std::string(type) + "\"";
  if (!name.empty()) xml += " Name=\"" + name + "\"";
  xml += " NumberOfComponents=\"" + std::to_string(components) + "\" format=\"binary\">" + base64(raw) +
         "</DataArray>\n";
  return xml;
}

Status write_text(const std::string& path, const std::string& text) {
  return write_file_atomically(path, text, "VTK file");
}

const char* kHeader =
    "<?xml version=\"1.0\"?>\n<VTKFile type=\"%s\" version=\"1.0\" byte_order=\"LittleEndian\" "
    "header_type=\"UInt64\">\n";

std::string header(const char* type) {
  char buffer[256];
  std::snprintf(buffer, sizeof(buffer), kHeader, type);
  return buffer;
}

}  // namespace

Status export_mesh_vtu(const Rig& rig, const std::string& path) {
  const TetMesh& mesh = rig.mesh;
  const int64_t nv = mesh.vertex_count(), nt = mesh.tet_count();
  std::string xml = header("UnstructuredGrid");
  xml += "<UnstructuredGrid>\n<Piece NumberOfPoints=\"" + std::to_string(nv) + "\" NumberOfCells=\"" +
         std::to_string(nt) + "\">\n<PointData>\n";
  for (size_t k = 0; k < rig.skeleton.segments.size(); ++k) {
    std::vector<float> w(static_cast<size_t>(nv), 0.0f);
    for (int64_t v = 0; v < nv && v < rig.weights.vertex_count(); ++v) {
      for (int i = 0; i < rig.weights.influences; ++i) {
        if (rig.weights.segment(v, i) == static_cast<int32_t>(k)) w[static_cast<size_t>(v)] = rig.weights.weight(v, i);
      }
    }
    xml += data_array("Float32", "w_" + rig.skeleton.segments[k].name, 1, w);
  }
  if (rig.centres.centre.rows() == nv) {
    std::vector<uint8_t> rigid(rig.centres.rigid.begin(), rig.centres.rigid.end());
    xml += data_array("UInt8", "rigid", 1, rigid);
    std::vector<double> centres(static_cast<size_t>(nv) * 3);
    for (int64_t v = 0; v < nv; ++v)
      for (int a = 0; a < 3; ++a) centres[static_cast<size_t>(3 * v + a)] = rig.centres.centre(v, a);
    xml += data_array("Float64", "centre_of_rotation", 3, centres);
  }
  xml += "</PointData>\n<CellData>\n";
  std::vector<int32_t> classes(mesh.tet_class.data(), mesh.tet_class.data() + nt);
  xml += data_array("Int32", "class", 1, classes);
  xml += "</CellData>\n<Points>\n";
  std::vector<double> points(static_cast<size_t>(nv) * 3);
  for (int64_t v = 0; v < nv; ++v)
    for (int a = 0; a < 3; ++a) points[static_cast<size_t>(3 * v + a)] = mesh.vertices(v, a);
  xml += data_array("Float64", "", 3, points);
  xml += "</Points>\n<Cells>\n";
  std::vector<int64_t> connectivity(static_cast<size_t>(nt) * 4), offsets(static_cast<size_t>(nt));
  for (int64_t t = 0; t < nt; ++t) {
    for (int c = 0; c < 4; ++c) connectivity[static_cast<size_t>(4 * t + c)] = mesh.tets(t, c);
    offsets[static_cast<size_t>(t)] = 4 * (t + 1);
  }
  xml += data_array("Int64", "connectivity", 1, connectivity);
  xml += data_array("Int64", "offsets", 1, offsets);
  xml += data_array("UInt8", "types", 1, std::vector<uint8_t>(static_cast<size_t>(nt), 10));  // VTK_TETRA
  xml += "</Cells>\n</Piece>\n</UnstructuredGrid>\n</VTKFile>\n";
  return write_text(path, xml);
}

Status export_skeleton_vtp(const Rig& rig, const std::string& path) {
  const rig::Skeleton& s = rig.skeleton;
  std::vector<double> points;
  std::vector<int32_t> joint_of_point, segment_of_point;
  for (size_t k = 0; k < s.segments.size(); ++k) {
    for (int a = 0; a < 3; ++a) points.push_back(s.segments[k].centroid_mm(a));
    joint_of_point.push_back(-1);
    segment_of_point.push_back(static_cast<int32_t>(k));
  }
  std::vector<int64_t> connectivity, offsets;
  for (size_t j = 0; j < s.joints.size(); ++j) {
    const int64_t index = static_cast<int64_t>(joint_of_point.size());
    for (int a = 0; a < 3; ++a) points.push_back(s.joints[j].centre_mm(a));
    joint_of_point.push_back(static_cast<int32_t>(j));
    segment_of_point.push_back(-1);
    for (const int end : {s.joints[j].parent, s.joints[j].child}) {
      connectivity.push_back(end);
      connectivity.push_back(index);
      offsets.push_back(static_cast<int64_t>(connectivity.size()));
    }
  }
  std::string xml = header("PolyData");
  xml += "<PolyData>\n<Piece NumberOfPoints=\"" + std::to_string(joint_of_point.size()) +
         "\" NumberOfVerts=\"0\" NumberOfLines=\"" + std::to_string(offsets.size()) +
         "\" NumberOfStrips=\"0\" NumberOfPolys=\"0\">\n<PointData>\n";
  xml += data_array("Int32", "joint", 1, joint_of_point);
  xml += data_array("Int32", "segment", 1, segment_of_point);
  xml += "</PointData>\n<Points>\n" + data_array("Float64", "", 3, points) + "</Points>\n<Lines>\n";
  xml += data_array("Int64", "connectivity", 1, connectivity);
  xml += data_array("Int64", "offsets", 1, offsets);
  xml += "</Lines>\n</Piece>\n</PolyData>\n</VTKFile>\n";
  return write_text(path, xml);
}

}  // namespace posewarp::api
