// What a study holds before a rig is built (posewarp inspect), and the synthetic studies (phantoms).
#pragma once

#include <Eigen/Core>

#include <string>
#include <vector>

#include "posewarp/labels/body.h"
#include "posewarp/labels/label_map.h"
#include "posewarp/phantom/phantom.h"

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
  labels::LabelCensus census;
  std::vector<BoneSegmentSummary> bones;  // the map's bone segments present in the study
  int64_t body_voxels = 0;
  double body_volume_ml = 0.0;
};

// Body mask, mesher classes, census and per-segment summary of a segmentation (and its CT, may be null).
Result<StudyInspection> inspect_study(const LabelVolume& labels, const IntensityVolume* ct, const labels::LabelMap& map,
                                      const labels::BodyParams& params);

// The body mask's knobs (api::BodyParams is the body phantom's), and what a label volume holds.
using BodyMaskParams = labels::BodyParams;
using labels::LabelCensus;

using phantom::BarParams;
using phantom::body_grid;
using phantom::body_spacing_for_voxels;
using phantom::BodyParams;
using phantom::make_bar;
using phantom::make_body;
using phantom::make_mannequin;
using phantom::mannequin_spacing_for_voxels;
using phantom::MannequinParams;
using phantom::Phantom;
using phantom::rotation_direction;

// Writes labels<extension>, ct<extension>, label_map.json and joints.json into `dir` (created if needed) and
// returns the paths written.
Result<std::vector<std::string>> write_phantom(const Phantom& phantom, const std::string& dir,
                                               const std::string& extension);

}  // namespace posewarp::api
