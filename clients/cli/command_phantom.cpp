// Phantom commands: write the bar, the mannequin or the body as label + CT volumes with their label map and
// joint truth.
#include <sstream>
#include <string>
#include <vector>

#include "cli_support.h"
#include "posewarp/api/study.h"

namespace posewarp::cli {
namespace {

struct PhantomOptions {
  std::string out_dir;
  std::string extension = ".nii.gz";
  int64_t target_voxels = 0;
  api::BarParams bar;
  api::MannequinParams mannequin;
  api::BodyParams body;
  std::vector<double> spacing;  // --spacing X,Y,Z
  double spacing_xy = 0.0;
  double slice = 0.0;
};

std::string spacing_text(const Vec3& spacing) {
  std::ostringstream text;
  text << spacing[0] << " x " << spacing[1] << " x " << spacing[2];
  return text.str();
}

int write_phantom(const api::Phantom& p, const PhantomOptions& options) {
  Result<std::vector<std::string>> written = api::write_phantom(p, options.out_dir, options.extension);
  if (!written.ok()) return report(written.status());
  say(p.name + ": " + p.labels.geometry().describe() + " (" + std::to_string(p.labels.voxel_count()) + " voxels), " +
      std::to_string(p.label_map.bone_segments().size()) + " bone segments, " + std::to_string(p.joints.size()) +
      " joints");
  std::string list;
  for (const std::string& path : *written) list += (list.empty() ? "" : ", ") + path;
  say("wrote " + list);
  return 0;
}

// The volume formats a phantom is written in.
const std::vector<std::string> kExtensions{".nii.gz", ".nii", ".nrrd", ".mha"};

// posewarp phantom bar.
void add_phantom_bar(CLI::App* group) {
  auto options = std::make_shared<PhantomOptions>();
  CLI::App* cmd = group->add_subcommand("bar", "The paper's bar: a soft cylinder holding a chain of bones (Fig. 7)");
  cmd->add_option("-o,--out-dir", options->out_dir, "Output directory")->required();
  cmd->add_option("--spacing", options->bar.spacing_mm, "Voxel spacing, mm")->capture_default_str();
  cmd->add_option("--length", options->bar.length_mm, "Bar length, mm")->capture_default_str();
  cmd->add_option("--radius", options->bar.radius_mm, "Soft-tissue radius, mm")->capture_default_str();
  cmd->add_option("--bone-radius", options->bar.bone_radius_mm, "Bone radius, mm")->capture_default_str();
  cmd->add_option("--bones", options->bar.bone_count, "Bones in the chain")->capture_default_str();
  cmd->add_option("--joint-gap", options->bar.joint_gap_mm, "Soft gap between bones, mm (0 = two voxels)")
      ->capture_default_str();
  cmd->add_option("--seed", options->bar.seed, "CT noise seed")->capture_default_str();
  cmd->add_option("--format", options->extension, "Volume file extension")->check(CLI::IsMember(kExtensions));
  cmd->callback([options] {
    Result<api::Phantom> p = api::make_bar(options->bar);
    int code = p.ok() ? write_phantom(*p, *options) : report(p.status());
    if (code != 0) throw CLI::RuntimeError(code);
  });
}

// posewarp phantom mannequin.
void add_phantom_mannequin(CLI::App* group) {
  auto options = std::make_shared<PhantomOptions>();
  CLI::App* cmd = group->add_subcommand(
      "mannequin",
      "A supine mannequin: pelvis, lumbar spine, thorax, legs, arms and head, with fat, a liver and a brain");
  cmd->add_option("-o,--out-dir", options->out_dir, "Output directory")->required();
  cmd->add_option("--spacing", options->mannequin.spacing_mm, "Voxel spacing, mm")->capture_default_str();
  cmd->add_option("--target-voxels", options->target_voxels,
                  "Choose the spacing that gives about this many voxels (overrides --spacing)")
      ->check(CLI::PositiveNumber);
  cmd->add_option("--height", options->mannequin.height_mm, "Standing height, mm")->capture_default_str();
  cmd->add_option("--joint-gap", options->mannequin.joint_gap_mm, "Soft gap at each joint, mm (0 = two voxels)")
      ->capture_default_str();
  cmd->add_option("--seed", options->mannequin.seed, "CT noise seed")->capture_default_str();
  cmd->add_option("--format", options->extension, "Volume file extension")->check(CLI::IsMember(kExtensions));
  cmd->callback([options] {
    if (options->target_voxels > 0) {
      options->mannequin.spacing_mm = api::mannequin_spacing_for_voxels(options->mannequin, options->target_voxels);
    }
    Result<api::Phantom> p = api::make_mannequin(options->mannequin);
    int code = p.ok() ? write_phantom(*p, *options) : report(p.status());
    if (code != 0) throw CLI::RuntimeError(code);
  });
}

// posewarp phantom body.
void add_phantom_body(CLI::App* group) {
  auto options = std::make_shared<PhantomOptions>();
  CLI::App* cmd = group->add_subcommand(
      "body",
      "A supine whole body as CT shows it, with exact joint truth. Skin: trunk, neck, head, fat shell, liver,\n"
      "brain; upper arms whose skin overlaps the trunk's, forearms along the flank, hands resting on the lateral\n"
      "thighs, thighs touching at the midline. Bones: pelvis (sacrum, hip halves, hemispherical acetabula),\n"
      "femur (head r 24, neck at 130 deg, trochanter, shaft inclined to the knee, condyle cylinder), patella,\n"
      "tibia (flat plateau, mortise), foot (talar dome); L5..L1, thorax (thoracic spine, rib shell, sternum),\n"
      "cervical spine, skull; clavicles, scapulae lying on the ribs with an acromion and a shallow glenoid,\n"
      "humerus (head r 22, trochlea), forearm (notch round the trochlea), hand. Hips and shoulders are balls,\n"
      "knees, elbows and ankles hinges about +x (axis in joints.json), the rest flat ends across a soft gap.\n"
      "Default grid: anisotropic (" +
          spacing_text(options->body.spacing_mm) + " mm) and oblique (8 deg about (1, 2, 6)), about 16M voxels.");
  cmd->add_option("-o,--out-dir", options->out_dir, "Output directory")->required();
  cmd->add_option("--spacing", options->spacing, "Voxel spacing X,Y,Z along the index axes, mm")
      ->delimiter(',')
      ->expected(3);
  cmd->add_option("--spacing-xy", options->spacing_xy, "In-plane spacing (index axes i, j), mm")
      ->check(CLI::PositiveNumber);
  cmd->add_option("--slice", options->slice, "Slice spacing (index axis k), mm")->check(CLI::PositiveNumber);
  cmd->add_option("--target-voxels", options->target_voxels,
                  "Scale the spacing, keeping its ratios, to give about this many voxels")
      ->check(CLI::PositiveNumber);
  cmd->add_option("--height", options->body.height_mm, "Standing height, mm")->capture_default_str();
  cmd->add_option("--joint-gap", options->body.joint_gap_mm, "Soft gap at each joint, mm (0 = 1.2 voxel diagonals)")
      ->capture_default_str();
  cmd->add_option("--seed", options->body.seed, "CT noise seed")->capture_default_str();
  cmd->add_option("--fat", options->body.fat_mm, "Subcutaneous fat thickness, mm")->capture_default_str();
  cmd->add_option("--skin-offset", options->body.skin_offset_mm,
                  "Skin grown outwards by this much, mm (0..100): a heavier body on the same skeleton (the grid grows "
                  "with it: --margin M with offset 0 gives the grid of --margin M-O with offset O, bone voxels alike)")
      ->capture_default_str();
  cmd->add_option("--margin", options->body.margin_mm, "Air around the body, mm")->capture_default_str();
  cmd->add_option("--format", options->extension, "Volume file extension")->check(CLI::IsMember(kExtensions));
  cmd->callback([options] {
    api::BodyParams& body = options->body;
    if (!options->spacing.empty()) body.spacing_mm = {options->spacing[0], options->spacing[1], options->spacing[2]};
    if (options->spacing_xy > 0.0) body.spacing_mm[0] = body.spacing_mm[1] = options->spacing_xy;
    if (options->slice > 0.0) body.spacing_mm[2] = options->slice;
    if (options->target_voxels > 0) body.spacing_mm = api::body_spacing_for_voxels(body, options->target_voxels);
    Result<api::Phantom> p = api::make_body(body);
    int code = p.ok() ? write_phantom(*p, *options) : report(p.status());
    if (code != 0) throw CLI::RuntimeError(code);
  });
}

}  // namespace

void add_phantom_commands(CLI::App& app) {
  CLI::App* group = app.add_subcommand(
      "phantom",
      "Write a synthetic body with exactly known joint centres (label + CT volumes, label map, joints.json)");
  group->require_subcommand(1);
  add_phantom_bar(group);
  add_phantom_mannequin(group);
  add_phantom_body(group);
}

}  // namespace posewarp::cli
