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
#include "posewarp/labels/body.h"
#include "posewarp/labels/label_map.h"
#include "posewarp/labels/presets.h"

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
  for (PixelType type : {PixelType::kUInt8, PixelType::kInt8, PixelType::kUInt16, PixelType::kInt16,
                         PixelType::kUInt32, PixelType::kInt32, PixelType::kFloat32, PixelType::kFloat64}) {
    if (pixel_type_name(type) == name) return type;
  }
  return std::nullopt;
}

const std::vector<std::string> kPixelTypeNames{"uint8", "int8", "uint16", "int16", "uint32", "int32", "float32", "float64"};

// ---- info -------------------------------------------------------------------------------------------------

struct InfoOptions {
  std::string path;
  bool as_json = false;
};

int run_info(const InfoOptions& options) {
  Result<io::VolumeHeader> header = io::read_header(options.path, read_options());
  if (!header.ok()) return report(header.status());
  Result<IntensityVolume> volume = io::read_intensity_volume(options.path, read_options());
  if (!volume.ok()) return report(volume.status());
  double lo = std::numeric_limits<double>::infinity(), hi = -lo, sum = 0.0;
  for (const float v : volume->voxels()) lo = std::min<double>(lo, v), hi = std::max<double>(hi, v), sum += v;
  const double mean = sum / static_cast<double>(std::max<int64_t>(1, volume->voxel_count()));
  const ImageGeometry& g = header->geometry;
  if (options.as_json) {
    json doc{{"path", options.path},
             {"format", io::format_name(header->format)},
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
            << "  format      " << io::format_name(header->format) << ", " << pixel_type_name(header->pixel_type)
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
  io::WriteOptions write;
  if (!options.pixel_type.empty()) write.pixel_type = parse_pixel_type(options.pixel_type);
  Status status;
  if (options.labels) {
    Result<LabelVolume> volume = io::read_label_volume(options.input, read_options());
    if (!volume.ok()) return report(volume.status());
    status = io::write_volume(*volume, options.output, write);
  } else {
    Result<IntensityVolume> volume = io::read_intensity_volume(options.input, read_options());
    if (!volume.ok()) return report(volume.status());
    status = io::write_volume(*volume, options.output, write);
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
  labels::BodyParams body;
};

Result<labels::LabelMap> load_label_map(const std::string& path, const std::string& preset) {
  if (!path.empty() && !preset.empty()) {
    return invalid_argument_error("give either --label-map or --preset, not both");
  }
  if (!path.empty()) return labels::read_label_map(path);
  return labels::preset_by_name(preset.empty() ? "totalsegmentator" : preset);
}

struct SegmentStats {
  int64_t voxels = 0;
  double sum[3] = {0, 0, 0};
};

int run_inspect(const InspectOptions& options) {
  const auto start = std::chrono::steady_clock::now();
  Result<labels::LabelMap> map = load_label_map(options.label_map_path, options.preset);
  if (!map.ok()) return report(map.status());
  Result<LabelVolume> seg = io::read_label_volume(options.labels_path, read_options());
  if (!seg.ok()) return report(seg.status());
  std::optional<IntensityVolume> ct;
  if (!options.ct_path.empty()) {
    Result<IntensityVolume> loaded = io::read_intensity_volume(options.ct_path, read_options());
    if (!loaded.ok()) return report(loaded.status());
    ct = std::move(loaded).value();
  }
  Result<LabelVolume> body = labels::body_mask(*map, *seg, ct ? &*ct : nullptr, options.body);
  if (!body.ok()) return report(body.status());
  const labels::LabelCensus census = labels::census(*map, *seg);
  const LabelVolume classes = labels::segment_classes(*map, *seg, *body);

  // Per bone segment: voxels and centroid.
  const std::vector<std::string> segments = map->bone_segments();
  std::vector<SegmentStats> stats(segments.size());
  const ImageGeometry& g = seg->geometry();
  for (int64_t k = 0; k < g.size[2]; ++k) {
    for (int64_t j = 0; j < g.size[1]; ++j) {
      for (int64_t i = 0; i < g.size[0]; ++i) {
        const Label c = classes.at(i, j, k);
        if (c < 2) continue;
        SegmentStats& s = stats[static_cast<size_t>(c - 2)];
        const Vec3 p = g.index_to_physical({static_cast<double>(i), static_cast<double>(j), static_cast<double>(k)});
        ++s.voxels;
        for (int a = 0; a < 3; ++a) s.sum[a] += p[a];
      }
    }
  }
  int64_t body_voxels = 0;
  for (const Label v : body->voxels()) body_voxels += v != 0;
  const double voxel_ml = g.spacing[0] * g.spacing[1] * g.spacing[2] / 1000.0;

  json doc;
  doc["labels"] = options.labels_path;
  doc["ct"] = options.ct_path;
  doc["label_map"] = map->name();
  doc["geometry"] = geometry_json(g);
  doc["body_voxels"] = body_voxels;
  doc["body_volume_ml"] = static_cast<double>(body_voxels) * voxel_ml;
  json bones = json::array();
  for (size_t s = 0; s < segments.size(); ++s) {
    if (stats[s].voxels == 0) continue;
    const double n = static_cast<double>(stats[s].voxels);
    bones.push_back({{"segment", segments[s]},
                     {"class", 2 + s},
                     {"voxels", stats[s].voxels},
                     {"volume_ml", n * voxel_ml},
                     {"centroid_mm", {stats[s].sum[0] / n, stats[s].sum[1] / n, stats[s].sum[2] / n}}});
  }
  doc["bone_segments"] = bones;
  doc["absent_bone_segments"] = census.absent_bone_segments;
  json tissues = json::array();
  for (const auto& [value, count] : census.voxel_counts) {
    const labels::LabelEntry* entry = map->find(value);
    if (value == 0 || (entry && entry->role == labels::LabelRole::kBone)) continue;
    tissues.push_back({{"value", value}, {"name", entry ? entry->name : "unknown"}, {"voxels", count}});
  }
  doc["tissues"] = tissues;
  doc["unknown_labels"] = census.unknown;

  if (!options.out_dir.empty()) {
    std::error_code ec;
    fs::create_directories(options.out_dir, ec);
    if (ec) return report(invalid_argument_error("cannot create " + options.out_dir + ": " + ec.message()));
    const std::string body_path = (fs::path(options.out_dir) / "body_mask.nii.gz").string();
    const std::string classes_path = (fs::path(options.out_dir) / "segment_classes.nii.gz").string();
    if (Status s = io::write_volume(*body, body_path); !s.ok()) return report(s);
    if (Status s = io::write_volume(classes, classes_path); !s.ok()) return report(s);
    std::ofstream((fs::path(options.out_dir) / "inspect.json").string()) << doc.dump(2) << '\n';
    doc["written"] = {body_path, classes_path, (fs::path(options.out_dir) / "inspect.json").string()};
  }
  const double seconds = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  doc["seconds"] = seconds;

  if (options.as_json) {
    std::cout << doc.dump(2) << '\n';
    return 0;
  }
  std::cout << "study        " << options.labels_path << (ct ? " + " + options.ct_path : std::string()) << "\n"
            << "grid         " << g.describe() << ", axes point " << orientation_code(g) << "\n"
            << "label map    " << map->name() << " (" << map->entries().size() << " labels)\n"
            << "body         " << body_voxels << " voxels, " << fixed(static_cast<double>(body_voxels) * voxel_ml, 1)
            << " ml" << (ct ? " (labels joined with CT > " + fixed(options.body.ct_threshold_hu, 0) + " HU)" : "")
            << "\n"
            << "bone segments found: " << bones.size() << "\n";
  for (const json& bone : bones) {
    const auto& c = bone["centroid_mm"];
    std::cout << "  " << std::left << std::setw(18) << bone["segment"].get<std::string>() << std::right
              << std::setw(8) << bone["voxels"].get<int64_t>() << " voxels  centroid (" << fixed(c[0], 1) << ", "
              << fixed(c[1], 1) << ", " << fixed(c[2], 1) << ") mm\n";
  }
  if (!census.absent_bone_segments.empty()) {
    std::cout << "bone segments of the map not in this study (outside the field of view?): "
              << census.absent_bone_segments.size() << "\n";
  }
  std::cout << "soft-tissue labels: " << tissues.size() << "\n";
  if (!census.unknown.empty()) {
    std::cout << "warning: labels not named by the map (treated as soft tissue):";
    for (const Label value : census.unknown) std::cout << ' ' << value;
    std::cout << "\n";
  }
  if (doc.contains("written")) {
    for (const auto& path : doc["written"]) std::cout << "wrote " << path.get<std::string>() << "\n";
  }
  std::cout << "took " << fixed(seconds, 2) << " s\n";
  return 0;
}

}  // namespace

void add_volume_commands(CLI::App& app) {
  {
    auto options = std::make_shared<InfoOptions>();
    CLI::App* cmd = app.add_subcommand("info", "Print a volume's header (grid, orientation, voxel type) and value range");
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
        ->check(CLI::IsMember(labels::preset_names()));
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
