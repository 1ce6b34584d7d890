// LabelMap: what each label value of a segmentation is (bone of which rigid segment, soft tissue, background), the
// joints it declares, and what a label volume holds against it. Its JSON form and presets: labels/.
#pragma once

#include <cstdint>
#include <map>
#include <optional>
#include <string>
#include <string_view>
#include <vector>

#include "posewarp/common/result.h"
#include "posewarp/common/volume.h"

namespace posewarp {

enum class LabelRole {
  kBackground,  // outside the body
  kBone,        // rigid: moves with its segment
  kTissue,      // soft: moves with the deformation field
  kIgnore,      // inside the body but not used to build the rig (e.g. a table or an implant label)
};

std::string_view role_name(LabelRole role);
Result<LabelRole> role_from_name(std::string_view name);

struct LabelEntry {
  Label value = 0;
  std::string name;
  LabelRole role = LabelRole::kTissue;
  // For bones: the rigid segment the label belongs to (several labels may form one segment). Empty otherwise.
  std::string segment;
};

// What kind of articulation a joint is; it decides how the rig finds its centre (and, for hinges, its axis).
enum class JointKind {
  kUnspecified,  // a sphere fit where a ball sits in a socket, else the contact centroid
  kBall,         // a head in a socket (hip, shoulder): the centre of a sphere fitted to the head
  kHinge,        // condyles or a trochlea (knee, elbow, ankle): the axis of a cylinder fitted to the convex side
  kPlane,        // flat or irregular surfaces (spine, sacroiliac, acromioclavicular): the contact centroid
};

// Which way positive flexion moves the child's far end from the rest pose, in the patient's axes. Hip, shoulder,
// elbow, spine and neck flex forward (anterior), the knee bends the heel back (posterior), the ankle dorsiflexes the
// toes up (superior).
enum class FlexionDirection { kAnterior, kPosterior, kSuperior, kInferior };

std::string_view joint_kind_name(JointKind kind);
Result<JointKind> joint_kind_from_name(std::string_view name);
std::string_view flexion_direction_name(FlexionDirection direction);
Result<FlexionDirection> flexion_direction_from_name(std::string_view name);

// A joint the map declares between two segments: its name, and for the automatic skeleton the anatomical
// parent -> child order (the tree takes declared joints first, in the map's order, whenever both segments are
// present; a declared joint that would close a loop is an alternative and is skipped), its kind and flexion sense.
struct JointName {
  std::string name;
  std::string segment_a;  // the parent, nearer the root
  std::string segment_b;  // the child
  JointKind kind = JointKind::kUnspecified;
  FlexionDirection flexion = FlexionDirection::kAnterior;
};

class LabelMap {
 public:
  LabelMap() = default;

  // Builds and validates a map: values unique, names non-empty, bones with a segment (defaulting to the
  // label's name), value 0 only as background, joint names only between known segments.
  static Result<LabelMap> create(std::string name, std::vector<LabelEntry> entries,
                                 std::vector<JointName> joint_names = {}, std::string root_segment = {});

  const std::string& name() const { return name_; }
  const std::vector<LabelEntry>& entries() const { return entries_; }
  const std::vector<JointName>& joint_names() const { return joint_names_; }
  // Preferred root of the skeleton; empty lets the rig choose.
  const std::string& root_segment() const { return root_segment_; }

  // The entry of a value, or nullptr when the map does not name it.
  const LabelEntry* find(Label value) const;
  // The role of a value; values the map does not name are soft tissue (and reported by census()).
  LabelRole role_of(Label value) const;

  // Bone segments in the order they first appear in the map.
  std::vector<std::string> bone_segments() const;
  // The label values that make up one bone segment.
  std::vector<Label> labels_of_segment(std::string_view segment) const;
  // The joint name the map gives to a pair of segments, if any.
  std::optional<std::string> joint_name(std::string_view segment_a, std::string_view segment_b) const;
  // The joint the map declares between two segments (either order), or nullptr.
  const JointName* declared_joint(std::string_view segment_a, std::string_view segment_b) const;

 private:
  std::string name_;
  std::vector<LabelEntry> entries_;
  std::vector<JointName> joint_names_;
  std::string root_segment_;
  std::map<Label, size_t> index_;
};

// What a label volume holds compared with its map.
struct LabelCensus {
  std::map<Label, int64_t> voxel_counts;  // every value present, with its voxel count (0 included)
  std::vector<Label> unknown;             // present in the volume, not named by the map
  std::vector<Label> absent;              // named by the map (non-background), not present in the volume
  std::vector<std::string> present_bone_segments;
  std::vector<std::string> absent_bone_segments;  // bone segments none of whose labels is present
};

}  // namespace posewarp
