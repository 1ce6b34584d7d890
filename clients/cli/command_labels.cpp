// Label-map commands: write a preset for editing, check a map against a segmentation.
#include <iostream>

#include "cli_support.h"
#include "posewarp/api/files.h"

namespace posewarp::cli {

void add_label_commands(CLI::App& app) {
  CLI::App* group = app.add_subcommand("labels", "Label maps: which label value is which bone segment or tissue");
  group->require_subcommand(1);
  {
    auto name = std::make_shared<std::string>();
    auto out = std::make_shared<std::string>();
    CLI::App* cmd = group->add_subcommand("preset", "Write a built-in label map as JSON (a starting point to edit)");
    cmd->add_option("name", *name, "Preset name")->required()->check(CLI::IsMember(api::preset_names()));
    cmd->add_option("-o,--out", *out, "Output JSON file (default: stdout)");
    cmd->callback([name, out] {
      Result<api::LabelMap> map = api::load_label_map("", *name);
      if (!map.ok()) throw CLI::RuntimeError(report(map.status()));
      if (out->empty()) {
        std::cout << api::label_map_to_json(*map);
        return;
      }
      if (Status s = api::write_label_map(*map, *out); !s.ok()) throw CLI::RuntimeError(report(s));
      say("wrote " + *out);
    });
  }
  {
    auto path = std::make_shared<std::string>();
    CLI::App* cmd = group->add_subcommand("check", "Validate a label map JSON file and summarize it");
    cmd->add_option("map", *path, "Label map JSON")->required();
    cmd->callback([path] {
      Result<api::LabelMap> map = api::read_label_map(*path);
      if (!map.ok()) throw CLI::RuntimeError(report(map.status()));
      std::cout << map->name() << ": " << map->entries().size() << " labels, " << map->bone_segments().size()
                << " bone segments, " << map->joint_names().size() << " joint names"
                << (map->root_segment().empty() ? std::string() : ", root " + map->root_segment()) << "\n";
    });
  }
}

}  // namespace posewarp::cli
