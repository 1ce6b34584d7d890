// posewarp: re-pose segmented CT/MRI volumes (command-line entry point).
#include <CLI/CLI.hpp>

#include <exception>
#include <iostream>
#include <new>

#include "cli_support.h"
#include "posewarp/api/support.h"

int main(int argc, char** argv) {
  using namespace posewarp;
  CLI::App app{
      "posewarp re-poses segmented CT/MRI volumes: it builds a tetrahedral rig from a label volume (and its CT)\n"
      "once, then warps labels and CT into new poses without holes or new label values.\n\n"
      "Volumes: NIfTI (.nii, .nii.gz), NRRD (.nrrd, .nhdr), MetaImage (.mha, .mhd) or a DICOM series (a directory).",
      "posewarp"};
  app.set_version_flag("--version", std::string("posewarp ") + POSEWARP_VERSION);
  app.require_subcommand(1);
  cli::GlobalOptions& global = cli::global_options();
  app.add_option("--threads", global.threads, "Worker threads (0 = all cores)")->check(CLI::NonNegativeNumber);
  app.add_option("--max-voxels", global.max_voxels, "Refuse volumes with more voxels than this")
      ->check(CLI::PositiveNumber);
  app.add_flag("-q,--quiet", global.quiet, "Print only errors");
  app.parse_complete_callback([&global] { set_thread_count(global.threads); });

  cli::add_volume_commands(app);
  cli::add_phantom_commands(app);
  cli::add_label_commands(app);
  cli::add_rig_commands(app);
  cli::add_pose_commands(app);
  cli::add_match_command(app);
  cli::add_dicom_commands(app);
  cli::add_batch_command(app);
  cli::add_health_command(app);

  try {
    app.parse(argc, argv);
  } catch (const CLI::ParseError& error) {
    // A command's own failure carries its exit code; help and version are 0; any usage error is bad input (2).
    const int code = app.exit(error);
    if (dynamic_cast<const CLI::RuntimeError*>(&error) != nullptr || code == 0) return code;
    return 2;
  } catch (const std::bad_alloc&) {
    // The stages turn their own allocation failures into statuses; this is the last wall, for the CLI's own code.
    std::cerr << "error: out of memory; free memory, or use a smaller volume or coarser settings\n";
    return 3;
  } catch (const std::exception& error) {
    std::cerr << "error: unexpected failure: " << error.what() << " (please report this as a bug)\n";
    return 1;
  }
  return 0;
}
