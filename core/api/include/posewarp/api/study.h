// What a study holds before a rig is built (posewarp inspect), and the synthetic studies (phantoms).
#pragma once

#include <Eigen/Core>

#include <string>
#include <vector>

#include "posewarp/common/label_map.h"
#include "posewarp/common/phantom.h"
#include "posewarp/common/result.h"
#include "posewarp/common/rig_params.h"
#include "posewarp/common/volume.h"

namespace posewarp::api {

struct BoneSegmentSummary {
  std::string segment;
  int mesher_class = 0;  // 2 + k in the class volume
  int64_t voxels = 0;
  double volume_ml = 0.0;
  Eigen::Vector3d centroid_mm = Eigen::Vector3d::Zero();  // LPS
};

struct StudyInspection {
  LabelVolume body;                // 1 inside the body
  LabelVolume classes;             // the mesher's input: 0 outside, 1 soft tissue, 2 + k bone segment k
  LabelCensus census;
  std::vector<BoneSegmentSummary> bones;  // the map's bone segments present in the study
  int64_t body_voxels = 0;
  double body_volume_ml = 0.0;
};

// Body mask, mesher classes, census and per-segment summary of a segmentation (and its CT, may be null).
Result<StudyInspection> inspect_study(const LabelVolume& labels, const IntensityVolume* ct, const LabelMap& map,
                                      const BodyMaskParams& params);

// The body mask's knobs (api::BodyParams is the body phantom's).
using posewarp::BodyMaskParams;

// Phantoms (phantom/): a bar of bones, a mannequin and a realistic body, with their joints known by construction.
using posewarp::BarParams;
using BodyParams = posewarp::BodyPhantomParams;
using posewarp::MannequinParams;
using posewarp::Phantom;
Result<Phantom> make_bar(const BarParams& params);
Result<Phantom> make_mannequin(const MannequinParams& params);
Result<Phantom> make_body(const BodyParams& params);
// The spacing that gives a phantom about `target_voxels` voxels.
double mannequin_spacing_for_voxels(const MannequinParams& params, int64_t target_voxels);
Vec3 body_spacing_for_voxels(const BodyParams& params, int64_t target_voxels);

// Writes labels<extension>, ct<extension>, label_map.json and joints.json into `dir` (created if needed) and
// returns the paths written.
Result<std::vector<std::string>> write_phantom(const Phantom& phantom, const std::string& dir,
                                               const std::string& extension);

}  // namespace posewarp::api
