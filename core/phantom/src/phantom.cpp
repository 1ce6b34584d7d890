// The bar and mannequin phantoms: label volumes, CTs, label maps and true joint centres; the joints JSON.
#include "posewarp/phantom/phantom.h"

#include <nlohmann/json.hpp>

#include <algorithm>
#include <array>
#include <cmath>
#include <string>

#include "raster.h"
#include "support.h"

namespace posewarp::phantom {
namespace {

using detail::check_positive;
using detail::check_size;
using detail::kAirHu;
using detail::kBoneHu;
using detail::kBrainHu;
using detail::kFatHu;
using detail::kLiverHu;
using detail::kSoftHu;
using detail::Shape;
using detail::validate_direction;
using labels::JointName;
using labels::LabelEntry;
using labels::LabelRole;

ImageGeometry grid_for(const std::vector<Shape>& shapes, double spacing, const std::array<double, 9>& direction,
                       double margin) {
  return detail::grid_for(shapes, Vec3{spacing, spacing, spacing}, direction, margin);
}

// ---- mannequin layout -------------------------------------------------------------------------------------------

namespace mannequin_labels {
constexpr Label kSoft = detail::kSoftLabel, kFat = detail::kFatLabel, kLiver = detail::kLiverLabel,
                kBrain = detail::kBrainLabel;
constexpr Label kPelvis = 10, kL5 = 11, kL4 = 12, kL3 = 13, kL2 = 14, kL1 = 15;
constexpr Label kThoracicSpine = 16, kRibs = 17, kShoulderGirdle = 18;
constexpr Label kFemurLeft = 20, kFemurRight = 21, kTibiaLeft = 22, kTibiaRight = 23;
constexpr Label kHumerusLeft = 24, kHumerusRight = 25, kForearmLeft = 26, kForearmRight = 27;
constexpr Label kSkull = 30, kCervicalSpine = 31;
}  // namespace mannequin_labels

// Every length of the mannequin, in mm at the requested height.
struct MannequinLayout {
  double f;    // scale: height / 1700 mm
  double gap;  // joint gap, mm
  double z(double mm_at_1700) const { return mm_at_1700 * f; }

  Vec3 hip(int side) const { return {side * 90 * f, 0.0, 900 * f}; }        // side: +1 left, -1 right
  Vec3 knee(int side) const { return {side * 90 * f, 0.0, 480 * f}; }
  Vec3 shoulder(int side) const { return {side * 215 * f, 0.0, 1390 * f}; }
  Vec3 elbow(int side) const { return {side * 215 * f, 0.0, 1110 * f}; }
  double spine_y() const { return 45 * f; }
  double pelvis_top() const { return 990 * f; }
  double vertebra_height() const { return 30 * f; }
  // Bottom of lumbar vertebra n (0 = L5 ... 4 = L1).
  double lumbar_bottom(int n) const { return pelvis_top() + gap + n * (vertebra_height() + gap); }
  double thoracic_bottom() const { return lumbar_bottom(5); }
  double thoracic_top() const { return 1420 * f; }
  double head_radius() const { return 100 * f; }
  Vec3 head_centre() const { return {0.0, 0.0, 1600 * f}; }
};

std::vector<Shape> mannequin_body(const MannequinLayout& m) {
  const double f = m.f;
  std::vector<Shape> body;
  body.push_back(detail::elliptic_cylinder_z(0, 0, 160 * f, 110 * f, 850 * f, 1440 * f));  // trunk
  body.push_back(detail::capsule({-215 * f, 0, 1395 * f}, {215 * f, 0, 1395 * f}, 58 * f));  // shoulders
  body.push_back(detail::capsule({0, 0, 1420 * f}, {0, 0, 1530 * f}, 55 * f));              // neck
  body.push_back(detail::sphere(m.head_centre(), m.head_radius()));
  for (int side : {+1, -1}) {
    body.push_back(detail::capsule(m.hip(side), m.knee(side), 75 * f));                            // thigh
    body.push_back(detail::capsule(m.knee(side), {side * 90 * f, 0, 60 * f}, 55 * f));             // shank
    body.push_back(detail::capsule(m.shoulder(side), m.elbow(side), 45 * f));                      // upper arm
    body.push_back(detail::capsule(m.elbow(side), {side * 215 * f, 0, 840 * f}, 38 * f));          // forearm
  }
  return body;
}

// Paints the pelvis, the lumbar and thoracic spine, the rib shell and the shoulder girdle.
void paint_mannequin_trunk(LabelVolume& labels, const MannequinLayout& m) {
  namespace L = mannequin_labels;
  const double f = m.f;
  // Pelvis: a block whose lower face passes through both hip centres, with hemispherical sockets.
  detail::paint(labels, detail::box({-125 * f, -30 * f, m.hip(1)[2]}, {125 * f, 55 * f, m.pelvis_top()}), L::kPelvis);
  // Sacral block under the spine, so the lumbosacral contact is the whole lower face of L5.
  detail::paint(labels, detail::box({-40 * f, 20 * f, m.hip(1)[2]}, {40 * f, 75 * f, m.pelvis_top()}), L::kPelvis);
  // Lumbar vertebrae L5 (n = 0) up to L1 (n = 4), then the thoracic spine.
  const Label lumbar[5] = {L::kL5, L::kL4, L::kL3, L::kL2, L::kL1};
  for (int n = 0; n < 5; ++n) {
    const double z0 = m.lumbar_bottom(n);
    detail::paint(labels, detail::cylinder({0, m.spine_y(), z0}, {0, m.spine_y(), z0 + m.vertebra_height()}, 22 * f),
                  lumbar[n]);
  }
  detail::paint(labels,
                detail::cylinder({0, m.spine_y(), m.thoracic_bottom()}, {0, m.spine_y(), m.thoracic_top()}, 22 * f),
                L::kThoracicSpine);
  // Rib shell joined to the thoracic spine by a posterior bar.
  {
    const double z0 = m.thoracic_bottom() + 10 * f;
    const double z1 = 1400 * f;
    detail::paint(labels, detail::elliptic_cylinder_z(0, 0, 140 * f, 95 * f, z0, z1), L::kRibs);
    detail::paint(labels, detail::elliptic_cylinder_z(0, 0, 132 * f, 87 * f, z0 - 1, z1 + 1), L::kSoft);
    detail::paint(labels, detail::box({-10 * f, m.spine_y(), z0}, {10 * f, 90 * f, z1}), L::kRibs);
  }
  // Shoulder girdle: a bar across the upper chest ending in glenoid domes over the shoulder centres.
  detail::paint(labels, detail::capsule({-175 * f, 20 * f, 1395 * f}, {175 * f, 20 * f, 1395 * f}, 14 * f),
                L::kShoulderGirdle);
  for (int side : {+1, -1}) {
    Shape dome = detail::sphere(m.shoulder(side), 22 * f + m.gap + 12 * f);
    dome.clip_min[2] = m.shoulder(side)[2];
    detail::paint(labels, dome, L::kShoulderGirdle);
  }
}

// Paints the skull with the brain inside and the cervical spine below it.
void paint_mannequin_head(LabelVolume& labels, const MannequinLayout& m) {
  namespace L = mannequin_labels;
  const double f = m.f;
  // Cervical spine fused to the skull; brain inside.
  detail::paint(labels, detail::sphere(m.head_centre(), 92 * f), L::kSkull);
  detail::paint(labels, detail::sphere(m.head_centre(), 84 * f), L::kBrain);
  detail::paint(labels,
                detail::cylinder({0, m.spine_y(), m.thoracic_top() + m.gap},
                                 {0, m.spine_y(), m.head_centre()[2] - 80 * f}, 18 * f),
                L::kCervicalSpine);
}

// A limb of the mannequin: a ball joint at `proximal` (the head's radius), the upper bone's shaft to the gap at
// `middle`, the lower bone from there to `end`.
struct MannequinLimb {
  Vec3 proximal;
  double head_radius;
  double upper_radius;
  Label upper;
  Vec3 middle;
  Vec3 end;
  double lower_radius;
  Label lower;
};

// Paints a limb: the socket carved into soft tissue around the head, the head, the upper shaft to the middle gap and
// the lower bone below it.
void paint_mannequin_limb(LabelVolume& labels, const MannequinLimb& limb, double gap) {
  detail::paint(labels, detail::sphere(limb.proximal, limb.head_radius + gap), mannequin_labels::kSoft);
  detail::paint(labels, detail::sphere(limb.proximal, limb.head_radius), limb.upper);
  const Vec3 upper_end{limb.middle[0], 0, limb.middle[2] + gap / 2};
  detail::paint(labels, detail::cylinder(limb.proximal, upper_end, limb.upper_radius), limb.upper);
  detail::paint(labels, detail::cylinder({limb.middle[0], 0, limb.middle[2] - gap / 2}, limb.end, limb.lower_radius),
                limb.lower);
}

// The leg and the arm of one side (+1 left, -1 right): the hip socket carved into the pelvis, the femur and the
// tibia; the shoulder socket carved into the dome, the humerus and the forearm.
std::array<MannequinLimb, 2> mannequin_limbs(const MannequinLayout& m, int side) {
  namespace L = mannequin_labels;
  const double f = m.f;
  const bool left = side > 0;
  return {{{m.hip(side), 24 * f, 16 * f, left ? L::kFemurLeft : L::kFemurRight, m.knee(side),
            {side * 90 * f, 0, 80 * f}, 15 * f, left ? L::kTibiaLeft : L::kTibiaRight},
           {m.shoulder(side), 22 * f, 14 * f, left ? L::kHumerusLeft : L::kHumerusRight, m.elbow(side),
            {side * 215 * f, 0, 860 * f}, 12 * f, left ? L::kForearmLeft : L::kForearmRight}}};
}

// The mannequin's label map entries: background, tissues, then every bone with the segment it belongs to.
std::vector<LabelEntry> mannequin_label_entries() {
  namespace L = mannequin_labels;
  std::vector<LabelEntry> entries = detail::tissue_entries();
  entries.push_back({L::kPelvis, "pelvis", LabelRole::kBone, "pelvis"});
  for (LabelEntry& entry : detail::lumbar_entries(L::kL5)) entries.push_back(std::move(entry));
  entries.insert(entries.end(), {
      {L::kThoracicSpine, "thoracic_spine", LabelRole::kBone, "thorax"},
      {L::kRibs, "ribs", LabelRole::kBone, "thorax"},
      {L::kShoulderGirdle, "shoulder_girdle", LabelRole::kBone, "thorax"},
      {L::kFemurLeft, "femur_left", LabelRole::kBone, "femur_left"},
      {L::kFemurRight, "femur_right", LabelRole::kBone, "femur_right"},
      {L::kTibiaLeft, "tibia_left", LabelRole::kBone, "tibia_left"},
      {L::kTibiaRight, "tibia_right", LabelRole::kBone, "tibia_right"},
      {L::kHumerusLeft, "humerus_left", LabelRole::kBone, "humerus_left"},
      {L::kHumerusRight, "humerus_right", LabelRole::kBone, "humerus_right"},
      {L::kForearmLeft, "forearm_left", LabelRole::kBone, "forearm_left"},
      {L::kForearmRight, "forearm_right", LabelRole::kBone, "forearm_right"},
      {L::kSkull, "skull", LabelRole::kBone, "skull"},
      {L::kCervicalSpine, "cervical_spine", LabelRole::kBone, "skull"},
  });
  return entries;
}

// Appends the true joints: the spine from lumbosacral to neck, then hips, knees, shoulders and elbows, left first.
void add_mannequin_joints(const MannequinLayout& m, std::vector<JointTruth>& joints) {
  const double gap = m.gap;
  const double y = m.spine_y();
  auto spine_joint = [&](const std::string& name, const std::string& parent, const std::string& child, double z) {
    joints.push_back({name, parent, child, {0.0, y, z}, "plane"});
  };
  spine_joint("lumbosacral", "pelvis", "vertebrae_L5", m.pelvis_top() + gap / 2);
  const char* lumbar_names[5] = {"vertebrae_L5", "vertebrae_L4", "vertebrae_L3", "vertebrae_L2", "vertebrae_L1"};
  const char* lumbar_joints[4] = {"L4_L5", "L3_L4", "L2_L3", "L1_L2"};
  for (int n = 1; n < 5; ++n) {
    spine_joint(lumbar_joints[n - 1], lumbar_names[n - 1], lumbar_names[n], m.lumbar_bottom(n) - gap / 2);
  }
  spine_joint("thoracolumbar", "vertebrae_L1", "thorax", m.thoracic_bottom() - gap / 2);
  spine_joint("neck", "thorax", "skull", m.thoracic_top() + gap / 2);
  for (int side : {+1, -1}) {
    const std::string s = side > 0 ? "left" : "right";
    joints.push_back({"hip_" + s, "pelvis", "femur_" + s, m.hip(side), "ball"});
    joints.push_back({"knee_" + s, "femur_" + s, "tibia_" + s, m.knee(side), "plane"});
    joints.push_back({"shoulder_" + s, "thorax", "humerus_" + s, m.shoulder(side), "ball"});
    joints.push_back({"elbow_" + s, "humerus_" + s, "forearm_" + s, m.elbow(side), "plane"});
  }
}

// The label map's joint names for the true joints: balls and planes, knees flexing backwards, the rest forwards.
std::vector<JointName> joint_names_of(const std::vector<JointTruth>& joints) {
  std::vector<JointName> joint_names;
  for (const JointTruth& joint : joints) {
    const bool ball = joint.kind == "ball";
    const bool knee = joint.name.rfind("knee", 0) == 0;
    joint_names.push_back({joint.name, joint.parent_segment, joint.child_segment,
                           ball ? labels::JointKind::kBall : labels::JointKind::kPlane,
                           knee ? labels::FlexionDirection::kPosterior : labels::FlexionDirection::kAnterior});
  }
  return joint_names;
}

}  // namespace

Status validate(const BarParams& p) {
  POSEWARP_RETURN_IF_ERROR(check_positive(p.spacing_mm, "bar spacing_mm"));
  POSEWARP_RETURN_IF_ERROR(check_positive(p.length_mm, "bar length_mm"));
  POSEWARP_RETURN_IF_ERROR(check_positive(p.radius_mm, "bar radius_mm"));
  POSEWARP_RETURN_IF_ERROR(check_positive(p.bone_radius_mm, "bar bone_radius_mm"));
  if (p.bone_radius_mm >= p.radius_mm) {
    return invalid_argument_error("bar bone_radius_mm must be smaller than radius_mm so soft tissue surrounds bone");
  }
  if (p.bone_count < 2 || p.bone_count > 16) {
    return invalid_argument_error("bar bone_count must lie in 2..16 (got " + std::to_string(p.bone_count) + ")");
  }
  if (p.joint_gap_mm < 0.0 || p.margin_mm < 0.0 || p.noise_hu < 0.0) {
    return invalid_argument_error("bar joint_gap_mm, margin_mm and noise_hu must not be negative");
  }
  const double gap = p.joint_gap_mm > 0.0 ? p.joint_gap_mm : 2.0 * p.spacing_mm;
  const double bone_length = (p.length_mm - 2.0 * gap - (p.bone_count - 1) * gap) / p.bone_count;
  if (bone_length < 2.0 * p.spacing_mm) {
    return invalid_argument_error("bar bones would be shorter than two voxels; lengthen the bar or use fewer bones");
  }
  return validate_direction(p.direction);
}

Status validate(const MannequinParams& p) {
  POSEWARP_RETURN_IF_ERROR(check_positive(p.spacing_mm, "mannequin spacing_mm"));
  POSEWARP_RETURN_IF_ERROR(check_positive(p.height_mm, "mannequin height_mm"));
  if (p.height_mm < 200.0 || p.height_mm > 3000.0) {
    return invalid_argument_error("mannequin height_mm must lie in 200..3000 (got " + std::to_string(p.height_mm) + ")");
  }
  if (p.joint_gap_mm < 0.0 || p.fat_mm < 0.0 || p.margin_mm < 0.0 || p.noise_hu < 0.0) {
    return invalid_argument_error("mannequin joint_gap_mm, fat_mm, margin_mm and noise_hu must not be negative");
  }
  const double f = p.height_mm / 1700.0;
  const double gap = p.joint_gap_mm > 0.0 ? p.joint_gap_mm : 2.0 * p.spacing_mm;
  if (gap > 25.0 * f) {
    return invalid_argument_error("mannequin joint gap of " + std::to_string(gap) +
                                  " mm is too wide for its size; use a finer spacing or a smaller joint_gap_mm");
  }
  if (p.spacing_mm > 14.0 * f) {
    return invalid_argument_error("mannequin spacing of " + std::to_string(p.spacing_mm) +
                                  " mm is too coarse to resolve its bones; use at most " + std::to_string(14.0 * f) +
                                  " mm");
  }
  return validate_direction(p.direction);
}

Result<Phantom> make_bar(const BarParams& p) {
  POSEWARP_RETURN_IF_ERROR(validate(p));
  const double gap = p.joint_gap_mm > 0.0 ? p.joint_gap_mm : 2.0 * p.spacing_mm;
  // Bones fill the axis from gap to length - gap, with `gap` of soft tissue between neighbours.
  const double bone_length = (p.length_mm - 2.0 * gap - (p.bone_count - 1) * gap) / p.bone_count;

  Phantom phantom;
  phantom.name = "bar";
  phantom.joint_gap_mm = gap;
  const Shape body = detail::cylinder({0, 0, 0}, {0, 0, p.length_mm}, p.radius_mm);
  const ImageGeometry grid = grid_for({body}, p.spacing_mm, p.direction, p.margin_mm);
  POSEWARP_RETURN_IF_ERROR(check_size(grid));
  phantom.labels = LabelVolume(grid, 0);
  phantom.labels.set_source_type(PixelType::kUInt8);
  detail::paint(phantom.labels, body, 1);

  std::vector<LabelEntry> entries{{0, "background", LabelRole::kBackground, ""}, {1, "soft_tissue", LabelRole::kTissue, ""}};
  std::vector<JointName> joint_names;
  std::vector<std::pair<Label, float>> hu{{1, kSoftHu}};
  for (int b = 0; b < p.bone_count; ++b) {
    const Label value = static_cast<Label>(10 + b);
    const std::string segment = "bar_bone_" + std::to_string(b + 1);
    const double z0 = gap + b * (bone_length + gap);
    detail::paint(phantom.labels, detail::cylinder({0, 0, z0}, {0, 0, z0 + bone_length}, p.bone_radius_mm), value);
    entries.push_back({value, segment, LabelRole::kBone, segment});
    hu.emplace_back(value, kBoneHu);
    if (b > 0) {
      const std::string parent = "bar_bone_" + std::to_string(b);
      const std::string name = "joint_" + std::to_string(b) + "_" + std::to_string(b + 1);
      joint_names.push_back({name, parent, segment});
      phantom.joints.push_back({name, parent, segment, {0.0, 0.0, z0 - 0.5 * gap}, "plane"});
    }
  }
  phantom.root_segment = "bar_bone_1";
  POSEWARP_ASSIGN_OR_RETURN(phantom.label_map,
                            labels::LabelMap::create("bar_phantom", std::move(entries), std::move(joint_names),
                                                     phantom.root_segment));
  phantom.ct = detail::synthesize_ct(phantom.labels, hu, kAirHu, p.noise_hu, p.seed);
  return phantom;
}

double mannequin_spacing_for_voxels(const MannequinParams& params, int64_t target_voxels) {
  const MannequinLayout layout{params.height_mm / 1700.0, 0.0};
  const ImageGeometry g = grid_for(mannequin_body(layout), 1.0, params.direction, params.margin_mm);
  const double volume_mm3 = static_cast<double>(g.voxel_count());
  return std::cbrt(volume_mm3 / static_cast<double>(std::max<int64_t>(1, target_voxels)));
}

Result<Phantom> make_mannequin(const MannequinParams& p) {
  namespace L = mannequin_labels;
  POSEWARP_RETURN_IF_ERROR(validate(p));
  const double f = p.height_mm / 1700.0;
  const double gap = p.joint_gap_mm > 0.0 ? p.joint_gap_mm : 2.0 * p.spacing_mm;
  const MannequinLayout m{f, gap};

  Phantom phantom;
  phantom.name = "mannequin";
  phantom.joint_gap_mm = gap;
  const std::vector<Shape> body = mannequin_body(m);
  const ImageGeometry grid = grid_for(body, p.spacing_mm, p.direction, p.margin_mm);
  POSEWARP_RETURN_IF_ERROR(check_size(grid));
  LabelVolume& labels = phantom.labels;
  labels = LabelVolume(grid, 0);
  labels.set_source_type(PixelType::kUInt8);

  // Later paints win: body with its fat shell, organs, bones, then soft joint spaces carved, then the balls.
  detail::paint_body(labels, body, L::kSoft, L::kFat, p.fat_mm * f);
  detail::paint(labels, detail::ellipsoid({-70 * f, -10 * f, 1120 * f}, {60 * f, 55 * f, 50 * f}), L::kLiver);
  paint_mannequin_trunk(labels, m);
  paint_mannequin_head(labels, m);
  for (int side : {+1, -1}) {
    for (const MannequinLimb& limb : mannequin_limbs(m, side)) paint_mannequin_limb(labels, limb, m.gap);
  }

  add_mannequin_joints(m, phantom.joints);
  phantom.root_segment = "pelvis";
  POSEWARP_ASSIGN_OR_RETURN(phantom.label_map,
                            labels::LabelMap::create("mannequin_phantom", mannequin_label_entries(),
                                                     joint_names_of(phantom.joints), phantom.root_segment));

  std::vector<std::pair<Label, float>> hu{{L::kSoft, kSoftHu}, {L::kFat, kFatHu}, {L::kLiver, kLiverHu},
                                          {L::kBrain, kBrainHu}};
  for (const LabelEntry& entry : phantom.label_map.entries()) {
    if (entry.role == LabelRole::kBone) hu.emplace_back(entry.value, kBoneHu);
  }
  phantom.ct = detail::synthesize_ct(labels, hu, kAirHu, p.noise_hu, p.seed);
  return phantom;
}

std::string joints_to_json(const Phantom& phantom) {
  nlohmann::json doc;
  doc["phantom"] = phantom.name;
  doc["root_segment"] = phantom.root_segment;
  doc["joint_gap_mm"] = phantom.joint_gap_mm;
  doc["space"] = "LPS, mm";
  nlohmann::json joints = nlohmann::json::array();
  for (const JointTruth& joint : phantom.joints) {
    nlohmann::json entry{{"name", joint.name},
                         {"parent", joint.parent_segment},
                         {"child", joint.child_segment},
                         {"centre_mm", {joint.centre_mm[0], joint.centre_mm[1], joint.centre_mm[2]}},
                         {"kind", joint.kind}};
    if (joint.axis != Vec3{0.0, 0.0, 0.0}) entry["axis"] = {joint.axis[0], joint.axis[1], joint.axis[2]};
    joints.push_back(std::move(entry));
  }
  doc["joints"] = std::move(joints);
  nlohmann::json contacts = nlohmann::json::array();
  for (const auto& [a, b] : phantom.skin_contacts) contacts.push_back({a, b});
  doc["skin_contacts"] = std::move(contacts);
  return doc.dump(2) + "\n";
}

}  // namespace posewarp::phantom
