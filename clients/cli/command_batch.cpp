// posewarp batch: the rows of a manifest (JSON or CSV), or of a PACS query, posed in parallel: each study's rig built
// once and reused by every pose of that study, results written to directories and/or stored back into the PACS,
// progress on the way, a state file that makes a rerun skip what is done, and a summary (JSON and CSV). With
// --server the rigs are built and the poses answered by posewarp-server; reading and writing DICOM stay here.
#include <nlohmann/json.hpp>

#include <algorithm>
#include <atomic>
#include <chrono>
#include <condition_variable>
#include <filesystem>
#include <fstream>
#include <future>
#include <map>
#include <mutex>
#include <set>
#include <sstream>
#include <thread>

#include "batch_manifest.h"
#include "cli_support.h"
#include "dicom_format_options.h"
#include "pacs_options.h"
#include "posewarp/api/dicom.h"
#include "posewarp/api/files.h"
#include "posewarp/api/match.h"
#include "posewarp/api/pacs.h"
#include "posewarp/api/pose_engine.h"
#include "posewarp/api/rig_file.h"
#include "posewarp/api/support.h"
#include "remote.h"

namespace posewarp::cli {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

struct BatchOptions {
  std::string manifest, state, summary, rig_cache;
  int jobs = 1;
  PacsOptions pacs;
  Connection server;  // rows posed by posewarp-server (one rig per study built there) instead of in this process
  std::string uid_root = "2.25";
  DicomFormatOptions dicom_formats;
  // Rows from a query instead of a manifest.
  std::string query, pose, animation, method = "cor", out_dir;
  bool to_pacs = false;
};

// A study ready to pose: its engine (poses of one study run one at a time on it) or its rig on the server, and where
// it came from.
struct Study {
  std::unique_ptr<api::PoseEngine> engine;
  std::mutex posing;
  std::optional<RemotePoser> remote;     // with --server: the study's rig there (the server runs poses side by side)
  std::string rig_id;                    // ... and its id
  api::LabelMap label_map;            // the rig's, naming the segments of a SEG
  std::optional<api::SeriesInfo> dicom;  // the source CT series, for derived series
  double fetch_s = 0, rig_s = 0;
  bool rig_cached = false;
};

struct RowResult {
  std::string status = "failed", error;
  std::vector<std::string> outputs;
  json figures = json::object();
  double fetch_s = 0, rig_s = 0, pose_s = 0, encode_s = 0, store_s = 0;
};

class Batch {
 public:
  Batch(BatchOptions options, std::vector<Row> rows) : o_(std::move(options)), rows_(std::move(rows)) {}

  int run() {
    if (Status s = open_pacs(); !s.ok()) return report(s);
    // Rows the state file says are done are skipped.
    std::map<std::string, std::vector<std::string>> done;  // row key -> its outputs
    {
      std::ifstream in(o_.state);
      for (std::string line; std::getline(in, line);) {
        const json entry = json::parse(line, nullptr, false);
        if (entry.is_object() && entry.value("status", "") == "done") {
          std::vector<std::string>& outputs = done[entry.value("key", "")];
          if (entry.contains("outputs") && entry["outputs"].is_array()) {
            for (const json& out : entry["outputs"]) {
              if (out.is_string()) outputs.push_back(out.get<std::string>());
            }
          }
        }
      }
    }
    results_.resize(rows_.size());
    std::vector<size_t> todo;
    for (size_t i = 0; i < rows_.size(); ++i) {
      keys_.push_back(row_key(rows_[i]));
      if (const auto found = done.find(keys_[i]); found != done.end()) {
        results_[i].status = "skipped";
        results_[i].outputs = found->second;  // as the run that did it recorded them
      } else {
        todo.push_back(i);
        ++rows_left_[rows_[i].study_key()];
      }
    }
    say("batch: " + std::to_string(rows_.size()) + " rows, " + std::to_string(rows_.size() - todo.size()) +
        " done before (skipped), " + std::to_string(todo.size()) + " to run with " + std::to_string(o_.jobs) + " jobs");
    const Stopwatch start;
    std::atomic<size_t> next{0};
    std::vector<std::thread> workers;
    std::atomic<bool> finished{false};
    std::thread progress([&] {
      while (!finished) {
        for (int i = 0; i < 20 && !finished; ++i) std::this_thread::sleep_for(std::chrono::milliseconds(100));
        if (!finished) say(progress_line(todo.size(), start));
      }
    });
    for (int w = 0; w < std::max(1, o_.jobs); ++w) {
      workers.emplace_back([&] {
        for (size_t n; (n = next++) < todo.size();) {
          const size_t i = todo[n];
          ++running_;
          try {
            results_[i] = run_row(rows_[i], keys_[i]);
          } catch (const std::exception& error) {
            results_[i] = RowResult{};
            results_[i].error = std::string("INTERNAL: ") + error.what();
          }
          --running_;
          release_study(rows_[i]);
          (results_[i].status == "done" ? finished_ok_ : failed_)++;
          if (results_[i].status != "done") say("row '" + rows_[i].id + "' failed: " + results_[i].error);
        }
      });
    }
    for (std::thread& t : workers) t.join();
    finished = true;
    progress.join();
    if (Status s = write_summary(); !s.ok()) return report(s);
    say("batch: " + std::to_string(finished_ok_) + " done, " + std::to_string(failed_) + " failed, " +
        std::to_string(rows_.size() - todo.size()) + " skipped in " +
        std::to_string(static_cast<int>(start.seconds())) + " s; summary in " + o_.summary + ".json and .csv");
    return failed_ == 0 ? 0 : 1;
  }

 private:
  Status open_pacs() {
    if (o_.pacs.url.empty()) {
      for (const Row& row : rows_) {
        if (!row.pacs_study.empty() || row.to_pacs) {
          return invalid_argument_error("row '" + row.id + "' uses the PACS: give --pacs URL (its DICOMweb root)");
        }
      }
      return ok_status();
    }
    POSEWARP_ASSIGN_OR_RETURN(const api::DicomWebOptions options, dicomweb_options(o_.pacs));
    pacs_ = std::make_unique<api::Pacs>(options);
    return ok_status();
  }

  std::string progress_line(size_t total, const Stopwatch& start) const {
    const size_t finished = finished_ok_ + failed_;
    std::string line = "batch: " + std::to_string(finished) + "/" + std::to_string(total) + " rows, " +
                       std::to_string(running_.load()) + " running, " + std::to_string(failed_.load()) + " failed";
    if (finished > 0 && finished < total) {
      const double eta = start.seconds() / static_cast<double>(finished) * static_cast<double>(total - finished);
      line += ", about " + std::to_string(static_cast<int>(eta)) + " s left";
    }
    return line;
  }

  // A study whose last row has finished is let go (its engine, volumes and rig), so a batch of many studies holds
  // only those still being posed.
  void release_study(const Row& row) {
    std::lock_guard<std::mutex> lock(studies_mutex_);
    if (--rows_left_[row.study_key()] == 0) studies_.erase(row.study_key());
  }

  // The study of a row, loaded once: its rig from the cache, or built (other rows of the study wait for it).
  Result<std::shared_ptr<Study>> study_of(const Row& row) {
    std::shared_future<Result<std::shared_ptr<Study>>> future;
    bool mine = false;
    std::promise<Result<std::shared_ptr<Study>>> promise;
    {
      std::lock_guard<std::mutex> lock(studies_mutex_);
      const auto found = studies_.find(row.study_key());
      if (found != studies_.end()) {
        future = found->second;
      } else {
        future = promise.get_future().share();
        studies_.emplace(row.study_key(), future);
        mine = true;
      }
    }
    if (mine) {
      try {
        promise.set_value(load_study(row));
      } catch (const std::exception& error) {  // out of memory, or a library's exception: the row fails, not the batch
        promise.set_value(internal_error(std::string("loading the study failed: ") + error.what()));
      }
    }
    return future.get();
  }

  Result<std::shared_ptr<Study>> load_study(const Row& row) {
    if (!o_.server.server.empty()) return load_remote_study(row);
    auto study = std::make_shared<Study>();
    const Stopwatch fetch_start;
    api::BuildInputs inputs;
    // A map of one's own replaces the preset.
    POSEWARP_ASSIGN_OR_RETURN(api::LabelMap map,
                              load_label_map(row.label_map, row.label_map.empty() ? row.preset : std::string(),
                                             "name a label_map file in the row"));
    if (!row.labels.empty()) {
      POSEWARP_ASSIGN_OR_RETURN(inputs.labels, api::read_label_volume(row.labels, read_options()));
      if (!row.ct.empty()) {
        POSEWARP_ASSIGN_OR_RETURN(inputs.ct, api::read_intensity_volume(row.ct, read_options()));
      }
      inputs.label_map = map;
    } else {
      POSEWARP_ASSIGN_OR_RETURN(api::DicomStudy dicom, read_dicom(row, map));
      inputs.labels = std::move(dicom.labels);
      inputs.ct = std::move(dicom.ct.ct);
      inputs.label_map = std::move(dicom.label_map);
      study->dicom = dicom.ct.info;
    }
    study->fetch_s = fetch_start.seconds();
    const Stopwatch rig_start;
    // The rig cache: one file per study (its inputs' key), kept between runs.
    const std::string cached = (fs::path(o_.rig_cache) / (study_content_key(row).substr(0, 32) + ".rig")).string();
    std::optional<api::Rig> rig;
    if (std::error_code ec; fs::exists(cached, ec)) {
      Result<api::Rig> loaded = api::load_rig(cached);
      if (loaded.ok()) rig = std::move(loaded).value(), study->rig_cached = true;
    }
    if (!rig) {
      say("row '" + row.id + "': building the rig of its study");
      POSEWARP_ASSIGN_OR_RETURN(api::Rig built, api::build_rig(inputs, {}, {}));
      std::error_code ec;
      fs::create_directories(o_.rig_cache, ec);
      if (Status s = api::save_rig(built, cached); !s.ok()) say("warning: the rig cache: " + s.to_string());
      rig = std::move(built);
    }
    POSEWARP_ASSIGN_OR_RETURN(api::PoseEngine engine, api::PoseEngine::create(std::move(*rig)));
    study->engine = std::make_unique<api::PoseEngine>(std::move(engine));
    study->label_map = study->engine->rig().label_map;
    study->rig_s = rig_start.seconds();
    return study;
  }

  // With --server: the study's volumes uploaded (files as they are; a DICOM study as NIfTI), its rig built there
  // (the server's store is the rig cache: the same inputs are built once, and a rerun finds the rig at once).
  Result<std::shared_ptr<Study>> load_remote_study(const Row& row) {
    auto study = std::make_shared<Study>();
    const Stopwatch fetch_start;
    RemoteRigInputs inputs;
    if (!row.labels.empty()) {
      const auto file = [](const std::string& path) -> Result<RemoteVolumeFile> {
        POSEWARP_ASSIGN_OR_RETURN(std::string bytes, api::read_text_input(path, "volume", int64_t{8} << 30));
        return RemoteVolumeFile{path, std::move(bytes)};
      };
      POSEWARP_ASSIGN_OR_RETURN(inputs.labels, file(row.labels));
      if (!row.ct.empty()) {
        POSEWARP_ASSIGN_OR_RETURN(inputs.ct, file(row.ct));
      }
      if (!row.label_map.empty()) {
        POSEWARP_ASSIGN_OR_RETURN(inputs.label_map_json, api::read_text_input(row.label_map, "label map"));
      } else {
        inputs.preset = row.preset;
      }
      inputs.name = fs::path(row.labels).filename().string();
    } else {
      POSEWARP_ASSIGN_OR_RETURN(api::LabelMap map,
                                load_label_map(row.label_map, row.label_map.empty() ? row.preset : std::string(),
                                               "name a label_map file in the row"));
      POSEWARP_ASSIGN_OR_RETURN(api::DicomStudy dicom, read_dicom(row, map));
      POSEWARP_ASSIGN_OR_RETURN(std::string labels, api::encode_volume(dicom.labels, api::VolumeFormat::kNifti, true));
      inputs.labels = RemoteVolumeFile{"labels.nii.gz", std::move(labels)};
      // HU as whole numbers in 16 bits where they are (the usual CT); a fractional rescale keeps floats.
      const float* hu = dicom.ct.ct.data();
      const bool whole = std::all_of(hu, hu + dicom.ct.ct.voxel_count(),
                                     [](float v) { return v == std::nearbyint(v) && v >= -32768.0f && v <= 32767.0f; });
      POSEWARP_ASSIGN_OR_RETURN(std::string ct, api::encode_volume(dicom.ct.ct, api::VolumeFormat::kNifti, true,
                                                                   whole ? PixelType::kInt16 : PixelType::kFloat32));
      inputs.ct = RemoteVolumeFile{"ct.nii.gz", std::move(ct)};
      inputs.label_map_json = api::label_map_to_json(dicom.label_map);
      inputs.name = "series " + dicom.ct.info.series_instance_uid;
      study->label_map = std::move(dicom.label_map);
      study->dicom = dicom.ct.info;
    }
    study->fetch_s = fetch_start.seconds();
    const Stopwatch rig_start;
    say("row '" + row.id + "': the rig of its study on " + o_.server.server);
    POSEWARP_ASSIGN_OR_RETURN(const std::string rig_id, build_rig_remote(o_.server, inputs));
    POSEWARP_ASSIGN_OR_RETURN(RemotePoser poser, RemotePoser::open(o_.server, rig_id));
    study->remote = std::move(poser);
    study->rig_id = rig_id;
    study->rig_s = rig_start.seconds();
    return study;
  }

  // A row's DICOM study: from a directory and a SEG file, or fetched from the PACS.
  Result<api::DicomStudy> read_dicom(const Row& row, const api::LabelMap& map) {
    api::DicomStudy dicom;
    if (!row.dicom_seg.empty()) {
      POSEWARP_ASSIGN_OR_RETURN(dicom, api::read_dicom_study(row.dicom_ct, row.dicom_seg, map));
    } else {
      POSEWARP_ASSIGN_OR_RETURN(dicom, fetch_from_pacs(row, map));
    }
    for (const std::string& w : dicom.warnings) say("row '" + row.id + "': " + w);
    return dicom;
  }

  // The CT series and SEG of a study in the PACS (the series named by the row, else its CT and its SEG).
  Result<api::DicomStudy> fetch_from_pacs(const Row& row, const api::LabelMap& map) {
    std::string ct_series = row.ct_series, seg_series = row.seg_series;
    if (ct_series.empty() || seg_series.empty()) {
      POSEWARP_ASSIGN_OR_RETURN(const std::vector<api::DicomWebRecord> series, pacs_->search_series(row.pacs_study));
      size_t most = 0;
      for (const api::DicomWebRecord& s : series) {
        const std::string modality = s.count("Modality") ? s.at("Modality") : "";
        const size_t count =
            s.count("NumberOfSeriesRelatedInstances") ? std::stoul("0" + s.at("NumberOfSeriesRelatedInstances")) : 0;
        const std::string description = s.count("SeriesDescription") ? s.at("SeriesDescription") : "";
        if (description.rfind("posewarp", 0) == 0) continue;  // our own derived series are not inputs
        if (row.ct_series.empty() && modality == "CT" && count >= most && s.count("SeriesInstanceUID")) {
          most = count, ct_series = s.at("SeriesInstanceUID");  // the largest CT series
        }
        if (row.seg_series.empty() && modality == "SEG" && seg_series.empty() && s.count("SeriesInstanceUID")) {
          seg_series = s.at("SeriesInstanceUID");
        }
      }
      if (ct_series.empty() || seg_series.empty()) {
        return not_found_error("study " + row.pacs_study + " in the PACS has no CT series or no SEG to pose");
      }
    }
    const fs::path scratch =
        fs::path(o_.rig_cache) / ("fetch-" + api::sha256_hex(row.id + row.pacs_study).substr(0, 16));
    std::error_code ec;
    fs::remove_all(scratch, ec);
    // The fetched files go whatever happens next.
    struct Cleanup {
      fs::path path;
      ~Cleanup() {
        std::error_code ignored;
        fs::remove_all(path, ignored);
      }
    } cleanup{scratch};
    POSEWARP_ASSIGN_OR_RETURN(const std::vector<std::string> ct_files,
                              pacs_->retrieve_series(row.pacs_study, ct_series, (scratch / "ct").string()));
    POSEWARP_ASSIGN_OR_RETURN(const std::vector<std::string> seg_files,
                              pacs_->retrieve_series(row.pacs_study, seg_series, (scratch / "seg").string()));
    if (seg_files.size() != 1)
      return invalid_argument_error("the SEG series " + seg_series + " holds " + std::to_string(seg_files.size()) +
                                    " instances, not one");
    std::vector<std::string> instances;
    for (const std::string& f : ct_files) {
      POSEWARP_ASSIGN_OR_RETURN(std::string bytes, api::read_text_input(f, "DICOM file", int64_t{1} << 31));
      instances.push_back(std::move(bytes));
    }
    POSEWARP_ASSIGN_OR_RETURN(const std::string seg,
                              api::read_text_input(seg_files.front(), "DICOM SEG", int64_t{1} << 32));
    return api::read_dicom_study(instances, seg, map);
  }

  // A posed frame as DICOM of the row's study: a derived CT series and its SEG. The same result has the same UIDs
  // (nothing stored twice): seeded by the source series' content (its series and instance UIDs), the pose and the
  // method.
  Result<api::DicomOutputs> encode_dicom(const Study& s, const Row& row, const api::PoseResult& posed,
                                         const std::string& pose_name, const std::string& frame) const {
    if (!posed.ct) return data_loss_error("the posed study has no CT to store");
    api::DerivedSeriesOptions options;
    options.uid_root = o_.uid_root;
    std::string source = s.dicom->series_instance_uid;
    for (const std::string& uid : s.dicom->sop_instance_uids) source += "\n" + uid;
    options.uid_seed = api::sha256_hex(source) + "/" + pose_hash(row) + "/" + row.method + "/" + frame;
    // Another format is another series (a PACS would otherwise mix the two under one UID).
    if (!o_.dicom_formats.defaults()) options.uid_seed += "/" + o_.dicom_formats.ct + "/" + o_.dicom_formats.seg;
    o_.dicom_formats.apply(&options);
    options.series_description =
        "posewarp: " + pose_name + (frame.empty() ? "" : " " + frame) + " (" + row.method + ")";
    options.derivation_description =
        "re-posed by posewarp (" + pose_name + ", " + row.method + ") from series " + s.dicom->series_instance_uid;
    return api::encode_dicom_outputs(*posed.ct, *posed.labels, s.label_map, *s.dicom, options);
  }

  // The series and its SEG stored side by side (the PACS ingests them in two of its workers); a row that fails here
  // is stored again whole by a rerun, under the same UIDs.
  Status store(const Study& s, const api::DicomOutputs& dicom) {
    std::future<Status> seg =
        std::async(std::launch::async, [&] { return pacs_->store({dicom.seg_file}, s.dicom->study_instance_uid); });
    Status stored = pacs_->store(dicom.ct_files, s.dicom->study_instance_uid);
    const Status seg_stored = seg.get();
    return stored.ok() ? seg_stored : stored;
  }

  RowResult run_row(const Row& row, const std::string& key) {
    RowResult result;
    Result<std::shared_ptr<Study>> study = study_of(row);
    if (!study.ok()) {
      result.error = study.status().to_string();
      return result;
    }
    Study& s = **study;
    // The first row of a study pays for fetching and the rig; the others find it ready.
    {
      std::lock_guard<std::mutex> lock(studies_mutex_);
      if (charged_.insert(row.study_key()).second) result.fetch_s = s.fetch_s, result.rig_s = s.rig_s;
    }
    std::vector<Pose> poses;
    std::optional<Matched> matched;
    if (!row.match.empty() || !row.standard.empty()) {
      Result<Matched> m = match(s, row);
      if (!m.ok()) return result.error = m.status().to_string(), result;
      poses.push_back(m->pose);
      matched = std::move(m).value();
    } else if (!row.pose.empty()) {
      Result<Pose> p = api::read_pose(row.pose);
      if (!p.ok()) return result.error = p.status().to_string(), result;
      poses.push_back(*p);
    } else {
      Result<api::Animation> a = api::read_animation(row.animation);
      if (!a.ok()) return result.error = a.status().to_string(), result;
      poses = a->frames;
    }
    const std::string pose_name = !row.standard.empty() ? row.standard
                                  : !row.match.empty()
                                      ? "match " + fs::path(row.match).stem().stem().string()
                                      : fs::path(row.pose.empty() ? row.animation : row.pose).stem().string();
    for (size_t f = 0; f < poses.size(); ++f) {
      const std::string frame = poses.size() == 1 ? "" : "frame_" + std::to_string(f);
      api::PoseRequest request;
      request.pose = poses[f];
      request.want_labels = request.want_ct = true;
      // A match's result lies on the target's grid, voxel for voxel comparable with it (a DICOM study's stays on
      // its own, where its derived series belong).
      if (matched && matched->grid && !s.dicom) {
        request.grid = api::GridPolicy::kGiven;
        request.given_grid = *matched->grid;
      }
      Result<api::Method> method = api::method_from_name(row.method);
      request.method = *method;
      const Stopwatch pose_start;
      Result<Posed> posed = pose(s, request);
      result.pose_s += pose_start.seconds();
      if (!posed.ok()) return result.error = posed.status().to_string(), result;
      result.figures = key_figures(posed->report_json);
      // Everything is made first; files land through a partial directory, the PACS gets each series whole.
      const Stopwatch encode_start;
      std::optional<api::DicomOutputs> dicom;
      if (s.dicom) {
        Result<api::DicomOutputs> encoded = encode_dicom(s, row, posed->result, pose_name, frame);
        if (!encoded.ok()) return result.error = encoded.status().to_string(), result;
        dicom = std::move(encoded).value();
      }
      if (!row.out_dir.empty()) {
        const fs::path out = frame.empty() ? fs::path(row.out_dir) : fs::path(row.out_dir) / frame;
        if (Status w = write_directory(out, *posed, dicom, matched ? &*matched : nullptr); !w.ok()) {
          return result.error = w.to_string(), result;
        }
        result.outputs.push_back(out.string());
      }
      result.encode_s += encode_start.seconds();
      if (row.to_pacs && dicom) {
        const Stopwatch store_start;
        if (Status stored = store(s, *dicom); !stored.ok()) return result.error = stored.to_string(), result;
        result.store_s += store_start.seconds();
        result.outputs.push_back("pacs:" + dicom->ct.series_instance_uid);
        result.outputs.push_back("pacs:" + dicom->seg.series_instance_uid);
      }
    }
    result.status = "done";
    record(row, key, result);
    return result;
  }

  // A match row's pose: found against the target (its report and the target's grid with it) or a standard posture.
  struct Matched {
    Pose pose;
    std::string report_json;  // posewarp.match; empty for a standard posture
    std::optional<ImageGeometry> grid;
  };

  Result<Matched> match(Study& s, const Row& row) {
    Matched m;
    if (s.remote) {
      RemoteMatchRequest request;
      request.rig_id = s.rig_id;
      request.standard = row.standard;
      if (!row.match.empty()) {
        POSEWARP_ASSIGN_OR_RETURN(std::string bytes, api::read_text_input(row.match, "volume", int64_t{8} << 30));
        request.target = RemoteVolumeFile{row.match, std::move(bytes)};  // named as the rig's labels are
      }
      POSEWARP_ASSIGN_OR_RETURN(RemoteMatch answer, match_remote(o_.server, request));
      m.pose = std::move(answer.match.match.pose);
      m.report_json = std::move(answer.report_json);
      if (!row.match.empty()) m.grid = answer.target_grid;
      return m;
    }
    const api::Rig& rig = s.engine->rig();
    if (!row.standard.empty()) {
      POSEWARP_ASSIGN_OR_RETURN(m.pose, api::standard_posture(rig, row.standard));
      return m;
    }
    POSEWARP_ASSIGN_OR_RETURN(const LabelVolume target, api::read_label_volume(row.match, read_options()));
    POSEWARP_ASSIGN_OR_RETURN(const api::PostureMatch found, api::match_posture(rig, target, rig.label_map));
    m.pose = found.match.pose;
    m.report_json = api::posture_match_to_json(found);
    m.grid = target.geometry();
    return m;
  }

  // A pose's volumes and its report as report.json holds it, from this process's engine or from the server.
  struct Posed {
    api::PoseResult result;
    std::string report_json;
  };

  static Result<Posed> pose(Study& s, const api::PoseRequest& request) {
    Posed posed;
    if (s.remote) {
      POSEWARP_ASSIGN_OR_RETURN(RemotePoseResult answer, s.remote->pose(request));
      if (!answer.result.labels) return data_loss_error("the server's answer holds no labels; run the batch again");
      posed.result = std::move(answer.result);
      posed.report_json = std::move(answer.report_json);
      return posed;
    }
    {
      std::lock_guard<std::mutex> lock(s.posing);
      POSEWARP_ASSIGN_OR_RETURN(posed.result, s.engine->pose(request));
    }
    posed.report_json = api::report_to_json(posed.result.report);
    return posed;
  }

  // The summary's figures of a quality report (report.json's fields).
  static json key_figures(const std::string& report_json) {
    const json r = json::parse(report_json, nullptr, false);
    if (!r.is_object()) return json::object();
    const auto at = [&r](const char* section, const char* key) {
      return r.contains(section) && r[section].is_object() && r[section].contains(key) ? r[section][key] : json();
    };
    return {{"inverted_tets", at("tets", "inverted")},
            {"bone_rigidity_error_mm", at("bone_rigidity", "max_error_mm")},
            {"volume_change", at("volume_change", "body")},
            {"new_labels", r.value("new_labels", json::array())},
            {"lost_labels", r.value("vanished_labels", json::array())},
            {"warnings", r.contains("warnings") && r["warnings"].is_array() ? r["warnings"].size() : 0}};
  }

  // A partial directory filled, then put in place as OUT (AtomicDirectory): a row killed midway leaves no OUT that
  // looks finished.
  static Status write_directory(const fs::path& out, const Posed& posed, const std::optional<api::DicomOutputs>& dicom,
                                const Matched* matched) {
    // An earlier result of this row (a rerun) is replaced; a directory holding anything else is not touched.
    std::error_code ec;
    fs::create_directories(out.parent_path(), ec);
    if (ec) return invalid_argument_error("cannot make '" + out.parent_path().string() + "': " + ec.message());
    if (fs::exists(out, ec) && !fs::is_empty(out, ec) && !fs::exists(out / "report.json", ec)) {
      return already_exists_error("'" + out.string() +
                                  "' holds files that are not a posewarp result; choose another out_dir");
    }
    POSEWARP_ASSIGN_OR_RETURN(AtomicDirectory directory,
                              AtomicDirectory::create(out.string(), "row's outputs", AtomicDirectory::Existing::kReplace));
    const fs::path partial(directory.partial_path());
    POSEWARP_RETURN_IF_ERROR(api::write_volume(*posed.result.labels, (partial / "labels.nii.gz").string()));
    if (posed.result.ct) {  // a study given as labels alone has none
      POSEWARP_RETURN_IF_ERROR(api::write_volume(*posed.result.ct, (partial / "ct.nii.gz").string()));
    }
    POSEWARP_RETURN_IF_ERROR(
        api::write_file_atomically((partial / "report.json").string(), posed.report_json, "report"));
    if (dicom) {
      POSEWARP_RETURN_IF_ERROR(api::write_dicom_outputs(*dicom, (partial / "dicom").string()));
    }
    if (matched) {  // the pose found (a pose file like any other), and how it fits the target
      POSEWARP_RETURN_IF_ERROR(
          api::write_file_atomically((partial / "pose.json").string(), api::pose_to_json(matched->pose), "pose"));
      if (!matched->report_json.empty()) {
        POSEWARP_RETURN_IF_ERROR(
            api::write_file_atomically((partial / "match.json").string(), matched->report_json, "match report"));
      }
    }
    return directory.commit();
  }

  // A finished row, appended to the state file and flushed to disk before the next row counts it done.
  void record(const Row& row, const std::string& key, const RowResult& result) {
    const json entry{{"key", key}, {"id", row.id}, {"status", "done"}, {"outputs", result.outputs}};
    std::lock_guard<std::mutex> lock(state_mutex_);
    // A line cut short by a kill is ended first, so this entry stands on its own line.
    bool ends_cleanly = true;
    {
      std::ifstream in(o_.state, std::ios::binary | std::ios::ate);
      if (in && in.tellg() > 0) {
        in.seekg(-1, std::ios::end);
        ends_cleanly = in.get() == '\n';
      }
    }
    std::ofstream out(o_.state, std::ios::app);
    if (!ends_cleanly) out << "\n";
    out << entry.dump() << "\n";
    out.flush();
    if (!out)
      say("warning: cannot append to the state file '" + o_.state + "'; a rerun will redo row '" + row.id + "'");
  }

  Status write_summary() const {
    json rows = json::array();
    std::string csv =
        "id,status,error,outputs,inverted_tets,bone_rigidity_error_mm,volume_change,warnings,fetch_s,rig_s,pose_s,"
        "encode_s,store_s\n";
    for (size_t i = 0; i < rows_.size(); ++i) {
      const RowResult& r = results_[i];
      rows.push_back({{"id", rows_[i].id},
                      {"status", r.status},
                      {"error", r.error},
                      {"outputs", r.outputs},
                      {"report", r.figures},
                      {"seconds",
                       {{"fetch", r.fetch_s},
                        {"rig", r.rig_s},
                        {"pose", r.pose_s},
                        {"encode", r.encode_s},
                        {"store", r.store_s}}}});
      std::string outputs;
      for (const std::string& out : r.outputs) outputs += (outputs.empty() ? "" : ";") + out;
      const auto figure = [&](const char* name) {
        return r.figures.contains(name) ? r.figures[name].dump() : std::string();
      };
      char times[160];
      std::snprintf(times, sizeof times, "%.3f,%.3f,%.3f,%.3f,%.3f", r.fetch_s, r.rig_s, r.pose_s, r.encode_s,
                    r.store_s);
      csv += csv_field(rows_[i].id) + "," + r.status + "," + csv_field(r.error) + "," + csv_field(outputs) + "," +
             figure("inverted_tets") + "," + figure("bone_rigidity_error_mm") + "," + figure("volume_change") + "," +
             figure("warnings") + "," + times + "\n";
    }
    const json doc{{"format", "posewarp.batch_summary"}, {"version", 1}, {"rows", rows}};
    POSEWARP_RETURN_IF_ERROR(api::write_file_atomically(o_.summary + ".json", doc.dump(2) + "\n", "batch summary"));
    return api::write_file_atomically(o_.summary + ".csv", csv, "batch summary");
  }

  BatchOptions o_;
  std::vector<Row> rows_;
  std::vector<std::string> keys_;
  std::vector<RowResult> results_;
  std::unique_ptr<api::Pacs> pacs_;
  std::mutex studies_mutex_, state_mutex_;
  std::map<std::string, std::shared_future<Result<std::shared_ptr<Study>>>> studies_;
  std::set<std::string> charged_;
  std::map<std::string, int> rows_left_;  // rows of each study still to run
  std::atomic<int> running_{0}, finished_ok_{0}, failed_{0};
};

// Rows from a QIDO-RS query: one per study found, posed with the given pose.
Result<std::vector<Row>> rows_from_query(const BatchOptions& o) {
  if (o.pacs.url.empty()) return invalid_argument_error("--query searches a PACS: give --pacs URL");
  if (o.pose.empty() == o.animation.empty()) return invalid_argument_error("--query needs --pose or --animation");
  if (o.out_dir.empty() && !o.to_pacs) return invalid_argument_error("--query needs --out-dir DIR, --to-pacs or both");
  POSEWARP_ASSIGN_OR_RETURN(const api::DicomWebOptions options, dicomweb_options(o.pacs));
  POSEWARP_ASSIGN_OR_RETURN(const std::vector<api::DicomWebRecord> studies,
                            api::Pacs(options).search_studies(o.query));
  std::vector<Row> rows;
  for (const api::DicomWebRecord& study : studies) {
    Row row;
    row.pacs_study = study.count("StudyInstanceUID") ? study.at("StudyInstanceUID") : "";
    if (row.pacs_study.empty()) continue;
    row.id = "study-" + row.pacs_study;
    row.pose = o.pose;
    row.animation = o.animation;
    row.method = o.method;
    row.to_pacs = o.to_pacs;
    if (!o.out_dir.empty()) row.out_dir = (fs::path(o.out_dir) / row.pacs_study).string();
    POSEWARP_RETURN_IF_ERROR(check_row(row, "--query row for study " + row.pacs_study));
    rows.push_back(row);
  }
  if (rows.empty()) return not_found_error("the query '" + o.query + "' found no studies in the PACS");
  return rows;
}

}  // namespace

void add_batch_command(CLI::App& app) {
  auto o = std::make_shared<BatchOptions>();
  CLI::App* cmd = app.add_subcommand(
      "batch",
      "Pose many studies: the rows of a manifest (JSON or CSV: id, labels, ct, label_map, preset | dicom_ct, dicom_seg "
      "| "
      "pacs_study, ct_series, seg_series; pose | animation | match (another scan's labels: the pose that matches "
      "them, posed on their grid) | standard (a standard posture); method; out_dir; to_pacs), or one row per study a "
      "PACS "
      "query "
      "finds. Rows run in parallel (--jobs); each study's rig is built once and cached; a state file makes a rerun "
      "skip finished rows; a summary (JSON and CSV) gives each row's status, outputs and quality figures. With "
      "--server "
      "the rigs are built and the poses run on posewarp-server. Exit 0 when "
      "every row succeeded, 1 otherwise");
  cmd->add_option("manifest", o->manifest, "Manifest file (.json or .csv); paths in it are relative to it");
  cmd->add_option("--jobs", o->jobs, "Rows at once")->check(CLI::Range(1, 64))->capture_default_str();
  cmd->add_option("--state", o->state, "State file of finished rows (default: MANIFEST.state.jsonl)");
  cmd->add_option("--summary", o->summary, "Summary files PREFIX.json and PREFIX.csv (default: MANIFEST.summary)");
  cmd->add_option("--rig-cache", o->rig_cache, "Directory of built rigs, one per study (default: MANIFEST.rigs)");
  add_pacs_options(cmd, o->pacs);
  cmd->add_option("--server", o->server.server,
                  "Pose through posewarp-server at HOST:PORT: each study's volumes are uploaded once and its rig built "
                  "there (the server keeps it; a rerun finds it), the rows' poses answered by the server");
  add_connection_options(cmd, o->server);
  cmd->add_option("--uid-root", o->uid_root, "Root of the derived series' UIDs")->capture_default_str();
  add_dicom_format_options(cmd, o->dicom_formats);
  cmd->add_option("--query", o->query,
                  "QIDO-RS study query (e.g. 'Modality=CT&StudyDate=20250101-'): one row per study");
  cmd->add_option("--pose", o->pose, "With --query: the pose for every study");
  cmd->add_option("--animation", o->animation, "With --query: an animation instead");
  cmd->add_option("--method", o->method, "With --query: cor, dqs, lbs or fem")->capture_default_str();
  cmd->add_option("--out-dir", o->out_dir, "With --query: a directory per study under this one");
  cmd->add_flag("--to-pacs", o->to_pacs, "With --query: store the derived CT series and SEG back into each study");
  cmd->callback([o] {
    BatchOptions options = *o;
    Result<std::vector<Row>> rows = invalid_argument_error("give a MANIFEST, or --pacs URL --query Q --pose POSE.json");
    std::string base = fs::path(options.manifest).replace_extension("").string();
    if (!options.query.empty()) {
      rows = rows_from_query(options);
      if (base.empty()) base = (fs::path(options.out_dir.empty() ? "." : options.out_dir) / "query").string();
    } else if (!options.manifest.empty()) {
      rows = read_manifest(options.manifest);
    }
    if (!rows.ok()) throw CLI::RuntimeError(report(rows.status()));
    if (options.state.empty()) options.state = base + ".state.jsonl";
    if (options.summary.empty()) options.summary = base + ".summary";
    if (options.rig_cache.empty()) options.rig_cache = base + ".rigs";
    const int code = Batch(options, std::move(rows).value()).run();
    if (code != 0) throw CLI::RuntimeError(code);
  });
}

}  // namespace posewarp::cli
