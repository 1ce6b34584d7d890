// Phantom commands: write the bar or the mannequin as label + CT volumes with their label map and joint truth.
#include <filesystem>
#include <fstream>

#include "cli_support.h"
#include "posewarp/labels/label_map.h"
#include "posewarp/phantom/phantom.h"

namespace posewarp::cli {
namespace {

namespace fs = std::filesystem;

struct PhantomOptions {
  std::string out_dir;
  std::string extension = ".nii.gz";
  int64_t target_voxels = 0;
  phantom::BarParams bar;
  phantom::MannequinParams mannequin;
};

int write_phantom(const phantom::Phantom& p, const PhantomOptions& options) {
  std::error_code ec;
  fs::create_directories(options.out_dir, ec);
  if (ec) return report(invalid_argument_error("cannot create " + options.out_dir + ": " + ec.message()));
  const fs::path dir(options.out_dir);
  const std::string labels_path = (dir / ("labels" + options.extension)).string();
  const std::string ct_path = (dir / ("ct" + options.extension)).string();
  if (Status s = io::write_volume(p.labels, labels_path); !s.ok()) return report(s);
  if (Status s = io::write_volume(p.ct, ct_path); !s.ok()) return report(s);
  if (Status s = labels::write_label_map(p.label_map, (dir / "label_map.json").string()); !s.ok()) return report(s);
  {
    std::ofstream out(dir / "joints.json");
    out << phantom::joints_to_json(p);
    if (!out) return report(internal_error("cannot write " + (dir / "joints.json").string()));
  }
  say(p.name + ": " + p.labels.geometry().describe() + " (" + std::to_string(p.labels.voxel_count()) + " voxels), " +
      std::to_string(p.label_map.bone_segments().size()) + " bone segments, " + std::to_string(p.joints.size()) +
      " joints");
  say("wrote " + labels_path + ", " + ct_path + ", " + (dir / "label_map.json").string() + ", " +
      (dir / "joints.json").string());
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
      Result<phantom::Phantom> p = phantom::make_bar(options->bar);
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
        options->mannequin.spacing_mm = phantom::mannequin_spacing_for_voxels(options->mannequin, options->target_voxels);
      }
      Result<phantom::Phantom> p = phantom::make_mannequin(options->mannequin);
      int code = p.ok() ? write_phantom(*p, *options) : report(p.status());
      if (code != 0) throw CLI::RuntimeError(code);
    });
  }
}

}  // namespace posewarp::cli
