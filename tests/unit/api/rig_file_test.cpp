#include "posewarp/api/rig_file.h"

#include <gtest/gtest.h>

#include <cmath>
#include <cstring>
#include <limits>

#include "posewarp/api/vtk_export.h"
#include "rig_bytes_support.h"
#include "rig_test_support.h"
#include "test_support.h"

namespace posewarp::api {
namespace {

using posewarp::testing::read_bytes;
using posewarp::testing::ScratchDir;
using posewarp::testing::shared_bar_rig;
using posewarp::testing::write_bytes;

TEST(RigFile, RoundTripKeepsEverySection) {
  ScratchDir dir;
  const Rig& rig = shared_bar_rig();
  ASSERT_TRUE(save_rig(rig, dir.file("bar.rig")).ok());
  Result<Rig> back = load_rig(dir.file("bar.rig"));
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  EXPECT_EQ(back->mesh.vertices, rig.mesh.vertices);
  EXPECT_EQ(back->mesh.tets, rig.mesh.tets);
  EXPECT_EQ(back->mesh.tet_class, rig.mesh.tet_class);
  EXPECT_EQ(back->weights.segment, rig.weights.segment);
  EXPECT_EQ(back->weights.weight, rig.weights.weight);
  EXPECT_EQ(back->centres.centre, rig.centres.centre);
  EXPECT_EQ(back->centres.rigid, rig.centres.rigid);
  EXPECT_EQ(back->skeleton.joints.size(), rig.skeleton.joints.size());
  EXPECT_EQ(back->skeleton.joints[0].centre_mm, rig.skeleton.joints[0].centre_mm);
  EXPECT_EQ(back->skeleton.joints[0].frame, rig.skeleton.joints[0].frame);
  ASSERT_FALSE(rig.skeleton.joints[0].ranges.empty());  // measured at build
  ASSERT_EQ(back->skeleton.joints[0].ranges.size(), rig.skeleton.joints[0].ranges.size());
  EXPECT_EQ(back->skeleton.joints[0].ranges[0].motion, rig.skeleton.joints[0].ranges[0].motion);
  EXPECT_EQ(back->skeleton.joints[0].ranges[0].negative_deg, rig.skeleton.joints[0].ranges[0].negative_deg);
  EXPECT_EQ(back->skeleton.joints[0].ranges[0].positive_stopped, rig.skeleton.joints[0].ranges[0].positive_stopped);
  EXPECT_EQ(back->label_map.entries().size(), rig.label_map.entries().size());
  EXPECT_TRUE(back->source_geometry.same_grid(rig.source_geometry, 0.0));
  EXPECT_EQ(back->id(), rig.id());
  EXPECT_EQ(content_hash(*back), content_hash(rig));
  std::string stored;  // the hash the end marker holds is the one the rig's sections give
  ASSERT_TRUE(load_rig(dir.file("bar.rig"), stored).ok());
  EXPECT_EQ(stored, content_hash(rig));
  EXPECT_EQ(back->provenance.stage_seconds.size(), rig.provenance.stage_seconds.size());
  // The engine's tables, made at build: one value per source voxel, as built.
  ASSERT_EQ(rig.rest_owner.size(), rig.labels.size());
  EXPECT_EQ(back->rest_owner, rig.rest_owner);
  EXPECT_EQ(back->body_region, rig.body_region);
  EXPECT_EQ(back->bone_substitute, rig.bone_substitute);
  // And the mesh's skin vertices, a bit per vertex (SKIN).
  ASSERT_EQ(static_cast<int64_t>(rig.skin_vertex.size()), rig.mesh.vertex_count());
  EXPECT_GT(std::count(rig.skin_vertex.begin(), rig.skin_vertex.end(), 1), 0);
  EXPECT_EQ(back->skin_vertex, rig.skin_vertex);
  // And the engine's summary (ENGN): a region per tet, the labels' counts, the CT's lowest value.
  ASSERT_EQ(static_cast<int64_t>(rig.tet_region.size()), rig.mesh.tet_count());
  EXPECT_EQ(back->tet_region, rig.tet_region);
  ASSERT_FALSE(rig.rest_label_counts.empty());
  EXPECT_EQ(back->rest_label_counts, rig.rest_label_counts);
  ASSERT_TRUE(rig.ct_lowest);
  EXPECT_EQ(back->ct_lowest, rig.ct_lowest);
}

TEST(RigFile, TheCtIsKeptInInt16WhereItFitsAndStoredAsItsFloatsWere) {
  // A rig written before the CT was held in int16 (the fuzzing corpus's, format 3) encodes to the same sections: the
  // hash its end marker holds is the one its sections give now.
  std::string stored;
  Result<Rig> old =
      load_rig(std::string(POSEWARP_SOURCE_DIR) + "/tests/fuzz/corpus/rig_file/bar_2_bones_skin.rig", stored);
  ASSERT_TRUE(old.ok()) << old.status().to_string();
  ASSERT_TRUE(old->ct);
  EXPECT_NE(old->ct->as_int16(), nullptr);  // its int16 samples are read as they are
  EXPECT_EQ(content_hash(*old), stored);
  // Whole numbers from int16 or uint8 are held and read back in int16, a fraction in float; the values bit for bit.
  ScratchDir dir;
  for (const PixelType source : {PixelType::kInt16, PixelType::kUInt8, PixelType::kFloat32}) {
    Rig rig = shared_bar_rig();
    IntensityVolume ct = rig.ct->to_float();
    for (int64_t v = 0; v < ct.voxel_count(); ++v) {
      ct.data()[v] = source == PixelType::kUInt8 ? static_cast<float>(v % 256) : std::round(ct.data()[v]) + 0.0f;
    }
    if (source == PixelType::kFloat32) ct.data()[ct.voxel_count() / 3] = 0.25f;
    ct.set_source_type(source);
    rig.ct.emplace(ct);
    ASSERT_EQ(rig.ct->as_int16() != nullptr, source != PixelType::kFloat32);
    const std::string file = dir.file("ct.rig");
    ASSERT_TRUE(save_rig(rig, file).ok());
    Result<Rig> back = load_rig(file);
    ASSERT_TRUE(back.ok()) << back.status().to_string();
    ASSERT_TRUE(back->ct);
    EXPECT_EQ(back->ct->as_int16() != nullptr, source != PixelType::kFloat32) << pixel_type_name(source);
    EXPECT_EQ(back->ct->source_type(), source);
    EXPECT_EQ(back->ct->to_float().voxels(), ct.voxels()) << pixel_type_name(source);
    EXPECT_EQ(content_hash(*back), content_hash(rig));
  }
}

TEST(RigFile, TruncatedFileIsDataLoss) {
  ScratchDir dir;
  ASSERT_TRUE(save_rig(shared_bar_rig(), dir.file("bar.rig")).ok());
  const std::string bytes = read_bytes(dir.file("bar.rig"));
  for (const size_t keep : {bytes.size() - 1, bytes.size() / 2, size_t{30}}) {
    write_bytes(dir.file("cut.rig"), bytes.substr(0, keep));
    Result<Rig> rig = load_rig(dir.file("cut.rig"));
    EXPECT_EQ(rig.status().code(), StatusCode::kDataLoss) << keep << ": " << rig.status().to_string();
  }
}

TEST(RigFile, FlippedByteFailsItsChecksum) {
  ScratchDir dir;
  ASSERT_TRUE(save_rig(shared_bar_rig(), dir.file("bar.rig")).ok());
  std::string bytes = read_bytes(dir.file("bar.rig"));
  bytes[bytes.size() / 2] ^= 0x40;
  write_bytes(dir.file("flipped.rig"), bytes);
  Result<Rig> rig = load_rig(dir.file("flipped.rig"));
  EXPECT_EQ(rig.status().code(), StatusCode::kDataLoss);
  EXPECT_NE(rig.status().message().find("checksum"), std::string::npos);
}

TEST(RigFile, FutureVersionAsksForAnUpgrade) {
  ScratchDir dir;
  ASSERT_TRUE(save_rig(shared_bar_rig(), dir.file("bar.rig")).ok());
  std::string bytes = read_bytes(dir.file("bar.rig"));
  const uint32_t future = kRigFormatVersion + 1;
  std::memcpy(bytes.data() + 8, &future, 4);
  write_bytes(dir.file("future.rig"), bytes);
  Result<Rig> rig = load_rig(dir.file("future.rig"));
  EXPECT_EQ(rig.status().code(), StatusCode::kFailedPrecondition);
  EXPECT_NE(rig.status().message().find("Upgrade posewarp"), std::string::npos);
}

TEST(RigFile, UnknownSectionsAreSkippedAndKept) {
  ScratchDir dir;
  Rig rig = shared_bar_rig();
  rig.unknown_sections.emplace_back(0x5a5a5a5a, "from a newer writer");
  ASSERT_TRUE(save_rig(rig, dir.file("newer.rig")).ok());
  Result<Rig> back = load_rig(dir.file("newer.rig"));
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  ASSERT_EQ(back->unknown_sections.size(), 1u);
  EXPECT_EQ(back->unknown_sections[0].second, "from a newer writer");
}

TEST(RigFile, NotARigAndMissingFilesAreClear) {
  ScratchDir dir;
  write_bytes(dir.file("text.rig"), "hello, this is not a rig at all");
  EXPECT_EQ(load_rig(dir.file("text.rig")).status().code(), StatusCode::kInvalidArgument);
  EXPECT_EQ(load_rig(dir.file("none.rig")).status().code(), StatusCode::kNotFound);
}

TEST(VtkExport, WritesMeshAndSkeletonFiles) {
  ScratchDir dir;
  ASSERT_TRUE(export_mesh_vtu(shared_bar_rig(), dir.file("mesh.vtu")).ok());
  ASSERT_TRUE(export_skeleton_vtp(shared_bar_rig(), dir.file("skeleton.vtp")).ok());
  const std::string vtu = read_bytes(dir.file("mesh.vtu"));
  EXPECT_NE(vtu.find("NumberOfCells=\"" + std::to_string(shared_bar_rig().mesh.tet_count()) + "\""), std::string::npos);
  EXPECT_NE(vtu.find("Name=\"w_bar_bone_1\""), std::string::npos);
  EXPECT_NE(read_bytes(dir.file("skeleton.vtp")).find("NumberOfLines=\"4\""), std::string::npos);
}

}  // namespace
}  // namespace posewarp::api

namespace posewarp::api {
namespace {

// Sections whose checksums are right but whose contents point out of range (what a crafted file holds) are refused
// on load, before any posing code follows an index.
TEST(RigFile, IndicesOutOfRangeAreRefusedEvenWithValidChecksums) {
  ScratchDir dir;
  auto refused = [&](Rig rig, const std::string& says) {
    ASSERT_TRUE(save_rig(rig, dir.file("crafted.rig")).ok());
    const Status status = load_rig(dir.file("crafted.rig")).status();
    EXPECT_EQ(status.code(), StatusCode::kDataLoss) << status.to_string();
    EXPECT_NE(status.message().find(says), std::string::npos) << status.to_string();
    EXPECT_NE(status.message().find("crafted.rig"), std::string::npos) << status.to_string();
  };
  {
    Rig rig = posewarp::testing::shared_bar_rig();
    rig.weights.segment(0, 0) = 99;
    refused(std::move(rig), "segment that does not exist");
  }
  {
    Rig rig = posewarp::testing::shared_bar_rig();
    rig.weights.weight(0, 0) = std::nanf("");
    refused(std::move(rig), "outside [0, 1]");
  }
  {
    Rig rig = posewarp::testing::shared_bar_rig();
    rig.mesh.tet_class(0) = 57;
    refused(std::move(rig), "class");
  }
  {
    Rig rig = posewarp::testing::shared_bar_rig();
    rig.mesh.vertices(0, 0) = std::numeric_limits<double>::infinity();
    refused(std::move(rig), "NaN or infinite vertices");
  }
  {
    Rig rig = posewarp::testing::shared_bar_rig();
    rig.skeleton.joints[0].centre_mm.x() = std::numeric_limits<double>::infinity();  // JSON writes null
    refused(std::move(rig), "skeleton");
  }
  {
    Rig rig = posewarp::testing::shared_bar_rig();
    ASSERT_FALSE(rig.surfaces.empty());
    rig.surfaces[0].triangles(0, 1) = static_cast<int32_t>(rig.surfaces[0].vertices.rows());
    refused(std::move(rig), "vertices that do not exist");
  }
  {
    Rig rig = posewarp::testing::shared_bar_rig();
    rig.skeleton.segments[0].parent_joint = 42;
    refused(std::move(rig), "missing joint");
  }
  {
    Rig rig = posewarp::testing::shared_bar_rig();
    rig.labels = LabelVolume();
    refused(std::move(rig), "no label volume");
  }
  {
    Rig rig = posewarp::testing::shared_bar_rig();
    std::vector<int32_t> owner = rig.rest_owner.unpacked();
    owner[owner.size() / 2] = static_cast<int32_t>(rig.mesh.tet_count());
    rig.rest_owner = RowPacked<int32_t>::pack(owner.data(), rig.labels.size(), -1);
    refused(std::move(rig), "OWNR");
  }
  {
    Rig rig = posewarp::testing::shared_bar_rig();
    ASSERT_TRUE(rig.bone_substitute && !rig.bone_substitute->substitute.empty());
    rig.bone_substitute->substitute.back() = static_cast<int32_t>(rig.labels.voxel_count());
    refused(std::move(rig), "SUBS");
  }
  {
    Rig rig = posewarp::testing::shared_bar_rig();
    const std::vector<int16_t> region = rig.body_region.unpacked();  // as if of a grid one slice thinner
    const Index3& m = rig.labels.size();
    rig.body_region = RowPacked<int16_t>::pack(region.data(), {m[0], m[1], m[2] - 1}, int16_t{-1});
    refused(std::move(rig), "one value per voxel");
  }
  {
    Rig rig = posewarp::testing::shared_bar_rig();
    rig.skin_vertex.pop_back();
    refused(std::move(rig), "SKIN");
  }
  {
    Rig rig = posewarp::testing::shared_bar_rig();
    rig.tet_region[0] = static_cast<int16_t>(rig.skeleton.segments.size());
    refused(std::move(rig), "ENGN");
  }
  {
    Rig rig = posewarp::testing::shared_bar_rig();
    rig.tet_region.pop_back();
    refused(std::move(rig), "ENGN");
  }
  {
    Rig rig = posewarp::testing::shared_bar_rig();
    rig.rest_label_counts.begin()->second += 1;  // more voxels than the labels hold
    refused(std::move(rig), "ENGN");
  }
  {
    Rig rig = posewarp::testing::shared_bar_rig();
    rig.ct_lowest.reset();  // a CT without its floor
    refused(std::move(rig), "ENGN");
  }
}

// The engine's summary claiming far more tets than its deflated bytes can hold (checksums recomputed) is refused
// before the regions are allocated.
TEST(RigFile, ASummaryClaimingHugeCountsIsRefusedBeforeAllocating) {
  const Rig& rig = shared_bar_rig();
  std::string bytes = rig_to_bytes(rig);
  const size_t at = bytes.find("ENGN");
  ASSERT_NE(at, std::string::npos);
  // After the label count, its (label, count) pairs, the CT flag and its lowest value: the tet count.
  const size_t tets_at = at + 24 + 8 + 12 * rig.rest_label_counts.size() + 1 + 4;
  uint64_t tets = 0;
  std::memcpy(&tets, bytes.data() + tets_at, 8);
  ASSERT_EQ(tets, static_cast<uint64_t>(rig.mesh.tet_count()));
  const uint64_t huge = uint64_t{1} << 40;
  std::memcpy(bytes.data() + tets_at, &huge, 8);
  const Status status = rig_from_bytes(posewarp::testing::with_rig_checksums(bytes), "crafted rig").status();
  EXPECT_EQ(status.code(), StatusCode::kDataLoss) << status.to_string();
  EXPECT_NE(status.message().find("more tets than it holds"), std::string::npos) << status.to_string();
}

// A section the reader knows appearing twice (checksums recomputed) is damage, not a second copy to append.
TEST(RigFile, AKnownSectionTwiceIsRefused) {
  const std::string bytes = rig_to_bytes(shared_bar_rig());
  const size_t at = bytes.find("SKEL");
  ASSERT_NE(at, std::string::npos);
  uint64_t size = 0;
  std::memcpy(&size, bytes.data() + at + 8, 8);
  const std::string section = bytes.substr(at, 24 + size);
  const std::string doubled = bytes.substr(0, at) + section + bytes.substr(at);
  const Status status = rig_from_bytes(posewarp::testing::with_rig_checksums(doubled), "crafted rig").status();
  EXPECT_EQ(status.code(), StatusCode::kDataLoss) << status.to_string();
  EXPECT_NE(status.message().find("holds section SKEL twice"), std::string::npos) << status.to_string();
}

// A label volume section whose geometry claims far more voxels than its compressed bytes can hold (deflate packs at
// most 1032:1) is refused before the volume is allocated, even with its checksums recomputed: a few KB cannot cost
// 8 GB.
TEST(RigFile, AVolumeSectionClaimingAHugeGridIsRefusedBeforeAllocating) {
  std::string bytes = rig_to_bytes(shared_bar_rig());
  const size_t at = bytes.find("LVOL");
  ASSERT_NE(at, std::string::npos);
  const size_t payload = at + 24;
  const int64_t big = 2000;
  for (size_t a = 0; a < 3; ++a) std::memcpy(bytes.data() + payload + 8 * a, &big, 8);
  // One chunk of all of them: after the grid (144 bytes), the source and the stored type.
  uint64_t chunks = 0;
  std::memcpy(&chunks, bytes.data() + payload + 160, 8);
  ASSERT_EQ(chunks, 1u);  // the bar's labels are one chunk
  const uint64_t all = uint64_t{2000} * 2000 * 2000;
  std::memcpy(bytes.data() + payload + 152, &all, 8);
  const Status status = rig_from_bytes(posewarp::testing::with_rig_checksums(bytes), "crafted rig").status();
  EXPECT_EQ(status.code(), StatusCode::kDataLoss) << status.to_string();
  EXPECT_NE(status.message().find("compressed bytes"), std::string::npos) << status.to_string();
}

// The engine's tables hold one value per voxel of the grid GEOM names: a grid claiming far more voxels than the
// label volume's bytes can hold is refused before a table is made (a few bytes of runs could otherwise ask for GBs).
TEST(RigFile, TablesOfAGridClaimingHugeSizesAreRefusedBeforeAllocating) {
  std::string bytes = rig_to_bytes(shared_bar_rig());
  const size_t at = bytes.find("GEOM");
  ASSERT_NE(at, std::string::npos);
  const int64_t big = 5000;
  for (size_t a = 0; a < 3; ++a) std::memcpy(bytes.data() + at + 24 + 8 * a, &big, 8);  // the size comes first
  const Status status = rig_from_bytes(posewarp::testing::with_rig_checksums(bytes), "crafted rig").status();
  EXPECT_EQ(status.code(), StatusCode::kDataLoss) << status.to_string();
  EXPECT_NE(status.message().find("more voxels than its label volume can hold"), std::string::npos)
      << status.to_string();
}

// A fixed-width array (tets: 4 columns) whose section declares another column count, checksums recomputed: Eigen
// sized the storage by 4 and the read by the file (a heap overflow found by fuzzing).
TEST(RigFile, AnArrayDeclaringTheWrongColumnCountIsRefused) {
  std::string bytes = rig_to_bytes(shared_bar_rig());
  const size_t at = bytes.find("TETS");
  ASSERT_NE(at, std::string::npos);
  const uint64_t cols = 5;
  std::memcpy(bytes.data() + at + 24 + 8, &cols, 8);  // after the row count
  const Status status = rig_from_bytes(posewarp::testing::with_rig_checksums(bytes), "crafted rig").status();
  EXPECT_EQ(status.code(), StatusCode::kDataLoss) << status.to_string();
  EXPECT_NE(status.message().find("5 columns where 4 belong"), std::string::npos) << status.to_string();
}

TEST(RigFile, BytesRoundTripEqualsTheFile) {
  ScratchDir dir;
  const Rig& rig = shared_bar_rig();
  ASSERT_TRUE(save_rig(rig, dir.file("bar.rig")).ok());
  const std::string bytes = rig_to_bytes(rig);
  EXPECT_EQ(bytes, read_bytes(dir.file("bar.rig")));
  Result<Rig> back = rig_from_bytes(bytes, "uploaded rig");
  ASSERT_TRUE(back.ok()) << back.status().to_string();
  EXPECT_EQ(content_hash(*back), content_hash(rig));
  const Status refused = rig_from_bytes(bytes.substr(0, 100), "uploaded rig").status();
  EXPECT_EQ(refused.code(), StatusCode::kDataLoss);
  EXPECT_NE(refused.message().find("uploaded rig"), std::string::npos) << refused.to_string();
}

TEST(RigFile, TwoRigsJoinedAreRefused) {
  ScratchDir dir;
  ASSERT_TRUE(save_rig(posewarp::testing::shared_bar_rig(), dir.file("bar.rig")).ok());
  const std::string bytes = read_bytes(dir.file("bar.rig"));
  write_bytes(dir.file("twice.rig"), bytes + bytes);
  const Status status = load_rig(dir.file("twice.rig")).status();
  EXPECT_EQ(status.code(), StatusCode::kDataLoss) << status.to_string();
  EXPECT_NE(status.message().find("after its end marker"), std::string::npos) << status.to_string();
}

}  // namespace
}  // namespace posewarp::api
