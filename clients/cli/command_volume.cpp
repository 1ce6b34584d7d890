// Volume commands: info, convert, inspect (the study check that precedes a rig build).
#include <nlohmann/json.hpp>

#include <chrono>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <iomanip>
#include <limits>
#include <map>
#include <sstream>

#include "cli_support.h"
#include "posewarp/api/files.h"
#include "posewarp/api/study.h"

namespace posewarp::cli {
namespace {

using json = nlohmann::json;
namespace fs = std::filesystem;

// "LPS"-style code: the patient direction each index axis points to most.
std::string orientation_code(const ImageGeometry& g) {
  std::string code;
  for (int axis = 0; axis < 3; ++axis) {
    int best = 0;
    for (int r = 1; r < 3; ++r) {
      if (std::abs(g.direction[3 * r + axis]) > std::abs(g.direction[3 * best + axis])) best = r;
    }
    const bool positive = g.direction[3 * best + axis] > 0;
    const char* letters[3][2] = {{"R", "L"}, {"A", "P"}, {"I", "S"}};
    code += letters[best][positive ? 1 : 0];
  }
  return code;
}

json geometry_json(const ImageGeometry& g) {
  return {{"size", {g.size[0], g.size[1], g.size[2]}},
          {"spacing_mm", {g.spacing[0], g.spacing[1], g.spacing[2]}},
          {"origin_mm", {g.origin[0], g.origin[1], g.origin[2]}},
          {"direction", g.direction},
          {"orientation", orientation_code(g)}};
}

std::string fixed(double value, int digits) {
  std::ostringstream out;
  out << std::fixed << std::setprecision(digits) << value;
  return out.str();
}

std::optional<PixelType> parse_pixel_type(const std::string& name) {
  for (PixelType type : {PixelType::kUInt8, PixelType::kInt8, PixelType::kUInt16, PixelType::kInt16, PixelType::kUInt32,
                         PixelType::kInt32, PixelType::kFloat32, PixelType::kFloat64}) {
    if (pixel_type_name(type) == name) return type;
  }
  return std::nullopt;
}

const std::vector<std::string> kPixelTypeNames{"uint8",  "int8",  "uint16",  "int16",
                                               "uint32", "int32", "float32", "float64"};

// ---- info -------------------------------------------------------------------------------------------------

struct InfoOptions {
  std::string path;
  bool as_json = false;
};

int run_info(const InfoOptions& options) {
  Result<api::VolumeHeader> header = api::read_header(options.path, read_options());
  if (!header.ok()) return report(header.status());
  Result<IntensityVolume> volume = api::read_intensity_volume(options.path, read_options());
  if (!volume.ok()) return report(volume.status());
  double lo = std::numeric_limits<double>::infinity(), hi = -lo, sum = 0.0;
  for (const float v : volume->voxels()) lo = std::min<double>(lo, v), hi = std::max<double>(hi, v), sum += v;
  const double mean = sum / static_cast<double>(std::max<int64_t>(1, volume->voxel_count()));
  const ImageGeometry& g = header->geometry;
  if (options.as_json) {
    json doc{{"path", options.path},
             {"format", api::format_name(header->format)},
             {"pixel_type", pixel_type_name(header->pixel_type)},
             {"geometry", geometry_json(g)},
             {"voxels", g.voxel_count()},
             {"min", lo},
             {"max", hi},
             {"mean", mean}};
    std::cout << doc.dump(2) << '\n';
    return 0;
  }
  std::cout << options.path << "\n"
            << "  format      " << api::format_name(header->format) << ", " << pixel_type_name(header->pixel_type)
            << "\n"
            << "  grid        " << g.describe() << " (" << g.voxel_count() << " voxels)\n"
            << "  origin      " << fixed(g.origin[0], 3) << ", " << fixed(g.origin[1], 3) << ", "
            << fixed(g.origin[2], 3) << " mm (LPS)\n"
            << "  axes point  " << orientation_code(g) << "\n"
            << "  values      " << lo << " .. " << hi << ", mean " << fixed(mean, 2) << "\n";
  return 0;
}

// ---- convert ----------------------------------------------------------------------------------------------

struct ConvertOptions {
  std::string input;
  std::string output;
  bool labels = false;
  std::string pixel_type;
};

int run_convert(const ConvertOptions& options) {
  if (Status s = refuse_overwriting_inputs({options.output}, {options.input}); !s.ok()) return report(s);
  api::WriteOptions write;
  if (!options.pixel_type.empty()) write.pixel_type = parse_pixel_type(options.pixel_type);
  Status status;
  if (options.labels) {
    Result<LabelVolume> volume = api::read_label_volume(options.input, read_options());
    if (!volume.ok()) return report(volume.status());
    status = api::write_volume(*volume, options.output, write);
  } else {
    Result<IntensityVolume> volume = api::read_intensity_volume(options.input, read_options());
    if (!volume.ok()) return report(volume.status());
    status = api::write_volume(*volume, options.output, write);
  }
  if (!status.ok()) return report(status);
  say("wrote " + options.output);
  return 0;
}

// ---- inspect ----------------------------------------------------------------------------------------------

struct InspectOptions {
  std::string labels_path;
  std::string ct_path;
  std::string label_map_path;
  std::string preset;
  std::string out_dir;
  bool as_json = false;
  api::BodyMaskParams body;
};

// What inspect found, as its JSON document: the grid, the body, each bone segment and each soft-tissue label.
json inspection_json(const InspectOptions& options, const api::LabelMap& map, const ImageGeometry& g,
                     const api::StudyInspection& study) {
  json doc;
  doc["labels"] = options.labels_path;
  doc["ct"] = options.ct_path;
  doc["label_map"] = map.name();
  doc["geometry"] = geometry_json(g);
  doc["body_voxels"] = study.body_voxels;
  doc["body_volume_ml"] = study.body_volume_ml;
  json bones = json::array();
  for (const api::BoneSegmentSummary& bone : study.bones) {
    bones.push_back({{"segment", bone.segment},
                     {"class", bone.mesher_class},
                     {"voxels", bone.voxels},
                     {"volume_ml", bone.volume_ml},
                     {"centroid_mm", {bone.centroid_mm.x(), bone.centroid_mm.y(), bone.centroid_mm.z()}}});
  }
  doc["bone_segments"] = bones;
  doc["absent_bone_segments"] = study.census.absent_bone_segments;
  json tissues = json::array();
  for (const auto& [value, count] : study.census.voxel_counts) {
    const api::LabelEntry* entry = map.find(value);
    if (value == 0 || (entry && entry->role == api::LabelRole::kBone)) continue;
    tissues.push_back({{"value", value}, {"name", entry ? entry->name : "unknown"}, {"voxels", count}});
  }
  doc["tissues"] = tissues;
  doc["unknown_labels"] = study.census.unknown;
  return doc;
}

// --out-dir: the body mask, the mesher's classes and the JSON document, named in doc["written"].
Status write_inspection(const InspectOptions& options, const api::StudyInspection& study, json& doc) {
  std::error_code ec;
  fs::create_directories(options.out_dir, ec);
  if (ec) return invalid_argument_error("cannot create " + options.out_dir + ": " + ec.message());
  const std::string body_path = (fs::path(options.out_dir) / "body_mask.nii.gz").string();
  const std::string classes_path = (fs::path(options.out_dir) / "segment_classes.nii.gz").string();
  POSEWARP_RETURN_IF_ERROR(api::write_volume(study.body, body_path));
  POSEWARP_RETURN_IF_ERROR(api::write_volume(study.classes, classes_path));
  const std::string json_path = (fs::path(options.out_dir) / "inspect.json").string();
  POSEWARP_RETURN_IF_ERROR(api::write_file_atomically(json_path, doc.dump(2) + "\n", "inspection"));
  doc["written"] = {body_path, classes_path, json_path};
  return Status();
}

// The same for a reader: the study, the body, the bones found and what the map did not name.
void print_inspection(const InspectOptions& options, bool with_ct, const api::LabelMap& map, const ImageGeometry& g,
                      const api::StudyInspection& study, const json& doc) {
  const json& bones = doc["bone_segments"];
  const api::LabelCensus& census = study.census;
  std::cout << "study        " << options.labels_path << (with_ct ? " + " + options.ct_path : std::string()) << "\n"
            << "grid         " << g.describe() << ", axes point " << orientation_code(g) << "\n"
            << "label map    " << map.name() << " (" << map.entries().size() << " labels)\n"
            << "body         " << study.body_voxels << " voxels, " << fixed(study.body_volume_ml, 1) << " ml"
            << (with_ct ? " (labels joined with CT > " + fixed(options.body.ct_threshold_hu, 0) + " HU)" : "") << "\n"
            << "bone segments found: " << bones.size() << "\n";
  for (const json& bone : bones) {
    const auto& c = bone["centroid_mm"];
    std::cout << "  " << std::left << std::setw(18) << bone["segment"].get<std::string>() << std::right << std::setw(8)
              << bone["voxels"].get<int64_t>() << " voxels  centroid (" << fixed(c[0], 1) << ", " << fixed(c[1], 1)
              << ", " << fixed(c[2], 1) << ") mm\n";
  }
  if (!census.absent_bone_segments.empty()) {
    std::cout << "bone segments of the map not in this study (outside the field of view?): "
              << census.absent_bone_segments.size() << "\n";
  }
  std::cout << "soft-tissue labels: " << doc["tissues"].size() << "\n";
  if (!census.unknown.empty()) {
    std::cout << "warning: labels not named by the map (treated as soft tissue):";
    for (const Label value : census.unknown) std::cout << ' ' << value;
    std::cout << "\n";
  }
  if (doc.contains("written")) {
    for (const auto& path : doc["written"]) std::cout << "wrote " << path.get<std::string>() << "\n";
  }
  std::cout << "took " << fixed(doc["seconds"].get<double>(), 2) << " s\n";
}

int run_inspect(const InspectOptions& options) {
  const auto start = std::chrono::steady_clock::now();
  Result<api::LabelMap> map = load_label_map(options.label_map_path, options.preset);
  if (!map.ok()) return report(map.status());
  Result<LabelVolume> seg = api::read_label_volume(options.labels_path, read_options());
  if (!seg.ok()) return report(seg.status());
  std::optional<IntensityVolume> ct;
  if (!options.ct_path.empty()) {
    Result<IntensityVolume> loaded = api::read_intensity_volume(options.ct_path, read_options());
    if (!loaded.ok()) return report(loaded.status());
    ct = std::move(loaded).value();
  }
  Result<api::StudyInspection> study = api::inspect_study(*seg, ct ? &*ct : nullptr, *map, options.body);
  if (!study.ok()) return report(study.status());
  json doc = inspection_json(options, *map, seg->geometry(), *study);
  if (!options.out_dir.empty()) {
    if (Status s = write_inspection(options, *study, doc); !s.ok()) return report(s);
  }
  doc["seconds"] = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (options.as_json) {
    std::cout << doc.dump(2) << '\n';
    return 0;
  }
  print_inspection(options, ct.has_value(), *map, seg->geometry(), *study, doc);
  return 0;
}

}  // namespace

void add_volume_commands(CLI::App& app) {
  {
    auto options = std::make_shared<InfoOptions>();
    CLI::App* cmd =
        app.add_subcommand("info", "Print a volume's header (grid, orientation, voxel type) and value range");
    cmd->add_option("volume", options->path, "Volume file or DICOM directory")->required();
    cmd->add_flag("--json", options->as_json, "Machine-readable output");
    cmd->callback([options] {
      if (int code = run_info(*options); code != 0) throw CLI::RuntimeError(code);
    });
  }
  {
    auto options = std::make_shared<ConvertOptions>();
    CLI::App* cmd = app.add_subcommand(
        "convert", "Convert a volume between NIfTI, NRRD, MetaImage and DICOM series, keeping its geometry");
    cmd->add_option("input", options->input, "Input volume")->required();
    cmd->add_option("output", options->output, "Output volume (format from the extension; no extension = DICOM dir)")
        ->required();
    cmd->add_flag("--labels", options->labels, "Treat as a label volume (integer values, checked)");
    cmd->add_option("--pixel-type", options->pixel_type, "Voxel type on disk (default: as read)")
        ->check(CLI::IsMember(kPixelTypeNames));
    cmd->callback([options] {
      if (int code = run_convert(*options); code != 0) throw CLI::RuntimeError(code);
    });
  }
  {
    auto options = std::make_shared<InspectOptions>();
    CLI::App* cmd = app.add_subcommand(
        "inspect",
        "Load a segmentation (and its CT), report the bone segments, tissues and body it finds, and write the body\n"
        "mask and the mesher's class volume (0 outside, 1 soft tissue, 2+k bone segment k)");
    cmd->add_option("--labels", options->labels_path, "Label volume (segmentation)")->required();
    cmd->add_option("--ct", options->ct_path, "CT on the same grid (joins a threshold mask to the body)");
    cmd->add_option("--label-map", options->label_map_path, "Label map JSON (see `posewarp labels preset`)");
    cmd->add_option("--preset", options->preset, "Built-in label map (default: totalsegmentator)")
        ->check(CLI::IsMember(api::preset_names()));
    cmd->add_option("--body-threshold", options->body.ct_threshold_hu, "CT threshold for the body mask, HU")
        ->capture_default_str();
    cmd->add_option("-o,--out-dir", options->out_dir, "Write body_mask.nii.gz, segment_classes.nii.gz, inspect.json");
    cmd->add_flag("--json", options->as_json, "Machine-readable output");
    cmd->callback([options] {
      if (int code = run_inspect(*options); code != 0) throw CLI::RuntimeError(code);
    });
  }
}

}  // namespace posewarp::cli
