// The catalogue of damaged and hostile inputs, one or more per reader and per class of failure that a first
// hardening pass found (crash, hang, huge allocation from a tiny file, bad input accepted, input destroyed, wrong
// exit code). Each case is a file made here from the bar phantom's own files, given to the real `posewarp` process;
// every case must exit with the documented code, name the file and the problem, stay small and quick (getrusage of
// the child), and leave every input file as it was.
#include <gtest/gtest.h>
#include <zlib.h>

#include <cmath>
#include <cstdint>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <functional>
#include <limits>
#include <map>
#include <string>
#include <vector>

#include "cli_run.h"

namespace posewarp::bad_input {
namespace {

constexpr int kBadInput = 2;
constexpr int kResource = 3;

struct Case {
  std::string name;      // also the file's name
  std::string bytes;     // the file's content
  // The command, with "{}" where the file's path goes.
  std::vector<std::string> command;
  int exit_code = kBadInput;
  std::string says;      // a fragment the message must hold
  std::string names;     // what the message must name, when not the file (a parameter's value)
};

// A minimal NIfTI-1 single file: `dims` voxels of `datatype` (2 uint8, 4 int16, 16 float32), 1.5 x 1.5 x 2.5 mm,
// qform and sform both set; `patch` edits the header before the voxels are appended.
std::string nifti(const std::vector<int16_t>& dims, int16_t datatype, const std::string& voxels,
                  const std::function<void(char*)>& patch = {}) {
  std::string header(352, '\0');
  auto put = [&header](size_t at, auto value) { std::memcpy(header.data() + at, &value, sizeof value); };
  put(0, int32_t{348});
  put(40, int16_t{3});
  for (size_t a = 0; a < 3; ++a) put(42 + 2 * a, dims[a]);
  for (size_t a = 3; a < 8; ++a) put(42 + 2 * a, int16_t{1});
  put(70, datatype);
  put(72, static_cast<int16_t>(datatype == 2 ? 8 : datatype == 4 ? 16 : 32));
  const float pixdim[8] = {1.0f, 1.5f, 1.5f, 2.5f, 1.0f, 1.0f, 1.0f, 1.0f};
  std::memcpy(header.data() + 76, pixdim, sizeof pixdim);
  put(108, 352.0f);  // vox_offset
  put(112, 1.0f);    // scl_slope
  header[123] = 10;  // mm, s
  put(252, int16_t{1});
  put(254, int16_t{1});
  const float srow[12] = {-1.5f, 0, 0, 10, 0, -1.5f, 0, -20, 0, 0, 2.5f, -30};
  std::memcpy(header.data() + 280, srow, sizeof srow);
  std::memcpy(header.data() + 344, "n+1", 4);
  if (patch) patch(header.data());
  return header + voxels;
}

std::string labels_u8(size_t count) {
  std::string voxels(count, '\0');
  for (size_t v = 0; v < count; ++v) voxels[v] = static_cast<char>(v % 3);
  return voxels;
}

// `raw` deflated, as zlib (MetaImage) or gzip (NRRD, .nii.gz) stream.
std::string deflated(const std::string& raw, bool gzip) {
  z_stream z{};
  deflateInit2(&z, 9, Z_DEFLATED, gzip ? 31 : 15, 8, Z_DEFAULT_STRATEGY);
  std::string out(deflateBound(&z, raw.size()) + 32, '\0');
  z.next_in = reinterpret_cast<Bytef*>(const_cast<char*>(raw.data()));
  z.avail_in = static_cast<uInt>(raw.size());
  z.next_out = reinterpret_cast<Bytef*>(out.data());
  z.avail_out = static_cast<uInt>(out.size());
  deflate(&z, Z_FINISH);
  out.resize(z.total_out);
  deflateEnd(&z);
  return out;
}

// Every regular file under the directory (outside out/) with its content, to see that no input changed.
std::map<std::string, std::string> snapshot(const fs::path& dir) {
  std::map<std::string, std::string> files;
  for (const auto& entry : fs::recursive_directory_iterator(dir)) {
    if (!entry.is_regular_file() || entry.path().string().find("/out/") != std::string::npos) continue;
    files[entry.path().string()] = file_text(entry.path());
  }
  return files;
}

class Catalogue : public BadInput {
 protected:
  // Writes the case's file, runs its command and checks everything a refusal must be.
  void check(const Case& c) {
    SCOPED_TRACE(c.name);
    const std::string path = at(c.name);
    {
      std::ofstream out(path, std::ios::binary);
      out << c.bytes;
    }
    fs::create_directories(at("out"));
    const auto before = snapshot(dir_);
    std::vector<std::string> args;
    for (const std::string& a : c.command) args.push_back(a == "{}" ? path : a);
    expect_refused(posewarp(args), c.exit_code, c.names.empty() ? c.name : c.names, c.says);
    EXPECT_EQ(snapshot(dir_), before) << "an input file changed";
    fs::remove(path);
    fs::remove_all(at("out"));
  }

  static std::string rig_bytes() { return file_text(at("bar.rig")); }
  std::vector<std::string> pose_with(const std::string& flag) {
    return {"pose", at("bar.rig"), "--pose", flag == "--pose" ? "{}" : at("pose.json"), "--labels-out",
            at("out/labels.nii.gz")};
  }
};

TEST_F(Catalogue, Volumes) {
  const std::string voxels = labels_u8(6 * 5 * 4);
  const std::vector<std::string> info{"info", "{}"};
  const std::vector<std::string> build{"rig", "build", "--labels", "{}", "--label-map", at("label_map.json"),
                                       "-o", at("out/x.rig")};
  // Crash: a NaN in the sform aborted inside ITK's SVD.
  check({"nan_sform.nii", nifti({6, 5, 4}, 2, voxels, [](char* h) {
           const float nan = std::nanf("");
           std::memcpy(h + 280, &nan, 4);
         }), info, kBadInput, "srow_x"});
  // Accepted: an infinite qform offset, a negative vox_offset, zero spacing.
  check({"inf_qoffset.nii", nifti({6, 5, 4}, 2, voxels, [](char* h) {
           const float inf = std::numeric_limits<float>::infinity();
           std::memcpy(h + 268, &inf, 4);
           h[254] = 0;  // sform unused: the qform is the geometry
         }), info, kBadInput, "qoffset"});
  check({"negative_vox_offset.nii", nifti({6, 5, 4}, 2, voxels, [](char* h) {
           const float offset = -4096.0f;
           std::memcpy(h + 108, &offset, 4);
         }), info, kBadInput, "vox_offset"});
  check({"zero_spacing.nii", nifti({6, 5, 4}, 2, voxels, [](char* h) {
           const float zero = 0.0f;
           std::memcpy(h + 80, &zero, 4);
           h[254] = 0;
         }), info, kBadInput, "pixdim[1] = 0"});
  // ITK's text passed through: "is not recognized as a NIFTI file" for a zero size, "orthonormal direction cosines"
  // for a zero or negative spacing with the sform in use. Named by field now, NIfTI and MetaImage alike.
  check({"zero_dim.nii", nifti({6, 0, 4}, 2, voxels), info, kBadInput, "dim[2] = 0"});
  check({"negative_spacing.nii", nifti({6, 5, 4}, 2, voxels, [](char* h) {
           const float negative = -1.5f;
           std::memcpy(h + 84, &negative, 4);
         }), info, kBadInput, "pixdim[2] = -1.5"});
  const auto mha = [](const std::string& dims, const std::string& spacing) {
    return "ObjectType = Image\nNDims = 3\nBinaryData = True\nDimSize = " + dims + "\nElementSpacing = " + spacing +
           "\nElementType = MET_UCHAR\nElementDataFile = LOCAL\n" + std::string(120, '\1');
  };
  check({"zero_dim.mha", mha("6 0 4", "1 1 1"), info, kBadInput, "DimSize[1] = 0"});
  check({"zero_spacing.mha", mha("6 5 4", "1 0 1"), build, kBadInput, "ElementSpacing[1] = 0"});
  check({"negative_spacing.mha", mha("6 5 4", "1 1 -2"), info, kBadInput, "ElementSpacing[2] = -2"});
  // Accepted: NaN in a float label volume was read as label 0.
  std::string floats(6 * 5 * 4 * sizeof(float), '\0');
  const float nan = std::nanf("");
  std::memcpy(floats.data() + 40, &nan, 4);
  check({"nan_labels.nii", nifti({6, 5, 4}, 16, floats), build, kBadInput, "NaN or infinite value at voxel 10"});
  // Damaged: voxels missing at the end.
  check({"truncated.nii", nifti({6, 5, 4}, 2, voxels.substr(0, 50)), build, kBadInput, "truncated"});
  // Huge allocation from a tiny file: 1 KB of compressed data claiming 700^3 voxels (ITK allocated 2.7 GB and
  // accepted uninitialised voxels); the same through NRRD's gzip encoding; a raw NRRD claiming a grid its file
  // does not hold.
  const std::string bomb = deflated(std::string(1 << 20, '\0'), false);
  check({"bomb.mha",
         "ObjectType = Image\nNDims = 3\nBinaryData = True\nBinaryDataByteOrderMSB = False\nCompressedData = True\n"
         "CompressedDataSize = " + std::to_string(bomb.size()) + "\nTransformMatrix = 1 0 0 0 1 0 0 0 1\n"
         "Offset = 0 0 0\nElementSpacing = 1 1 1\nDimSize = 700 700 700\nElementType = MET_UCHAR\n"
         "ElementDataFile = LOCAL\n" + bomb, build, kBadInput, "compressed"});
  const std::string gz_bomb = deflated(std::string(1 << 20, '\0'), true);
  check({"bomb.nrrd",
         "NRRD0004\ntype: uint8\ndimension: 3\nspace: left-posterior-superior\nsizes: 700 700 700\n"
         "space directions: (1,0,0) (0,1,0) (0,0,1)\nkinds: domain domain domain\nencoding: gzip\n"
         "space origin: (0,0,0)\n\n" + gz_bomb, build, kBadInput, "header promises"});
  check({"short_raw.nrrd",
         "NRRD0004\ntype: int16\ndimension: 3\nsizes: 512 512 900\nspacings: 1 1 1\nencoding: raw\nendian: little\n\n" +
             std::string(4096, '\0'), build, kBadInput, "truncated"});
  // Crash: a file list (a printf pattern) made ITK's MetaIO overflow a buffer (found by fuzzing).
  check({"file_list.mha",
         "ObjectType = Image\nNDims = 3\nBinaryData = True\nDimSize = 6 5 4\nElementType = MET_UCHAR\n"
         "ElementDataFile = slice%03d.raw 1 4 1\n",
         build, kBadInput, "names its voxel data"});
  // Hang: ITK's MetaIO looped forever on a negative NDims (found by fuzzing).
  check({"negative_ndims.mha",
         "ObjectType = Image\nNDims = -3\nBinaryData = True\nDimSize = 6 5 4\nElementType = MET_UCHAR\n"
         "ElementDataFile = LOCAL\n" + std::string(120, '\0'),
         info, kBadInput, "NDims"});
  // A header naming a file elsewhere as its voxels (an upload could read any file on a server as a volume), and a
  // directory as its data (MetaIO allocated without bound: found by fuzzing).
  check({"elsewhere.mha",
         "ObjectType = Image\nNDims = 3\nBinaryData = True\nDimSize = 6 5 4\nElementType = MET_UCHAR\n"
         "ElementDataFile = /etc/passwd\n",
         build, kBadInput, "without a directory"});
  check({"directory.mhd",
         "ObjectType = Image\nNDims = 3\nBinaryData = True\nDimSize = 6 5 4\nElementType = MET_UCHAR\n"
         "ElementDataFile = ..\n",
         build, kBadInput, "without a directory"});
  check({"elsewhere.nhdr",
         "NRRD0004\ntype: uint8\ndimension: 3\nsizes: 6 5 4\nspacings: 1 1 1\nencoding: raw\n"
         "data file: /etc/passwd\n",
         build, kBadInput, "without a directory"});
  // Not a volume at all.
  check({"not_a_volume.nii.gz", "this is text, not a gzip stream", info, kBadInput, "not_a_volume.nii.gz"});
}

TEST_F(Catalogue, LabelMaps) {
  const std::vector<std::string> check_map{"labels", "check", "{}"};
  check({"deep_map.json", "{\"labels\": " + std::string(100000, '[') + std::string(100000, ']') + "}", check_map,
         kBadInput, "levels deep"});
  check({"huge_number_map.json", R"({"name": "x", "labels": [{"value": 1e999, "name": "femur_left", "role": "bone"}]})",
         check_map, kBadInput, "huge_number_map.json"});
  check({"not_json_map.json", "labels: femur", check_map, kBadInput, "not_json_map.json"});
}

TEST_F(Catalogue, RigSpecs) {
  const std::vector<std::string> build{"rig",  "build", "--labels", at("labels.nii.gz"), "--label-map",
                                       at("label_map.json"), "--rig-spec", "{}", "-o", at("out/x.rig")};
  // Accepted: a label listed in two segments (silently the last), a fractional label (soft tissue became bone), a
  // joint centre at 1e12 mm (posing reported "-nan%"). Hang: a contact distance of 1e6 mm.
  check({"twice.json", R"({"segments": {"a": [1], "b": [1]}})", build, kBadInput, "in segment \"b\""});
  check({"fractional.json", R"({"segments": {"a": [25.7]}})", build, kBadInput, "whole"});
  check({"far_joint.json", R"({"joints": [{"parent": "bar_bone_1", "child": "bar_bone_2", "centre_mm": [1e12, 0, 0]}]})",
         build, kBadInput, "far_joint.json"});
  check({"far_contacts.json", R"({"contact_distance_mm": 1e6})", build, kBadInput, "contact_distance_mm"});
}

TEST_F(Catalogue, RigFiles) {
  const std::vector<std::string> info{"rig", "info", "{}"};
  const std::string rig = rig_bytes();
  check({"joined.rig", rig + rig, info, kBadInput, "after its end marker"});
  check({"half.rig", rig.substr(0, rig.size() / 2), info, kBadInput, "truncated"});
  std::string flipped = rig;
  flipped[flipped.size() / 3] = static_cast<char>(flipped[flipped.size() / 3] ^ 0x5a);
  check({"flipped.rig", flipped, info, kBadInput, "checksum"});
  check({"text.rig", "POSE", info, kBadInput, "not a posewarp rig file"});
  std::string newer = rig;
  newer[8] = 99;
  check({"newer.rig", newer, info, kBadInput, "newer posewarp"});
}

TEST_F(Catalogue, Poses) {
  check({"deep_pose.json", "{\"joints\": " + std::string(100000, '{') + "}", pose_with("--pose"), kBadInput,
         "levels deep"});
  check({"nan_pose.json", R"({"joints": {"joint_2_3": {"axis_angle": {"axis": [1, 0, 0], "degrees": NaN}}}})",
         pose_with("--pose"), kBadInput, "nan_pose.json"});
  check({"unknown_joint.json", R"({"joints": {"elbow_of_nobody": {"axis_angle": {"axis": [1, 0, 0], "degrees": 10}}}})",
         pose_with("--pose"), kBadInput, "elbow_of_nobody"});
  check({"huge_angle.json", R"({"joints": {"joint_2_3": {"axis_angle": {"axis": [1, 0, 0], "degrees": 1e308}}}})",
         pose_with("--pose"), kBadInput, "\"degrees\" = 1e+308 is outside [-360, 360] degrees"});
  // Accepted: a flexion of 1e308 degrees (finite, an arbitrary rotation), and a root moved 30 m on a grown grid
  // (1.25 GB of output).
  check({"huge_flexion.json", R"({"joints": {"joint_2_3": {"angles_deg": {"flexion": 1e308}}}})", pose_with("--pose"),
         kBadInput, "\"flexion\" = 1e+308 is outside [-360, 360] degrees"});
  check({"far_root.json", R"({"root": {"translation_mm": [0, 30000, 0]}, "joints": {}})",
         {"pose", at("bar.rig"), "--pose", "{}", "--grid", "grow", "--labels-out", at("out/l.nii.gz")}, kBadInput,
         "root: \"translation_mm[1]\" = 30000 is outside [-2000, 2000] mm"});
}

// Outputs that must be files, given as existing directories: the export failed INTERNAL (exit 1) when it renamed
// its file over the directory. Refused as bad input, naming the directory, which stays as it was.
TEST_F(Catalogue, OutputsOntoADirectory) {
  const std::string dir = at("a_directory");
  const std::string volume_dir = at("a_directory.nii.gz");
  fs::create_directories(dir);
  fs::create_directories(volume_dir);
  const std::vector<std::vector<std::string>> commands{
      {"rig", "export", at("bar.rig"), "--mesh", dir},
      {"rig", "export", at("bar.rig"), "--skeleton", dir},
      {"rig", "build", "--labels", at("labels.nii.gz"), "--label-map", at("label_map.json"), "-o", dir},
      {"pose", at("bar.rig"), "--pose", at("pose.json"), "--labels-out", at("l.nii.gz"), "--report", dir},
      {"pose", at("bar.rig"), "--pose", at("pose.json"), "--labels-out", volume_dir}};
  for (const std::vector<std::string>& command : commands) {
    SCOPED_TRACE(command[0] + " " + command[1] + " ... " + command[command.size() - 2]);
    const std::string target = command.back() == volume_dir ? volume_dir : dir;
    expect_refused(posewarp(command), kBadInput, "'" + target + "': it is a directory", "name a file to write");
    EXPECT_TRUE(fs::is_empty(target));
  }
  EXPECT_FALSE(fs::exists(at("l.nii.gz")));
  fs::remove_all(dir);
  fs::remove_all(volume_dir);
}

// The labels and the CT given the wrong way round built a rig (30 s of meshing garbage): refused before any work,
// naming both.
TEST_F(Catalogue, LabelsAndCtSwapped) {
  ASSERT_EQ(posewarp({"-q", "convert", at("ct.nii.gz"), at("ct16.nii.gz"), "--pixel-type", "int16"}).exit_code, 0);
  const CliRun run = posewarp({"rig", "build", "--labels", at("ct16.nii.gz"), "--ct", at("labels.nii.gz"),
                               "--label-map", at("label_map.json"), "-o", at("swapped.rig")});
  // The labels, checked first, are refused (HU values below -100); the message names both and the swap.
  expect_refused(run, kBadInput, "the CT '" + at("labels.nii.gz") + "'", "are the two swapped?");
  EXPECT_NE(run.err.find("the labels '" + at("ct16.nii.gz") + "'"), std::string::npos) << run.err;
  EXPECT_FALSE(fs::exists(at("swapped.rig")));
  fs::remove(at("ct16.nii.gz"));
}

// posewarp match: a target that is no volume, a target map that is no JSON, a pose written onto the rig, a SEG
// without its CT, an unknown method, a rig file given to --server: each refused by name before any work, no input
// touched.
TEST_F(Catalogue, Match) {
  const std::vector<std::string> target{"match", at("bar.rig"), "--target-labels", "{}", "-o", at("out/found.json")};
  check({"target.nii.gz", "not a volume at all", target, kBadInput, "target.nii.gz"});
  check({"target_map.json", "{\"format\": ", {"match", at("bar.rig"), "--target-labels", at("labels.nii.gz"),
          "--label-map", "{}", "-o", at("out/found.json")}, kBadInput, "target_map.json"});
  expect_refused(posewarp({"match", at("bar.rig"), "--target-labels", at("labels.nii.gz"), "-o", at("bar.rig")}),
                 kBadInput, "the output '" + at("bar.rig") + "' is the input", "");
  check({"seg.dcm", std::string(128, '\0') + "DICM", target, kBadInput, "give --target-ct DIR"});
  expect_refused(posewarp({"match", at("bar.rig"), "-o", at("found.json")}), kBadInput, "--target-labels",
                 "--standard NAME");
  expect_refused(posewarp({"match", at("bar.rig"), "--standard", "t-pose", "-o", at("found.json")}), kBadInput,
                 "'t-pose'", "arms-up");
  // A method nobody has, and a rig path where the server wants a rig id: refused before any work or connection.
  expect_refused(posewarp({"match", at("bar.rig"), "--target-labels", at("labels.nii.gz"), "--method", "warp", "-o",
                           at("found.json")}),
                 kBadInput, "warp", "");
  expect_refused(posewarp({"match", at("bar.rig"), "--server", "127.0.0.1:1", "--retries", "0", "--target-labels",
                           at("labels.nii.gz"), "-o", at("found.json")}),
                 kBadInput, "rig id", "");
  EXPECT_FALSE(fs::exists(at("found.json")));
}

TEST_F(Catalogue, AnimationsAndBvh) {
  const std::vector<std::string> animate{"animate", at("bar.rig"), "--animation", "{}", "--out-dir", at("out")};
  check({"frames_not_list.json", R"({"format": "posewarp.animation", "version": 1, "frames": 7})", animate, kBadInput,
         "frames_not_list.json"});
  check({"no_frames.json", R"({"format": "posewarp.animation", "version": 1, "frames": []})", animate, kBadInput,
         "no_frames.json"});
  fs::copy_file(fs::path(POSEWARP_SOURCE_DIR) / "data/poses/bar_wave_map.json", at("map.json"),
                fs::copy_options::overwrite_existing);
  const std::vector<std::string> bvh{"animate", at("bar.rig"), "--bvh", "{}", "--map", at("map.json"), "--out-dir",
                                     at("out")};
  // A motion claiming a billion frames in a few bytes, and a billion channels on one joint.
  const std::string hierarchy = file_text(fs::path(POSEWARP_SOURCE_DIR) / "data/poses/bar_wave.bvh");
  const std::string head = hierarchy.substr(0, hierarchy.find("MOTION"));
  check({"billion_frames.bvh", head + "MOTION\nFrames: 1000000000\nFrame Time: 0.1\n0 0 0\n", bvh, kBadInput,
         "billion_frames.bvh"});
  std::string channels = hierarchy;
  channels.replace(channels.find("CHANNELS 3"), 10, "CHANNELS 1000000000");
  check({"billion_channels.bvh", channels, bvh, kBadInput, "billion_channels.bvh"});
  fs::copy_file(fs::path(POSEWARP_SOURCE_DIR) / "data/poses/bar_wave.bvh", at("wave.bvh"),
                fs::copy_options::overwrite_existing);
  check({"bad_map.json", R"({"format": "posewarp.bvh_map", "version": 1, "up": "w", "joints": {}})",
         {"animate", at("bar.rig"), "--bvh", at("wave.bvh"), "--map", "{}", "--out-dir", at("out")}, kBadInput,
         "bad_map.json"});
}

TEST_F(Catalogue, Meshes) {
  auto with_mesh = [](const std::string&) {
    return std::vector<std::string>{"pose", at("bar.rig"), "--pose", at("pose.json"), "--surface", "{}",
                                    "--surfaces-out", at("out")};
  };
  // Huge allocations from tiny files: a binary STL claiming a billion triangles, a PLY claiming four billion
  // vertices.
  std::string stl(80, ' ');
  const uint32_t billion = 1000000000u;
  stl.append(reinterpret_cast<const char*>(&billion), 4);
  check({"billion.stl", stl, with_mesh("stl"), kBadInput, "billion.stl"});
  check({"huge.ply",
         "ply\nformat binary_little_endian 1.0\nelement vertex 4000000000\nproperty float x\nproperty float y\n"
         "property float z\nelement face 1\nproperty list uchar int vertex_indices\nend_header\n" +
             std::string(64, '\0'),
         with_mesh("ply"), kBadInput, "huge.ply"});
  check({"dangling.obj", "v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 9\n", with_mesh("obj"), kBadInput, "vertex 9 of 3"});
  check({"garbage.vtp", "<VTKFile type=\"PolyData\"><PolyData><Piece NumberOfPoints=\"-5\">", with_mesh("vtp"),
         kBadInput, "garbage.vtp"});
  check({"points_only.obj", "v 0 0 0\nv 1 0 0\n", with_mesh("obj"), kBadInput, "no faces"});
}

TEST_F(Catalogue, ParametersThatWouldNotFinish) {
  // A bone tet size of 0.25 mm on this body would make millions of vertices: refused before meshing, within the
  // memory bound, with the sizes to change.
  check({"tiny_tets_spec.json", "{}",
         {"rig", "build", "--labels", at("labels.nii.gz"), "--label-map", at("label_map.json"), "--rig-spec", "{}",
          "--bone-size", "0.25", "--soft-size", "0.25", "--facet-size", "0.5", "--facet-distance", "0.25", "-o",
          at("out/x.rig")},
         kResource, "bone_cell_size_mm", "0.25 mm"});
  // A pose whose outputs would take more memory than the budget (here 1 MB) is refused before they are allocated.
  check({"budget_pose.json", file_text(at("pose.json")),
         {"pose", at("bar.rig"), "--pose", "{}", "--grid", "grow", "--labels-out", at("out/l.nii.gz"), "--ct-out",
          at("out/ct.nii.gz"), "--max-output-mb", "1"},
         kResource, "over the budget", "1 MB"});
  // An output grid of 700^3 voxels whose file holds only a header.
  check({"huge_grid.nii", nifti({700, 700, 700}, 2, ""),
         {"pose", at("bar.rig"), "--pose", at("pose.json"), "--grid-like", "{}", "--labels-out", at("out/l.nii.gz")},
         kBadInput, "truncated"});
}

}  // namespace
}  // namespace posewarp::bad_input
