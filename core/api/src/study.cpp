// Study inspection and phantoms: the client-facing helpers of the facade.
#include "posewarp/api/study.h"
#include "posewarp/api/files.h"
#include "posewarp/api/rig.h"
#include "posewarp/common/atomic_file.h"
#include "posewarp/io/volume_io.h"
#include "posewarp/labels/body.h"
#include "posewarp/labels/label_map.h"
#include "posewarp/phantom/phantom.h"

#include <filesystem>
#include <fstream>


namespace posewarp::api {

Result<Phantom> make_bar(const BarParams& params) { return phantom::make_bar(params); }

Result<Phantom> make_mannequin(const MannequinParams& params) { return phantom::make_mannequin(params); }

Result<Phantom> make_body(const BodyParams& params) { return phantom::make_body(params); }

double mannequin_spacing_for_voxels(const MannequinParams& params, int64_t target_voxels) {
  return phantom::mannequin_spacing_for_voxels(params, target_voxels);
}

Vec3 body_spacing_for_voxels(const BodyParams& params, int64_t target_voxels) {
  return phantom::body_spacing_for_voxels(params, target_voxels);
}

Result<StudyInspection> inspect_study(const LabelVolume& labels, const IntensityVolume* ct, const labels::LabelMap& map,
                                      const labels::BodyParams& params) {
  StudyInspection study;
  POSEWARP_ASSIGN_OR_RETURN(study.body, labels::body_mask(map, labels, ct, params));
  study.census = labels::census(map, labels);
  study.classes = labels::segment_classes(map, labels, study.body);
  const std::vector<std::string> segments = map.bone_segments();
  std::vector<BoneSegmentSummary> all(segments.size());
  const ImageGeometry& g = labels.geometry();
  const double voxel_ml = g.spacing[0] * g.spacing[1] * g.spacing[2] / 1000.0;
  for (int64_t k = 0; k < g.size[2]; ++k) {
    for (int64_t j = 0; j < g.size[1]; ++j) {
      for (int64_t i = 0; i < g.size[0]; ++i) {
        const Label c = study.classes.at(i, j, k);
        if (c < 2) continue;
        BoneSegmentSummary& s = all[static_cast<size_t>(c - 2)];
        const Vec3 p = g.index_to_physical({static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)});
        ++s.voxels;
        s.centroid_mm += Eigen::Vector3d(p[0], p[1], p[2]);
      }
    }
  }
  for (size_t s = 0; s < all.size(); ++s) {
    if (all[s].voxels == 0) continue;
    all[s].segment = segments[s];
    all[s].mesher_class = static_cast<int>(2 + s);
    all[s].volume_ml = static_cast<double>(all[s].voxels) * voxel_ml;
    all[s].centroid_mm /= static_cast<double>(all[s].voxels);
    study.bones.push_back(all[s]);
  }
  for (const Label v : study.body.voxels()) study.body_voxels += v != 0;
  study.body_volume_ml = static_cast<double>(study.body_voxels) * voxel_ml;
  return study;
}

Result<std::vector<std::string>> write_phantom(const Phantom& phantom, const std::string& dir,
                                               const std::string& extension) {
  namespace fs = std::filesystem;
  std::error_code ec;
  fs::create_directories(dir, ec);
  if (ec) return invalid_argument_error("cannot create " + dir + ": " + ec.message());
  const fs::path base(dir);
  const std::vector<std::string> written{(base / ("labels" + extension)).string(), (base / ("ct" + extension)).string(),
                                         (base / "label_map.json").string(), (base / "joints.json").string()};
  POSEWARP_RETURN_IF_ERROR(io::write_volume(phantom.labels, written[0]));
  POSEWARP_RETURN_IF_ERROR(io::write_volume(phantom.ct, written[1]));
  POSEWARP_RETURN_IF_ERROR(labels::write_label_map(phantom.label_map, written[2]));
  POSEWARP_RETURN_IF_ERROR(write_file_atomically(written[3], phantom::joints_to_json(phantom), "joint truth"));
  return written;
}

}  // namespace posewarp::api
