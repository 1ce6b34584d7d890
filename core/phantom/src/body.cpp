// The body phantom: a supine whole body with arms against the trunk, touching thighs, hinge knees, elbows and
// ankles, a shoulder girdle on the rib shell, and exact joint truth.
#include "posewarp/phantom/phantom.h"

#include <algorithm>
#include <array>
#include <cmath>
#include <string>
#include <utility>

#include "raster.h"
#include "support.h"

namespace posewarp::phantom {
namespace {

using detail::Shape;
using labels::JointName;
using labels::LabelEntry;
using labels::LabelRole;

constexpr double kPi = 3.14159265358979323846;

Vec3 add(const Vec3& u, const Vec3& v) {
  return {u[0] + v[0], u[1] + v[1], u[2] + v[2]};
}
Vec3 sub(const Vec3& u, const Vec3& v) {
  return {u[0] - v[0], u[1] - v[1], u[2] - v[2]};
}
Vec3 scale(const Vec3& u, double k) {
  return {u[0] * k, u[1] * k, u[2] * k};
}
Vec3 unit(const Vec3& u) {
  return scale(u, 1.0 / std::sqrt(u[0] * u[0] + u[1] * u[1] + u[2] * u[2]));
}
Vec3 lerp(const Vec3& a, const Vec3& b, double t) {
  return add(a, scale(sub(b, a), t));
}

namespace body_labels {
constexpr Label kSoft = detail::kSoftLabel, kFat = detail::kFatLabel, kLiver = detail::kLiverLabel,
                kBrain = detail::kBrainLabel;
constexpr Label kSacrum = 10, kHipLeft = 11, kHipRight = 12;
constexpr Label kL5 = 13, kL4 = 14, kL3 = 15, kL2 = 16, kL1 = 17;
constexpr Label kThoracicSpine = 18, kRibs = 19, kSternum = 20, kCervicalSpine = 21, kSkull = 22;
// Paired bones: left value, right = left + 1.
constexpr Label kClavicula = 30, kScapula = 32, kHumerus = 34, kForearm = 36, kHand = 38;
constexpr Label kFemur = 40, kPatella = 42, kTibia = 44, kFoot = 46;
Label sided(Label left_value, int side) {
  return side > 0 ? left_value : left_value + 1;
}
// Several paired bones on one side at once.
template <size_t N>
std::array<Label, N> sided(const Label (&left_values)[N], int side) {
  std::array<Label, N> values{};
  for (size_t i = 0; i < N; ++i) values[i] = sided(left_values[i], side);
  return values;
}
}  // namespace body_labels

std::string side_name(int side) {
  return side > 0 ? "left" : "right";
}

// Every landmark of the body, in mm at the requested height. Numbers are mm at 1700 mm height (scaled by f);
// `side` is +1 for the patient's left (+x), -1 for the right.
struct BodyLayout {
  double f;    // height / 1700 mm
  double gap;  // joint gap, mm (not scaled)

  Vec3 p(double x, double y, double z) const { return {x * f, y * f, z * f}; }

  // ---- skin --------------------------------------------------------------------------------------------------
  Vec3 thigh_top(int s) const { return p(s * 86, 5, 920); }
  double thigh_top_radius() const { return 88 * f; }
  double thigh_knee_radius() const { return 60 * f; }
  Vec3 upper_arm_top(int s) const { return p(s * 205, 5, 1395); }
  // The thigh's lateral skin line in the coronal plane: x at height z (linear between the two end spheres).
  double thigh_lateral_x(int s, double z) const {
    const double z0 = knee(s)[2];
    const double z1 = thigh_top(s)[2];
    const double x0 = std::abs(knee(s)[0]) + thigh_knee_radius();
    const double x1 = std::abs(thigh_top(s)[0]) + thigh_top_radius();
    return s * (x0 + (x1 - x0) * (z - z0) / (z1 - z0));
  }
  // The hand lies along the thigh's lateral skin line: u runs distally along it, n points out of the thigh.
  Vec3 hand_axis(int s) const {
    const double dx = std::abs(thigh_lateral_x(s, thigh_top(s)[2])) - std::abs(thigh_lateral_x(s, knee(s)[2]));
    return unit({-s * dx, 0.0, -(thigh_top(s)[2] - knee(s)[2])});
  }
  double hand_half_thickness() const { return 15 * f; }
  double hand_overlap() const { return 3 * f; }  // hand skin sinks this far into the thigh's
  Vec3 hand_centre(int s) const {
    const double z = 735 * f;
    const Vec3 n = outward(s);
    return add({thigh_lateral_x(s, z), 0.0, z}, scale(n, hand_half_thickness() - hand_overlap()));
  }
  // Unit normal of the thigh's lateral skin line, pointing away from the thigh (coronal plane).
  Vec3 outward(int s) const {
    const Vec3 u = hand_axis(s);  // (-s a, 0, -c)
    return {s * std::abs(u[2]), 0.0, -std::abs(u[0])};
  }
  // The middle of the radiocarpal gap on the hand's axis.
  Vec3 wrist(int s) const { return sub(hand_centre(s), scale(hand_axis(s), 85 * f)); }
  // The radiocarpal joint turns about the centre of the proximal carpal row's convex head (a ball), across the gap
  // from the radius's cup.
  double carpal_radius() const { return 11 * f; }
  Vec3 carpal_centre(int s) const { return add(wrist(s), scale(hand_axis(s), gap / 2 + carpal_radius())); }

  // ---- joints ------------------------------------------------------------------------------------------------
  Vec3 hip(int s) const { return p(s * 88, 0, 900); }
  double femoral_head_radius() const { return 24 * f; }
  // Neck from the head centre to the shaft, 45 mm inferolaterally at 41 degrees from vertical: with the shaft
  // running from there to the knee (9 degrees from vertical) the neck-shaft angle is 130 degrees.
  Vec3 femoral_neck_base(int s) const {
    const double a = 41.0 * kPi / 180.0;
    return add(hip(s), scale({s * std::sin(a), 0.0, -std::cos(a)}, 45 * f));
  }
  Vec3 knee(int s) const { return p(s * 56, 0, 480); }
  double condyle_radius() const { return 22 * f; }
  double condyle_half_length() const { return 35 * f; }
  double plateau_top() const { return knee(1)[2] - condyle_radius() - gap; }
  Vec3 patella_centre(int s) const { return {knee(s)[0], -(condyle_radius() + gap + 9 * f), knee(s)[2]}; }
  Vec3 ankle(int s) const { return p(s * 62, 0, 80); }
  double talar_radius() const { return 18 * f; }
  double talar_half_length() const { return 18 * f; }
  Vec3 shoulder(int s) const { return p(s * 180, 5, 1385); }
  double humeral_head_radius() const { return 22 * f; }
  Vec3 elbow(int s) const { return p(s * 201, 0, 1075); }
  double trochlea_radius() const { return 13 * f; }
  double trochlea_half_length() const { return 22 * f; }

  // ---- spine and thorax --------------------------------------------------------------------------------------
  double spine_y() const { return 45 * f; }
  double pelvis_top() const { return 1000 * f; }
  double vertebra_height() const { return 28 * f; }
  double lumbar_bottom(int n) const { return pelvis_top() + gap + n * (vertebra_height() + gap); }  // 0 = L5
  double thoracic_bottom() const { return lumbar_bottom(5); }
  double thoracic_top() const { return 1420 * f; }
  double skull_base() const { return 1500 * f; }
  Vec3 rib_centre() const { return p(0, 0, 1200); }
  Vec3 rib_outer() const { return p(140, 95, 260); }
  Vec3 rib_inner() const { return p(132, 87, 252); }
  double rib_bottom() const { return thoracic_bottom() + 10 * f; }
  double rib_top() const { return 1405 * f; }
  double scapula_thickness() const { return 10 * f; }
  // y of the ellipsoid with radii `r` around rib_centre() at (x, z), on the posterior (+1) or anterior (-1) side.
  double ellipsoid_y(const Vec3& r, double x, double z, int side_y) const {
    const double u = x / r[0];
    const double w = (z - rib_centre()[2]) / r[2];
    return side_y * r[1] * std::sqrt(std::max(0.0, 1.0 - u * u - w * w));
  }
  // A point in the middle of the scapula's layer on the rib shell.
  Vec3 scapula_point(int s, double x_mm, double z_mm) const {
    const Vec3 mid = add(rib_outer(), Vec3{scapula_thickness() / 2, scapula_thickness() / 2, scapula_thickness() / 2});
    return {s * x_mm * f, ellipsoid_y(mid, x_mm * f, z_mm * f, +1), z_mm * f};
  }
  Vec3 manubrium() const { return {0.0, ellipsoid_y(rib_outer(), 0.0, 1380 * f, -1), 1380 * f}; }
  double manubrium_radius() const { return 20 * f; }
  double clavicle_radius() const { return 8 * f; }
  double acromion_radius() const { return 8 * f; }
  Vec3 sternoclavicular_direction(int s) const { return unit({s * 1.0, -0.4, 0.6}); }
  Vec3 clavicle_medial(int s) const {
    return add(manubrium(), scale(sternoclavicular_direction(s), manubrium_radius() + gap + clavicle_radius()));
  }
  double acromion_z() const { return shoulder(1)[2] + humeral_head_radius() + gap + 16 * f; }
  Vec3 acromion_tip(int s) const { return {s * 190 * f, 10 * f, acromion_z()}; }
  Vec3 acromion_base(int s) const { return {s * 150 * f, 30 * f, acromion_z()}; }
  // The clavicle ends in front of (-y) the acromion tip across the gap.
  Vec3 clavicle_lateral(int s) const {
    return add(acromion_tip(s), Vec3{0.0, -(acromion_radius() + gap + clavicle_radius()), 0.0});
  }
};

// The skin surfaces with the name of the body part each belongs to (for skin contacts).
struct SkinPart {
  std::string part;
  Shape shape;
};

std::vector<SkinPart> body_skin(const BodyLayout& m) {
  const double f = m.f;
  std::vector<SkinPart> skin;
  skin.push_back({"trunk", detail::elliptic_cylinder_z(0, 0, 165 * f, 112 * f, 870 * f, 1440 * f)});
  skin.push_back({"trunk", detail::ellipsoid(m.p(0, 0, 870), m.p(165, 112, 95))});            // buttocks and groin
  skin.push_back({"trunk", detail::capsule(m.p(-170, 5, 1405), m.p(170, 5, 1405), 58 * f)});  // shoulders
  skin.push_back({"neck", detail::capsule(m.p(0, 20, 1410), m.p(0, 15, 1540), 60 * f)});
  skin.push_back({"head", detail::ellipsoid(m.p(0, -5, 1585), m.p(85, 105, 115))});
  for (int s : {+1, -1}) {
    const std::string side = side_name(s);
    const Vec3 a = m.ankle(s);
    skin.push_back(
        {"thigh_" + side, detail::round_cone(m.thigh_top(s), m.knee(s), m.thigh_top_radius(), m.thigh_knee_radius())});
    skin.push_back({"leg_" + side, detail::round_cone(m.knee(s), {a[0], 0.0, a[2] + 60 * f}, 58 * f, 36 * f)});
    skin.push_back({"foot_" + side, detail::capsule({a[0], 0, a[2] - 10 * f}, {a[0], 0, a[2] + 50 * f}, 44 * f)});
    skin.push_back({"foot_" + side, detail::capsule({a[0], 15 * f, 35 * f}, {a[0], 40 * f, 35 * f}, 32 * f)});
    skin.push_back({"foot_" + side, detail::capsule({a[0], -10 * f, 42 * f}, {a[0], -175 * f, 33 * f}, 30 * f)});
    skin.push_back({"arm_" + side, detail::round_cone(m.upper_arm_top(s), m.elbow(s), 48 * f, 42 * f)});
    skin.push_back({"forearm_" + side, detail::round_cone(m.elbow(s), m.wrist(s), 40 * f, 28 * f)});
    skin.push_back({"hand_" + side, detail::oriented_box(m.hand_centre(s), m.outward(s), {0, 1, 0},
                                                         {m.hand_half_thickness(), 42 * f, 95 * f}, 12 * f)});
  }
  return skin;
}

std::vector<Shape> skin_shapes(const BodyLayout& m) {
  std::vector<Shape> shapes;
  for (const SkinPart& part : body_skin(m)) shapes.push_back(part.shape);
  return shapes;
}

double default_gap(const Vec3& spacing) {
  return 1.2 * std::sqrt(spacing[0] * spacing[0] + spacing[1] * spacing[1] + spacing[2] * spacing[2]);
}

double gap_of(const BodyParams& p) {
  return p.joint_gap_mm > 0.0 ? p.joint_gap_mm : default_gap(p.spacing_mm);
}

// ---- bones -------------------------------------------------------------------------------------------------------

void paint_thorax(LabelVolume& labels, const BodyLayout& m) {
  namespace L = body_labels;
  const double f = m.f;
  // Scapulae first: the plate is the layer just outside the rib shell, so the rib shell painted next cuts it to
  // lie exactly on the ribs (they touch, no gap).
  for (int s : {+1, -1}) {
    const Label scapula = L::sided(L::kScapula, s);
    const Vec3 layer = add(m.rib_outer(), Vec3{m.scapula_thickness(), m.scapula_thickness(), m.scapula_thickness()});
    Shape plate = detail::ellipsoid(m.rib_centre(), layer);
    plate.clip_min = {s > 0 ? 35 * f : -125 * f, 25 * f, 1230 * f};
    plate.clip_max = {s > 0 ? 125 * f : -35 * f, detail::kInf, 1395 * f};
    detail::paint(labels, plate, scapula);
    // Shallow glenoid: a cup over the medial cap of the humeral head, opening laterally.
    const Vec3 sh = m.shoulder(s);
    const double r_in = m.humeral_head_radius() + m.gap;
    detail::paint(labels, detail::spherical_cup(sh, {-1.0 * s, 0, 0}, r_in, r_in + 7 * f, 35.0 * kPi / 180.0), scapula);
    // Scapular neck from behind the cup to the plate's lateral border (starting clear of the joint space).
    detail::paint(labels,
                  detail::capsule(add(sh, Vec3{-s * (r_in + 10 * f), 0, 0}), m.scapula_point(s, 85, 1360), 9 * f),
                  scapula);
    // Spine of the scapula and the acromion over the humeral head.
    detail::paint(labels, detail::capsule(m.scapula_point(s, 60, 1385), m.acromion_base(s), m.acromion_radius()),
                  scapula);
    detail::paint(labels, detail::capsule(m.acromion_base(s), m.acromion_tip(s), m.acromion_radius()), scapula);
  }
  // Rib shell (hollowed), joined to the thoracic spine by a posterior bar; sternum and manubrium in front.
  Shape ribs = detail::ellipsoid(m.rib_centre(), m.rib_outer());
  ribs.clip_min[2] = m.rib_bottom();
  ribs.clip_max[2] = m.rib_top();
  detail::paint(labels, ribs, L::kRibs);
  Shape cavity = detail::ellipsoid(m.rib_centre(), m.rib_inner());
  cavity.clip_min[2] = m.rib_bottom() - 1.0;
  cavity.clip_max[2] = m.rib_top() + 1.0;
  detail::repaint(labels, cavity, L::kRibs, L::kSoft);
  detail::paint(labels, detail::box({-10 * f, m.spine_y(), m.rib_bottom()}, {10 * f, 90 * f, m.rib_top()}), L::kRibs);
  const double front_1220 = m.ellipsoid_y(m.rib_outer(), 0.0, 1220 * f, -1);
  const double front_1370 = m.ellipsoid_y(m.rib_outer(), 0.0, 1370 * f, -1);
  detail::paint(labels, detail::capsule({0, front_1220, 1220 * f}, {0, front_1370, 1370 * f}, 12 * f), L::kSternum);
  detail::paint(labels, detail::sphere(m.manubrium(), m.manubrium_radius()), L::kSternum);
  detail::paint(labels,
                detail::cylinder({0, m.spine_y(), m.thoracic_bottom()}, {0, m.spine_y(), m.thoracic_top()}, 19 * f),
                L::kThoracicSpine);
}

void paint_axial(LabelVolume& labels, const BodyLayout& m) {
  namespace L = body_labels;
  const double f = m.f;
  const double y = m.spine_y();
  const Label lumbar[5] = {L::kL5, L::kL4, L::kL3, L::kL2, L::kL1};
  for (int n = 0; n < 5; ++n) {
    const double z0 = m.lumbar_bottom(n);
    detail::paint(labels, detail::cylinder({0, y, z0}, {0, y, z0 + m.vertebra_height()}, 22 * f), lumbar[n]);
  }
  detail::paint(labels, detail::cylinder({0, y, m.thoracic_top() + m.gap}, {0, y, m.skull_base() - m.gap}, 14 * f),
                L::kCervicalSpine);
  // Skull: an ellipsoid shell cut flat at the skull base, with an occipital block over the cervical spine.
  Shape skull = detail::ellipsoid(m.p(0, -5, 1590), m.p(73, 93, 98));
  skull.clip_min[2] = m.skull_base();
  detail::paint(labels, skull, L::kSkull);
  detail::paint(labels, detail::box({-22 * f, 20 * f, m.skull_base()}, {22 * f, 65 * f, 1520 * f}), L::kSkull);
  Shape brain = detail::ellipsoid(m.p(0, -5, 1592), m.p(65, 85, 90));
  brain.clip_min[2] = 1515 * f;
  detail::paint(labels, brain, L::kBrain);
}

void paint_pelvis(LabelVolume& labels, const BodyLayout& m) {
  namespace L = body_labels;
  const double f = m.f;
  // Sacrum: a block whose flat top carries L5, tapering down and back.
  detail::paint(labels, detail::box({-45 * f, 20 * f, 940 * f}, {45 * f, 75 * f, m.pelvis_top()}), L::kSacrum);
  detail::paint(labels, detail::capsule(m.p(0, 55, 950), m.p(0, 72, 875), 18 * f), L::kSacrum);
  for (int s : {+1, -1}) {
    const Label hip = L::sided(L::kHipLeft, s);
    const Vec3 centre = m.hip(s);
    // Iliac wing: a slab from the sacroiliac joint forward and outward to the crest.
    detail::paint(labels,
                  detail::oriented_box(m.p(s * 95, 30, 985), unit({s * 90.0, -55.0, 0.0}), {0, 0, 1}, m.p(55, 40, 7)),
                  hip);
    // Acetabulum: a hemispherical cup around the femoral head, its pole up and medial.
    const Vec3 pole = unit({-0.6 * s, 0.0, 0.8});
    const double r_in = m.femoral_head_radius() + m.gap;
    detail::paint(labels, detail::spherical_cup(centre, pole, r_in, r_in + 12 * f, 0.5 * kPi), hip);
    // Struts from the cup to the ilium, the pubic symphysis and the ischial tuberosity: at most 14 mm thick and
    // starting 14 mm beyond the cup's inner radius, so none reaches into the joint space.
    const double clear = r_in + 14 * f;
    detail::paint(labels, detail::capsule(add(centre, scale(pole, clear)), m.p(s * 95, 30, 985), 14 * f), hip);
    detail::paint(
        labels, detail::capsule(add(centre, scale(unit({-0.6 * s, -0.7, -0.2}), clear)), m.p(s * 4, -50, 875), 10 * f),
        hip);
    detail::paint(labels,
                  detail::capsule(add(centre, scale(unit({-0.5 * s, 0.7, -0.1}), clear)), m.p(s * 50, 45, 845), 12 * f),
                  hip);
  }
}

void paint_leg(LabelVolume& labels, const BodyLayout& m, int s) {
  namespace L = body_labels;
  const double f = m.f;
  const auto [femur, tibia, foot] = L::sided({L::kFemur, L::kTibia, L::kFoot}, s);
  const Vec3 hip = m.hip(s);
  const Vec3 neck = m.femoral_neck_base(s);
  const Vec3 knee = m.knee(s);
  const Vec3 ankle = m.ankle(s);
  // Femur: head, neck, greater trochanter, shaft inclined medially toward the knee, distal flare, condyles.
  detail::paint(labels, detail::sphere(hip, m.femoral_head_radius()), femur);
  detail::paint(labels, detail::capsule(hip, neck, 15 * f), femur);
  detail::paint(labels, detail::sphere(add(neck, Vec3{s * 12 * f, 0, 15 * f}), 16 * f), femur);
  detail::paint(labels, detail::cylinder(neck, knee, 14 * f), femur);
  const Vec3 flare_top =
      lerp(knee, neck, 100 * f / std::sqrt(std::pow(neck[0] - knee[0], 2) + std::pow(neck[2] - knee[2], 2)));
  detail::paint(labels, detail::round_cone(flare_top, knee, 14 * f, 20 * f), femur);
  const double half = m.condyle_half_length();
  detail::paint(
      labels,
      detail::cylinder({knee[0] - half, knee[1], knee[2]}, {knee[0] + half, knee[1], knee[2]}, m.condyle_radius()),
      femur);
  // Patella in front of the condyles.
  detail::paint(labels, detail::ellipsoid(m.patella_centre(s), m.p(20, 9, 18)), L::sided(L::kPatella, s));
  // Tibia: flat plateau under the condyles, metaphysis, shaft, and a concave mortise over the talar dome with a
  // medial malleolus beside it.
  const double top = m.plateau_top();
  detail::paint(labels, detail::cylinder({knee[0], 0, top - 16 * f}, {knee[0], 0, top}, 38 * f), tibia);
  const double mortise_top = ankle[2] + m.talar_radius() + m.gap + 28 * f;
  const Vec3 shaft_top{knee[0], 0, top - 16 * f};
  const Vec3 shaft_bottom{ankle[0], 0, mortise_top};
  detail::paint(labels,
                detail::round_cone({knee[0], 0, top - 30 * f}, lerp(shaft_top, shaft_bottom, 0.3), 28 * f, 13 * f),
                tibia);
  detail::paint(labels, detail::cylinder(shaft_top, shaft_bottom, 12 * f), tibia);
  const double malleolus_x = ankle[0] - s * (m.talar_half_length() + m.gap + 7 * f);
  const double lateral_x = ankle[0] + s * 20 * f;
  detail::paint(labels,
                detail::box({std::min(malleolus_x, lateral_x), -18 * f, ankle[2] + 2 * f},
                            {std::max(malleolus_x, lateral_x), 18 * f, mortise_top}),
                tibia);
  const double carve_half = m.talar_half_length() + m.gap;
  detail::repaint(labels,
                  detail::cylinder({ankle[0] - carve_half, 0, ankle[2]}, {ankle[0] + carve_half, 0, ankle[2]},
                                   m.talar_radius() + m.gap),
                  tibia, L::kSoft);
  detail::paint(labels,
                detail::capsule({malleolus_x, 0, ankle[2] + m.talar_radius() + m.gap + 20 * f},
                                {malleolus_x, 0, ankle[2] - 12 * f}, 7 * f),
                tibia);
  // Foot: talar dome (the ankle's hinge cylinder), talus and calcaneus, and a forefoot pointing anteriorly.
  const double dome = m.talar_half_length();
  detail::paint(
      labels, detail::cylinder({ankle[0] - dome, 0, ankle[2]}, {ankle[0] + dome, 0, ankle[2]}, m.talar_radius()), foot);
  detail::paint(labels, detail::capsule(ankle, {ankle[0], 22 * f, 45 * f}, 16 * f), foot);
  detail::paint(labels, detail::capsule({ankle[0], 10 * f, 40 * f}, {ankle[0], 42 * f, 36 * f}, 20 * f), foot);
  detail::paint(labels, detail::capsule({ankle[0], -8 * f, 50 * f}, {ankle[0], -110 * f, 36 * f}, 12 * f), foot);
  detail::paint(labels, detail::box({ankle[0] - 20 * f, -165 * f, 26 * f}, {ankle[0] + 20 * f, -60 * f, 38 * f}), foot);
}

void paint_arm(LabelVolume& labels, const BodyLayout& m, int s) {
  namespace L = body_labels;
  const double f = m.f;
  const auto [clavicula, humerus, forearm, hand] = L::sided({L::kClavicula, L::kHumerus, L::kForearm, L::kHand}, s);
  detail::paint(labels, detail::capsule(m.clavicle_medial(s), m.clavicle_lateral(s), m.clavicle_radius()), clavicula);
  const Vec3 sh = m.shoulder(s);
  const Vec3 elbow = m.elbow(s);
  const Vec3 wrist = m.wrist(s);
  const Vec3 u = m.hand_axis(s);
  const Vec3 n = m.outward(s);
  const Vec3 y_axis{0, 1, 0};
  // Forearm: a notch (half-pipe under the trochlea, hollowed to leave the joint space), ulna and radius shafts,
  // and a distal end whose cup (the radius's concave articular surface) faces the carpal head across the wrist gap.
  const double half = m.trochlea_half_length();
  const double r_notch = m.trochlea_radius() + m.gap;
  const Vec3 axis_a{elbow[0] - half, elbow[1], elbow[2]};
  const Vec3 axis_b{elbow[0] + half, elbow[1], elbow[2]};
  Shape notch = detail::cylinder(axis_a, axis_b, r_notch + 8 * f);
  notch.clip_max[2] = elbow[2];
  detail::paint(labels, notch, forearm);
  Shape joint_space = detail::cylinder(axis_a, axis_b, r_notch);
  detail::repaint(labels, joint_space, forearm, L::kSoft);
  const Vec3 distal = sub(wrist, scale(u, m.gap / 2 + 12 * f));
  detail::paint(labels, detail::cylinder({elbow[0], 0, elbow[2] - (r_notch + 4 * f)}, distal, 8 * f), forearm);
  detail::paint(labels,
                detail::cylinder({elbow[0] + s * 6 * f, -12 * f, elbow[2] - (r_notch + 6 * f)},
                                 add(distal, Vec3{0, -12 * f, 0}), 9 * f),
                forearm);
  const Vec3 carpal = m.carpal_centre(s);
  const double cup_in = m.carpal_radius() + m.gap;
  const double cup_out = cup_in + 5 * f;
  detail::paint(labels,
                detail::oriented_box(sub(carpal, scale(u, cup_out + 10 * f)), n, y_axis, {12 * f, 24 * f, 10 * f}),
                forearm);
  detail::paint(labels, detail::spherical_cup(carpal, scale(u, -1.0), cup_in, cup_out, 50.0 * kPi / 180.0), forearm);
  // Hand: the proximal carpal row's convex head facing the cup across the wrist gap, joined by a narrower neck to the
  // carpal block (beyond the reach of a fit over the head, as the humeral and femoral necks are), and a plate of
  // metacarpals and fingers.
  detail::paint(labels, detail::sphere(carpal, m.carpal_radius()), hand);
  detail::paint(labels, detail::capsule(carpal, add(carpal, scale(u, 18 * f)), 6 * f), hand);
  detail::paint(labels, detail::oriented_box(add(carpal, scale(u, 30 * f)), n, y_axis, m.p(10, 20, 12)), hand);
  detail::paint(labels, detail::oriented_box(add(carpal, scale(u, 70 * f)), n, y_axis, m.p(6, 32, 52)), hand);
  // Humerus: head in the glenoid, anatomical neck, shaft, epicondyles and the trochlea (the elbow's hinge).
  const Vec3 neck = add(sh, m.p(s * 18, 0, -28));
  detail::paint(labels, detail::sphere(sh, m.humeral_head_radius()), humerus);
  detail::paint(labels, detail::capsule(sh, neck, 16 * f), humerus);
  detail::paint(labels, detail::cylinder(neck, elbow, 11 * f), humerus);
  detail::paint(labels,
                detail::box({elbow[0] - 28 * f, -8 * f, elbow[2]}, {elbow[0] + 28 * f, 8 * f, elbow[2] + 30 * f}),
                humerus);
  // The coronoid fossa: the hollow in front of the trochlea that takes the rim of the forearm's notch when the elbow
  // bends (without it, shaft and epicondyles stand where the rim goes, and the bones overlap at 90 degrees whatever
  // the joint centre). The posterior half joins trochlea and shaft.
  Shape fossa =
      detail::cylinder(sub(axis_a, Vec3{m.gap, 0, 0}), add(axis_b, Vec3{m.gap, 0, 0}), r_notch + 8 * f + m.gap);
  fossa.clip_max[1] = elbow[1];
  detail::repaint(labels, fossa, humerus, L::kSoft);
  detail::paint(labels, detail::cylinder(axis_a, axis_b, m.trochlea_radius()), humerus);
}

std::vector<LabelEntry> body_entries() {
  namespace L = body_labels;
  std::vector<LabelEntry> entries = detail::tissue_entries();
  entries.insert(entries.end(), {
      {L::kSacrum, "sacrum", LabelRole::kBone, "pelvis"},
      {L::kHipLeft, "hip_left", LabelRole::kBone, "pelvis"},
      {L::kHipRight, "hip_right", LabelRole::kBone, "pelvis"},
  });
  for (LabelEntry& entry : detail::lumbar_entries(L::kL5)) entries.push_back(std::move(entry));
  entries.insert(entries.end(), {
      {L::kThoracicSpine, "thoracic_spine", LabelRole::kBone, "thorax"},
      {L::kRibs, "ribs", LabelRole::kBone, "thorax"},
      {L::kSternum, "sternum", LabelRole::kBone, "thorax"},
      {L::kCervicalSpine, "cervical_spine", LabelRole::kBone, "cervical_spine"},
      {L::kSkull, "skull", LabelRole::kBone, "skull"},
  });
  const std::pair<Label, const char*> paired[] = {
      {L::kClavicula, "clavicula"}, {L::kScapula, "scapula"}, {L::kHumerus, "humerus"},
      {L::kForearm, "forearm"},     {L::kHand, "hand"},       {L::kFemur, "femur"},
      {L::kPatella, "patella"},     {L::kTibia, "tibia"},     {L::kFoot, "foot"}};
  for (const auto& [value, name] : paired) {
    for (int s : {+1, -1}) {
      const std::string label = std::string(name) + "_" + side_name(s);
      entries.push_back({L::sided(value, s), label, LabelRole::kBone, label});
    }
  }
  return entries;
}

std::vector<JointTruth> body_joints(const BodyLayout& m) {
  const double y = m.spine_y();
  const double g = m.gap;
  const Vec3 left{1.0, 0.0, 0.0};
  std::vector<JointTruth> joints;
  auto plane = [&](const std::string& name, const std::string& parent, const std::string& child, const Vec3& c) {
    joints.push_back({name, parent, child, c, "plane"});
  };
  plane("lumbosacral", "pelvis", "vertebrae_L5", {0, y, m.pelvis_top() + g / 2});
  const char* lumbar[5] = {"vertebrae_L5", "vertebrae_L4", "vertebrae_L3", "vertebrae_L2", "vertebrae_L1"};
  const char* lumbar_joints[4] = {"L4_L5", "L3_L4", "L2_L3", "L1_L2"};
  for (int n = 1; n < 5; ++n) plane(lumbar_joints[n - 1], lumbar[n - 1], lumbar[n], {0, y, m.lumbar_bottom(n) - g / 2});
  plane("thoracolumbar", "vertebrae_L1", "thorax", {0, y, m.thoracic_bottom() - g / 2});
  plane("cervicothoracic", "thorax", "cervical_spine", {0, y, m.thoracic_top() + g / 2});
  plane("atlanto_occipital", "cervical_spine", "skull", {0, y, m.skull_base() - g / 2});
  for (int s : {+1, -1}) {
    const std::string side = side_name(s);
    plane("sternoclavicular_" + side, "thorax", "clavicula_" + side,
          add(m.manubrium(), scale(m.sternoclavicular_direction(s), m.manubrium_radius() + g / 2)));
    plane("acromioclavicular_" + side, "clavicula_" + side, "scapula_" + side,
          add(m.acromion_tip(s), Vec3{0, -(m.acromion_radius() + g / 2), 0}));
    joints.push_back({"shoulder_" + side, "scapula_" + side, "humerus_" + side, m.shoulder(s), "ball"});
    joints.push_back({"elbow_" + side, "humerus_" + side, "forearm_" + side, m.elbow(s), "hinge", left});
    joints.push_back({"wrist_" + side, "forearm_" + side, "hand_" + side, m.carpal_centre(s), "ball"});
  }
  for (int s : {+1, -1}) {
    const std::string side = side_name(s);
    joints.push_back({"hip_" + side, "pelvis", "femur_" + side, m.hip(s), "ball"});
    joints.push_back({"knee_" + side, "femur_" + side, "tibia_" + side, m.knee(s), "hinge", left});
    plane("patellofemoral_" + side, "femur_" + side, "patella_" + side,
          {m.knee(s)[0], -(m.condyle_radius() + g / 2), m.knee(s)[2]});
    joints.push_back({"ankle_" + side, "tibia_" + side, "foot_" + side, m.ankle(s), "hinge", left});
  }
  return joints;
}

ImageGeometry grid_of(const BodyParams& p) {
  const BodyLayout layout{p.height_mm / 1700.0, gap_of(p)};
  return detail::grid_for(skin_shapes(layout), p.spacing_mm, p.direction,
                          p.margin_mm + p.skin_offset_mm * p.height_mm / 1700.0);
}

}  // namespace

Status validate(const BodyParams& p) {
  for (int a = 0; a < 3; ++a) {
    POSEWARP_RETURN_IF_ERROR(detail::check_positive(p.spacing_mm[a], "body spacing_mm"));
  }
  POSEWARP_RETURN_IF_ERROR(detail::check_positive(p.height_mm, "body height_mm"));
  if (p.height_mm < 200.0 || p.height_mm > 3000.0) {
    return invalid_argument_error("body height_mm must lie in 200..3000 (got " + std::to_string(p.height_mm) + ")");
  }
  if (!(p.joint_gap_mm >= 0.0) || !(p.fat_mm >= 0.0) || !(p.margin_mm >= 0.0) || !(p.noise_hu >= 0.0) ||
      !(p.skin_offset_mm >= 0.0)) {
    return invalid_argument_error(
        "body joint_gap_mm, fat_mm, skin_offset_mm, margin_mm and noise_hu must not be negative");
  }
  if (p.skin_offset_mm > 100.0) {
    return invalid_argument_error("body skin_offset_mm must be at most 100 (got " + std::to_string(p.skin_offset_mm) +
                                  ")");
  }
  const double f = p.height_mm / 1700.0;
  const double coarsest = std::max({p.spacing_mm[0], p.spacing_mm[1], p.spacing_mm[2]});
  if (coarsest > 10.0 * f) {
    return invalid_argument_error("body spacing of " + std::to_string(coarsest) +
                                  " mm is too coarse to resolve its bones; use at most " + std::to_string(10.0 * f) +
                                  " mm on every axis");
  }
  const double gap = gap_of(p);
  if (gap > 16.0 * f) {
    return invalid_argument_error("body joint gap of " + std::to_string(gap) +
                                  " mm is too wide for its size (at most " + std::to_string(16.0 * f) +
                                  " mm); use a finer spacing or a smaller joint_gap_mm");
  }
  return detail::validate_direction(p.direction);
}

Result<ImageGeometry> body_grid(const BodyParams& params) {
  POSEWARP_RETURN_IF_ERROR(validate(params));
  const ImageGeometry grid = grid_of(params);
  POSEWARP_RETURN_IF_ERROR(detail::check_size(grid));
  return grid;
}

Vec3 body_spacing_for_voxels(const BodyParams& params, int64_t target_voxels) {
  // Voxel count scales as 1/k^3 with the spacing factor k, up to the rounding of the grid size and the margin;
  // a few fixed-point steps settle it.
  const double target = static_cast<double>(std::max<int64_t>(1, target_voxels));
  BodyParams probe = params;
  double k = 1.0;
  for (int step = 0; step < 6; ++step) {
    probe.spacing_mm = scale(params.spacing_mm, k);
    k *= std::cbrt(static_cast<double>(grid_of(probe).voxel_count()) / target);
  }
  return scale(params.spacing_mm, k);
}

Result<Phantom> make_body(const BodyParams& p) {
  namespace L = body_labels;
  POSEWARP_ASSIGN_OR_RETURN(const ImageGeometry grid, body_grid(p));
  const double f = p.height_mm / 1700.0;
  const BodyLayout m{f, gap_of(p)};

  Phantom phantom;
  phantom.name = "body";
  phantom.joint_gap_mm = m.gap;
  LabelVolume& labels = phantom.labels;
  labels = LabelVolume(grid, 0);
  labels.set_source_type(PixelType::kUInt8);

  // Later paints win: skin with its fat shell, shoulder girdle and thorax, liver, spine and skull, pelvis, legs,
  // arms (each joint's carved space before the bone that moves in it).
  detail::paint_body(labels, skin_shapes(m), L::kSoft, L::kFat, p.fat_mm * f, p.skin_offset_mm * f);
  paint_thorax(labels, m);
  detail::paint(labels, detail::ellipsoid(m.p(-65, -10, 1135), m.p(60, 55, 55)), L::kLiver);
  paint_axial(labels, m);
  paint_pelvis(labels, m);
  for (int s : {+1, -1}) paint_leg(labels, m, s);
  for (int s : {+1, -1}) paint_arm(labels, m, s);

  phantom.joints = body_joints(m);
  std::vector<JointName> joint_names;
  for (const JointTruth& joint : phantom.joints) {
    // Declared as a label map for real bodies would: kinds, and flexion moving the heel back at the knee and the
    // toes up at the ankle.
    const labels::JointKind kind = joint.kind == "ball"    ? labels::JointKind::kBall
                                   : joint.kind == "hinge" ? labels::JointKind::kHinge
                                                           : labels::JointKind::kPlane;
    const labels::FlexionDirection flexion = joint.name.rfind("knee", 0) == 0    ? labels::FlexionDirection::kPosterior
                                             : joint.name.rfind("ankle", 0) == 0 ? labels::FlexionDirection::kSuperior
                                                                                 : labels::FlexionDirection::kAnterior;
    joint_names.push_back({joint.name, joint.parent_segment, joint.child_segment, kind, flexion});
  }
  phantom.root_segment = "pelvis";
  POSEWARP_ASSIGN_OR_RETURN(phantom.label_map, labels::LabelMap::create("body_phantom", body_entries(),
                                                                        std::move(joint_names), phantom.root_segment));
  for (const char* side_text : {"left", "right"}) {
    const std::string side(side_text);
    phantom.skin_contacts.emplace_back("arm_" + side, "trunk");
    phantom.skin_contacts.emplace_back("forearm_" + side, "trunk");
    phantom.skin_contacts.emplace_back("forearm_" + side, "thigh_" + side);
    phantom.skin_contacts.emplace_back("hand_" + side, "thigh_" + side);
  }
  phantom.skin_contacts.emplace_back("thigh_left", "thigh_right");

  std::vector<std::pair<Label, float>> hu{{L::kSoft, detail::kSoftHu},
                                          {L::kFat, detail::kFatHu},
                                          {L::kLiver, detail::kLiverHu},
                                          {L::kBrain, detail::kBrainHu}};
  for (const LabelEntry& entry : phantom.label_map.entries()) {
    if (entry.role == LabelRole::kBone) hu.emplace_back(entry.value, detail::kBoneHu);
  }
  phantom.ct = detail::synthesize_ct(labels, hu, detail::kAirHu, p.noise_hu, p.seed);
  return phantom;
}

}  // namespace posewarp::phantom
