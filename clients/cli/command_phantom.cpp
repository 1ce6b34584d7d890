// Phantom commands: write the bar or the mannequin as label + CT volumes with their label map and joint truth.
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
};

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

}  // namespace

void add_phantom_commands(CLI::App& app) {
  CLI::App* group = app.add_subcommand(
      "phantom", "Write a synthetic body with exactly known joint centres (label + CT volumes, label map, joints.json)");
  group->require_subcommand(1);
  const std::vector<std::string> extensions{".nii.gz", ".nii", ".nrrd", ".mha"};
  {
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
    cmd->add_option("--format", options->extension, "Volume file extension")->check(CLI::IsMember(extensions));
    cmd->callback([options] {
      Result<api::Phantom> p = api::make_bar(options->bar);
      int code = p.ok() ? write_phantom(*p, *options) : report(p.status());
      if (code != 0) throw CLI::RuntimeError(code);
    });
  }
  {
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
    cmd->add_option("--format", options->extension, "Volume file extension")->check(CLI::IsMember(extensions));
    cmd->callback([options] {
      if (options->target_voxels > 0) {
        options->mannequin.spacing_mm = api::mannequin_spacing_for_voxels(options->mannequin, options->target_voxels);
      }
      Result<api::Phantom> p = api::make_mannequin(options->mannequin);
      int code = p.ok() ? write_phantom(*p, *options) : report(p.status());
      if (code != 0) throw CLI::RuntimeError(code);
    });
  }
}

}  // namespace posewarp::cli
