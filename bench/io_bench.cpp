// Volume I/O, body mask and phantom generation throughput (voxels per second).
#include <benchmark/benchmark.h>

#include <filesystem>

#include "posewarp/common/parallel.h"
#include "posewarp/io/volume_io.h"
#include "posewarp/labels/body.h"
#include "posewarp/labels/presets.h"
#include "posewarp/phantom/phantom.h"

namespace {

using namespace posewarp;
const std::string kSample = POSEWARP_SAMPLE_DIR;

void BM_ReadSampleLabels(benchmark::State& state) {
  for (auto _ : state) {
    Result<LabelVolume> seg = io::read_label_volume(kSample + "/seg_total.nii.gz");
    benchmark::DoNotOptimize(seg.ok());
    state.counters["voxels"] = static_cast<double>(seg->voxel_count());
  }
  state.SetItemsProcessed(state.iterations() * 1380064);
}
BENCHMARK(BM_ReadSampleLabels)->Unit(benchmark::kMillisecond);

void BM_ReadSampleCt(benchmark::State& state) {
  for (auto _ : state) {
    Result<IntensityVolume> ct = io::read_intensity_volume(kSample + "/ct.nii.gz");
    benchmark::DoNotOptimize(ct.ok());
  }
  state.SetItemsProcessed(state.iterations() * 1380064);
}
BENCHMARK(BM_ReadSampleCt)->Unit(benchmark::kMillisecond);

void BM_SampleBodyMask(benchmark::State& state) {
  Result<LabelVolume> seg = io::read_label_volume(kSample + "/seg_total.nii.gz");
  Result<IntensityVolume> ct = io::read_intensity_volume(kSample + "/ct.nii.gz");
  const labels::LabelMap map = labels::totalsegmentator_v2_preset();
  for (auto _ : state) {
    Result<LabelVolume> body = labels::body_mask(map, *seg, &*ct);
    benchmark::DoNotOptimize(body.ok());
  }
  state.SetItemsProcessed(state.iterations() * seg->voxel_count());
}
BENCHMARK(BM_SampleBodyMask)->Unit(benchmark::kMillisecond);

// Mannequin of about N million voxels: generation, then a .nii.gz write and read of its labels.
void BM_MannequinGenerate(benchmark::State& state) {
  phantom::MannequinParams params;
  params.spacing_mm = phantom::mannequin_spacing_for_voxels(params, state.range(0) * 1'000'000);
  int64_t voxels = 0;
  for (auto _ : state) {
    Result<phantom::Phantom> m = phantom::make_mannequin(params);
    voxels = m->labels.voxel_count();
  }
  state.counters["voxels"] = static_cast<double>(voxels);
  state.SetItemsProcessed(state.iterations() * voxels);
}
BENCHMARK(BM_MannequinGenerate)->Arg(1)->Arg(5)->Arg(20)->Unit(benchmark::kMillisecond);

void BM_MannequinLabelsNiftiRoundTrip(benchmark::State& state) {
  phantom::MannequinParams params;
  params.spacing_mm = phantom::mannequin_spacing_for_voxels(params, state.range(0) * 1'000'000);
  Result<phantom::Phantom> m = phantom::make_mannequin(params);
  const std::string path = (std::filesystem::temp_directory_path() / "posewarp_bench_labels.nii.gz").string();
  for (auto _ : state) {
    benchmark::DoNotOptimize(io::write_volume(m->labels, path).ok());
    benchmark::DoNotOptimize(io::read_label_volume(path).ok());
  }
  std::filesystem::remove(path);
  state.counters["voxels"] = static_cast<double>(m->labels.voxel_count());
  state.SetItemsProcessed(state.iterations() * m->labels.voxel_count());
}
BENCHMARK(BM_MannequinLabelsNiftiRoundTrip)->Arg(1)->Arg(20)->Unit(benchmark::kMillisecond);

// What `posewarp pose` writes at the end: the 20M-voxel mannequin's labels (uint8 on disk) or CT (int16) as .nii or
// .nii.gz, from the engine's int32 and float32 voxels (args: 0 labels / 1 CT, 0 .nii / 1 .nii.gz).
void BM_MannequinWrite(benchmark::State& state) {
  phantom::MannequinParams params;
  params.spacing_mm = phantom::mannequin_spacing_for_voxels(params, 20'000'000);
  Result<phantom::Phantom> m = phantom::make_mannequin(params);
  const bool ct = state.range(0) == 1, gzip = state.range(1) == 1;
  const std::string path =
      (std::filesystem::temp_directory_path() / (std::string("posewarp_bench_write.nii") + (gzip ? ".gz" : "")))
          .string();
  for (auto _ : state) {
    const Status written = ct ? io::write_volume(m->ct, path) : io::write_volume(m->labels, path);
    if (!written.ok()) state.SkipWithError(written.message().c_str());
  }
  std::filesystem::remove(path);
  state.SetLabel(std::string(ct ? "CT" : "labels") + (gzip ? " .nii.gz" : " .nii"));
  state.SetItemsProcessed(state.iterations() * m->labels.voxel_count());
}
BENCHMARK(BM_MannequinWrite)->ArgsProduct({{0, 1}, {0, 1}})->Unit(benchmark::kMillisecond);

}  // namespace

int main(int argc, char** argv) {
  posewarp::set_thread_count(0);
  benchmark::Initialize(&argc, argv);
  benchmark::RunSpecifiedBenchmarks();
  benchmark::Shutdown();
  return 0;
}
