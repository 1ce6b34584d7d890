// PACS-side batch repositioning measured end to end: a real Orthanc (DICOMweb, authentication on) holding copies of
// the sample as separate studies, and `posewarp batch` posing each study twice and storing the derived CT and SEG
// back. Per row, from the batch's summary: fetch (WADO-RS of the CT and SEG, read), rig (built once per study: the
// first row of a study pays), pose, encode (derived CT and SEG) and store (STOW-RS). Each DICOM format in turn (the
// studies in the PACS and what the batch writes alike), each in an Orthanc of its own: a CT series and a binary SEG,
// and one Enhanced CT and a label map SEG (Supplement 243).
// Target (issue 24): fetch + encode + store at most 5x the pose on the sample.
// Usage: posewarp_bench_pacs [--studies N (5)] [--jobs J (1)] [--formats CT/SEG,... (series/binary,enhanced/labelmap)]
#include <nlohmann/json.hpp>

#include <algorithm>
#include <cstring>
#include <iostream>
#include <sstream>

#include "orthanc_process.h"
#include "posewarp/api/dicom.h"
#include "posewarp/api/files.h"

namespace {

using namespace posewarp;
namespace fs = std::filesystem;

std::string file_text(const fs::path& path) {
  std::ifstream in(path, std::ios::binary);
  return {std::istreambuf_iterator<char>(in), std::istreambuf_iterator<char>()};
}

}  // namespace

struct Formats {
  std::string ct, seg;
};

// One format: the sample stored `studies` times in a fresh Orthanc, the batch run over it; the per-row table and the
// ratio of fetch + encode + store to the pose.
void run_format(const Formats& formats, int studies, int jobs, const fs::path& work) {
  std::fflush(stdout);  // Orthanc's process starts from this one: it must not inherit what is buffered here
  fs::create_directories(work);
  testing_support::OrthancProcess orthanc(work / "orthanc");
  if (!orthanc.ready()) throw std::runtime_error("Orthanc did not start:\n" + orthanc.log());
  pacs::DicomWebClient client(orthanc.options());
  // The sample as N studies (new UIDs each), stored in the PACS in this format.
  const std::string sample = POSEWARP_SAMPLE_DIR;
  const IntensityVolume ct = *api::read_intensity_volume(sample + "/ct.nii.gz");
  const LabelVolume labels = *api::read_label_volume(sample + "/seg_total.nii.gz");
  const api::LabelMap map = *api::preset_by_name("totalsegmentator");
  api::DerivedSeriesOptions options;
  options.ct_format = formats.ct == "enhanced" ? api::CtFormat::kEnhanced : api::CtFormat::kSeries;
  options.seg_format = formats.seg == "labelmap" ? api::SegFormat::kLabelMap : api::SegFormat::kBinary;
  std::string csv = "id,pacs_study,pose,method,to_pacs\n";
  const std::string poses = std::string(POSEWARP_SOURCE_DIR) + "/data/poses";
  size_t ct_bytes = 0, seg_bytes = 0, ct_files = 0;
  for (int s = 0; s < studies; ++s) {
    Result<api::DicomOutputs> study = api::encode_new_dicom_study(ct, labels, map, "Bench^Patient" + std::to_string(s),
                                                                  "BENCH-" + std::to_string(s), options);
    if (!study.ok()) throw std::runtime_error(study.status().to_string());
    for (const std::string& f : study->ct_files) ct_bytes += f.size();
    seg_bytes += study->seg_file.size();
    ct_files = study->ct_files.size();
    if (Status st = client.store(study->ct_files); !st.ok()) throw std::runtime_error(st.to_string());
    if (Status st = client.store({study->seg_file}); !st.ok()) throw std::runtime_error(st.to_string());
    const std::string uid = study->ct.study_instance_uid;
    // Stored back into the PACS only (no local files): the PACS path alone.
    csv += "s" + std::to_string(s) + "-hip," + uid + "," + poses + "/sample_hip_flexion.json,cor,true\n";
    csv += "s" + std::to_string(s) + "-rest," + uid + "," + poses + "/identity.json,cor,true\n";
  }
  std::ofstream(work / "rows.csv") << csv;
  std::ofstream(work / "password") << "s3cret\n";
  const std::string command = std::string("'") + POSEWARP_CLI + "' -q batch '" + (work / "rows.csv").string() +
                              "' --jobs " + std::to_string(jobs) + " --ct-format " + formats.ct + " --seg-format " +
                              formats.seg + " --pacs '" + orthanc.options().base_url +
                              "' --pacs-user posewarp --pacs-password-file '" + (work / "password").string() + "' > '" +
                              (work / "batch.log").string() + "' 2>&1";
  std::fflush(stdout);  // the batch's process must not inherit what is buffered here
  const auto start = std::chrono::steady_clock::now();
  const int code = std::system(command.c_str());
  const double wall = std::chrono::duration<double>(std::chrono::steady_clock::now() - start).count();
  if (code != 0) throw std::runtime_error("the batch failed:\n" + file_text(work / "batch.log"));
  const nlohmann::json summary = nlohmann::json::parse(file_text(work / "rows.summary.json"));
  std::printf(
      "\n== CT %s, SEG %s: %d studies of the sample in Orthanc (CT %.1f MB in %zu files, SEG %.1f MB), %zu rows, "
      "--jobs %d: %.1f s wall\n",
      formats.ct.c_str(), formats.seg.c_str(), studies, static_cast<double>(ct_bytes) / studies / 1e6, ct_files,
      static_cast<double>(seg_bytes) / studies / 1e6, summary["rows"].size(), jobs, wall);
  std::printf("%-10s %8s %8s %8s %8s %8s   (seconds)\n", "row", "fetch", "rig", "pose", "encode", "store");
  double overhead_sum = 0, pose_sum = 0, rows = 0;
  for (const nlohmann::json& row : summary["rows"]) {
    const nlohmann::json& t = row["seconds"];
    std::printf("%-10s %8.3f %8.3f %8.3f %8.3f %8.3f\n", row["id"].get<std::string>().c_str(), t["fetch"].get<double>(),
                t["rig"].get<double>(), t["pose"].get<double>(), t["encode"].get<double>(), t["store"].get<double>());
    // A study's fetch is charged to its first row: the sums compare (per row on average).
    overhead_sum += t["fetch"].get<double>() + t["encode"].get<double>() + t["store"].get<double>();
    pose_sum += t["pose"].get<double>();
    ++rows;
  }
  std::printf("per row on average: fetch + encode + store %.3f s, pose %.3f s (ratio %.1f; target <= 5)\n",
              overhead_sum / rows, pose_sum / rows, overhead_sum / pose_sum);
}

int main(int argc, char** argv) {
  int studies = 5, jobs = 1;
  std::vector<Formats> formats{{"series", "binary"}, {"enhanced", "labelmap"}};
  for (int i = 1; i < argc; ++i) {
    if (!std::strcmp(argv[i], "--studies") && i + 1 < argc) {
      studies = std::max(1, std::atoi(argv[++i]));
    } else if (!std::strcmp(argv[i], "--jobs") && i + 1 < argc) {
      jobs = std::max(1, std::atoi(argv[++i]));
    } else if (!std::strcmp(argv[i], "--formats") && i + 1 < argc) {
      formats.clear();
      std::stringstream list(argv[++i]);
      for (std::string item; std::getline(list, item, ',');) {
        const size_t slash = item.find('/');
        formats.push_back({item.substr(0, slash), slash == std::string::npos ? "binary" : item.substr(slash + 1)});
        const Formats& f = formats.back();
        if ((f.ct != "series" && f.ct != "enhanced") || (f.seg != "binary" && f.seg != "labelmap")) {
          std::fprintf(stderr,
                       "posewarp_bench_pacs: --formats takes CT/SEG pairs: series|enhanced / binary|labelmap\n");
          return 2;
        }
      }
    } else {
      std::fprintf(stderr,
                   "usage: %s [--studies N (5)] [--jobs J (1)] [--formats CT/SEG,... "
                   "(series/binary,enhanced/labelmap)]\n",
                   argv[0]);
      return 2;
    }
  }
  if (!fs::exists(testing_support::kOrthancDicomWebPlugin)) {
    std::fprintf(stderr,
                 "posewarp_bench_pacs: Orthanc's DICOMweb plugin is not installed (scripts/setup installs it)\n");
    return 1;
  }
  const fs::path work = fs::temp_directory_path() / ("posewarp-bench-pacs-" + std::to_string(::getpid()));
  fs::remove_all(work);
  try {
    for (const Formats& f : formats) run_format(f, studies, jobs, work / (f.ct + "-" + f.seg));
  } catch (const std::exception& error) {
    std::fprintf(stderr, "posewarp_bench_pacs: %s\n", error.what());
    fs::remove_all(work);
    return 1;
  }
  fs::remove_all(work);
  return 0;
}
