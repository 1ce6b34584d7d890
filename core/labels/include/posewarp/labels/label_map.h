// Label maps in files: the JSON form, relabelling by segment names (DICOM SEG) and the census of a label volume.
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "posewarp/common/label_map.h"
#include "posewarp/common/result.h"
#include "posewarp/common/volume.h"

namespace posewarp::labels {

// The map itself is vocabulary (posewarp/common/label_map.h); its JSON form, presets and census are
// this stage's.
using posewarp::FlexionDirection;
using posewarp::flexion_direction_from_name;
using posewarp::flexion_direction_name;
using posewarp::joint_kind_from_name;
using posewarp::joint_kind_name;
using posewarp::JointKind;
using posewarp::JointName;
using posewarp::LabelCensus;
using posewarp::LabelEntry;
using posewarp::LabelMap;
using posewarp::LabelRole;
using posewarp::role_from_name;
using posewarp::role_name;

// JSON form:
// {"format": "posewarp.label_map", "version": 1, "name": "...", "root_segment": "sacrum",
//  "labels": [{"value": 75, "name": "femur_left", "role": "bone", "segment": "femur_left"}, ...],
//  "joints": [{"name": "hip_left", "parent": "hip_left", "child": "femur_left", "kind": "ball",
//              "flexion": "anterior"}, ...]}
// A joint may give "segments": [parent, child] instead of "parent" and "child"; "kind" (ball, hinge, plane) and
// "flexion" (anterior, posterior, superior, inferior) are optional.
// `source` names the text's origin (a file path) in error messages.
Result<LabelMap> label_map_from_json(std::string_view json_text, std::string_view source);
std::string label_map_to_json(const LabelMap& map);

Result<LabelMap> read_label_map(const std::string& path);
Status write_label_map(const LabelMap& map, const std::string& path);

// `map` with its values replaced by the values that `names` give the same names (a DICOM SEG numbers its segments
// 1, 2, 3, ... and names them): names compare without case, with spaces, hyphens and underscores alike. A name the
// map does not know becomes a soft-tissue entry; the map's entries no name refers to are dropped, and so are its
// joints between segments that are gone. `unknown` (optional) receives the names the map did not know.
Result<LabelMap> relabel_by_name(const LabelMap& map, const std::vector<std::pair<Label, std::string>>& names,
                                 std::vector<std::string>* unknown = nullptr);

// What a label volume holds compared with its map.
LabelCensus census(const LabelMap& map, const LabelVolume& volume);

}  // namespace posewarp::labels
