// DICOM commands: export (a study that never was DICOM as a CT series and its SEG, for a PACS or a test) and info
// (what a CT series or SEG holds, as posewarp reads it).
#include <algorithm>
#include <filesystem>

#include "cli_support.h"
#include "dicom_format_options.h"
#include "pacs_options.h"
#include "posewarp/api/dicom.h"
#include "posewarp/api/files.h"

namespace posewarp::cli {
namespace {

namespace fs = std::filesystem;

struct ExportOptions {
  std::string ct_path, labels_path, label_map_path, preset = "totalsegmentator", out;
  std::string patient_name = "Anonymous", patient_id = "POSEWARP", uid_root = "2.25";
  DicomFormatOptions formats;
};

int run_export(const ExportOptions& o) {
  if (Status s = refuse_overwriting_inputs({o.out}, {o.ct_path, o.labels_path, o.label_map_path}); !s.ok())
    return report(s);
  // A map of one's own replaces the preset.
  Result<api::LabelMap> map = load_label_map(o.label_map_path, o.label_map_path.empty() ? o.preset : std::string());
  if (!map.ok()) return report(map.status());
  Result<IntensityVolume> ct = api::read_intensity_volume(o.ct_path, read_options());
  if (!ct.ok()) return report(ct.status());
  Result<LabelVolume> labels = api::read_label_volume(o.labels_path, read_options());
  if (!labels.ok()) return report(labels.status());
  if (!labels->geometry().same_grid(ct->geometry())) {
    return report(invalid_argument_error("the labels '" + o.labels_path +
                                         "' are not on the CT's grid; a SEG must lie "
                                         "on its CT series' grid"));
  }
  api::DerivedSeriesOptions options;
  options.uid_root = o.uid_root;
  o.formats.apply(&options);
  options.series_description = "CT (" + fs::path(o.ct_path).filename().string() + ")";
  Result<api::DicomOutputs> outputs =
      api::encode_new_dicom_study(*ct, *labels, *map, o.patient_name, o.patient_id, options);
  if (!outputs.ok()) return report(outputs.status());
  if (Status s = api::write_dicom_outputs(*outputs, o.out); !s.ok()) return report(s);
  const std::string written = outputs->ct.frame_numbers.empty()
                                  ? "a CT series of " + std::to_string(outputs->ct_files.size()) + " images"
                                  : "an Enhanced CT of " + std::to_string(outputs->ct.slice_count()) + " frames";
  say("wrote " + written + " (" + o.out + "/ct/) and its " + o.formats.seg + " SEG (" + o.out + "/seg.dcm), study " +
      outputs->ct.study_instance_uid);
  return 0;
}

struct InfoOptions {
  std::string ct_dir, seg_path, label_map_path, preset = "totalsegmentator";
};

int run_dicom_info(const InfoOptions& o) {
  Result<api::CtSeries> series = api::read_ct_directory(o.ct_dir);
  if (!series.ok()) return report(series.status());
  const api::SeriesInfo& i = series->info;
  const ImageGeometry& g = series->ct.geometry();
  std::printf("study %s, series %s (%s), %s\n", i.study_instance_uid.c_str(), i.series_instance_uid.c_str(),
              i.series_description.c_str(),
              i.frame_numbers.empty()
                  ? (std::to_string(i.slice_count()) + " images").c_str()
                  : ("one multi-frame image of " + std::to_string(i.slice_count()) + " frames").c_str());
  std::printf("grid %lld x %lld x %lld, spacing %.3f x %.3f x %.3f mm\n", static_cast<long long>(g.size[0]),
              static_cast<long long>(g.size[1]), static_cast<long long>(g.size[2]), g.spacing[0], g.spacing[1],
              g.spacing[2]);
  if (o.seg_path.empty()) return 0;
  // A map of one's own replaces the preset.
  Result<api::LabelMap> map = load_label_map(o.label_map_path, o.label_map_path.empty() ? o.preset : std::string());
  if (!map.ok()) return report(map.status());
  Result<api::DicomStudy> study = api::read_dicom_study(o.ct_dir, o.seg_path, *map);
  if (!study.ok()) return report(study.status());
  for (const api::DicomSegment& s : study->segments) {
    const api::LabelEntry* entry = study->label_map.find(s.number);
    std::printf("segment %3d  %-28s %s\n", s.number, s.label.c_str(),
                entry != nullptr ? std::string(api::role_name(entry->role)).c_str() : "?");
  }
  for (const std::string& warning : study->warnings) say("warning: " + warning);
  return 0;
}

struct StoreOptions {
  PacsOptions pacs;
  std::vector<std::string> paths;
};

// Each path (a DICOM file, or a directory of them) stored with one STOW-RS request.
int run_store(const StoreOptions& o) {
  Result<api::DicomWebOptions> options = dicomweb_options(o.pacs);
  if (!options.ok()) return report(options.status());
  const api::Pacs client(*options);
  for (const std::string& path : o.paths) {
    Result<std::vector<std::string>> files = api::list_dicom_files(path);
    if (!files.ok()) return report(files.status());
    if (Status s = client.store_files(*files); !s.ok()) return report(s.with_context(path));
    say("stored " + std::to_string(files->size()) + " instances from " + path);
  }
  return 0;
}

}  // namespace

void add_dicom_commands(CLI::App& app) {
  CLI::App* dicom = app.add_subcommand("dicom", "DICOM CT series and segmentations (SEG)");
  dicom->require_subcommand(1);
  {
    auto o = std::make_shared<ExportOptions>();
    CLI::App* cmd = dicom->add_subcommand(
        "export",
        "Write a CT and its labels (NIfTI, NRRD, ...) as a new DICOM study: a CT series (OUT/ct/) and a SEG "
        "(OUT/seg.dcm) whose segments carry the label map's names");
    cmd->add_option("--ct", o->ct_path, "CT volume")->required();
    cmd->add_option("--labels", o->labels_path, "Label volume on the CT's grid")->required();
    cmd->add_option("--preset", o->preset, "Built-in label map naming the labels")->capture_default_str();
    cmd->add_option("--label-map", o->label_map_path, "A label map of one's own instead");
    cmd->add_option("--patient-name", o->patient_name, "Patient's Name (DICOM PN, e.g. Doe^Jane)")
        ->capture_default_str();
    cmd->add_option("--patient-id", o->patient_id, "Patient ID")->capture_default_str();
    cmd->add_option("--uid-root", o->uid_root, "Root of the new UIDs (2.25: UUID-derived)")->capture_default_str();
    add_dicom_format_options(cmd, o->formats);
    cmd->add_option("-o,--out", o->out, "Output directory (new or empty)")->required();
    cmd->callback([o] {
      if (int code = run_export(*o); code != 0) throw CLI::RuntimeError(code);
    });
  }
  {
    auto o = std::make_shared<StoreOptions>();
    CLI::App* cmd =
        dicom->add_subcommand("store", "Store DICOM files (or directories of them) in a PACS through STOW-RS");
    cmd->add_option("paths", o->paths, "DICOM files or directories (one request each)")->required();
    add_pacs_options(cmd, o->pacs);
    cmd->callback([o] {
      if (int code = run_store(*o); code != 0) throw CLI::RuntimeError(code);
    });
  }
  {
    auto o = std::make_shared<InfoOptions>();
    CLI::App* cmd =
        dicom->add_subcommand("info", "What a DICOM CT series (and a SEG made on it) holds, as posewarp reads it");
    cmd->add_option("ct", o->ct_dir, "Directory of the CT series' files")->required();
    cmd->add_option("--seg", o->seg_path,
                    "A SEG made on that series: its segments and the roles the label map gives them");
    cmd->add_option("--preset", o->preset, "Built-in label map the segments' names are looked up in")
        ->capture_default_str();
    cmd->add_option("--label-map", o->label_map_path, "A label map of one's own instead");
    cmd->callback([o] {
      if (int code = run_dicom_info(*o); code != 0) throw CLI::RuntimeError(code);
    });
  }
}

}  // namespace posewarp::cli
