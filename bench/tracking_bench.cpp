// Marker tracking speed (capture/tracking.h) on rendered 1024 x 1024 8-bit
// footage: six markers (an impactor's two falling onto the mat, four on the
// mat), one core. Rendering is done before timing; reading PNG frames from
// disk is timed on its own. Run:
//   build/bench/tracking_bench --benchmark_counters_tabular=true
#include <benchmark/benchmark.h>
#include <unistd.h>

#include <filesystem>
#include <string>
#include <vector>

#include "capture/footage.h"
#include "samples/generator/render.h"

namespace {

using dropfit::capture::Image8;
using dropfit::synth::FootageOptions;
using dropfit::synth::MarkerFootage;

constexpr int kFrames = 200;
const std::vector<std::string> kPoints = {"imp_base_front", "imp_base_back", "mat_n", "mat_s", "mat_e", "mat_w"};

// The impactor falls at about 3 px/frame, lands at frame 100 and stops over
// 60 frames; the mat markers sink with it.
MarkerFootage footage() {
  MarkerFootage f;
  f.centres_px.resize(kFrames, 12);
  f.radius_px = {5.0, 5.0, 4.0, 4.0, 4.0, 4.0};
  for (int k = 0; k < kFrames; ++k) {
    const double t = k - 100.0;
    const double d = t <= 0 ? 2.8 * t + 0.003 * t * t : t < 60 ? 2.8 * (t - t * t / 120.0) : 84.0;
    const double sink = t > 0 ? d : 0.0;
    f.centres_px.row(k) << 431.3, 620.0 + d, 598.7, 620.4 + d, 300.2, 632.6 + 0.15 * sink, 730.6,
        632.2 + 0.15 * sink, 442.3, 634.1 + 0.9 * sink, 587.2, 633.8 + 0.9 * sink;
  }
  return f;
}

FootageOptions render_options() {
  FootageOptions o;
  o.exposure_frames = 0.5;
  o.noise_grey = 2.5;
  return o;
}

const std::vector<Image8>& frames() {
  static const std::vector<Image8> images = [] {
    const MarkerFootage f = footage();
    const dropfit::synth::FootageRenderer renderer(render_options());
    std::vector<Image8> out(kFrames);
    for (int k = 0; k < kFrames; ++k) renderer.render(f, k, out[k]);
    return out;
  }();
  return images;
}

std::vector<dropfit::capture::Seed> seeds() {
  const MarkerFootage f = footage();
  std::vector<dropfit::capture::Seed> s;
  for (int p = 0; p < 6; ++p)
    s.push_back({kPoints[p], 0, f.centres_px.row(0).segment<2>(2 * p).transpose() + Eigen::Vector2d(1.0, -1.0), "", 0});
  return s;
}

// Frames per second of tracking (whole trial per iteration, seeding included).
void BM_Track6Markers1024(benchmark::State& state) {
  const auto& images = frames();
  const auto s = seeds();
  int gaps = 0;
  for (auto _ : state) {
    dropfit::capture::MarkerTracker tracker("cam1", kPoints, s);
    for (const auto& img : images) tracker.add_frame(img.view());
    const auto result = tracker.result();
    gaps = static_cast<int>(result.gaps().size());
    benchmark::DoNotOptimize(result.tracks.uv_px.data());
  }
  state.SetItemsProcessed(state.iterations() * kFrames);
  state.counters["fps"] = benchmark::Counter(static_cast<double>(state.iterations()) * kFrames,
                                             benchmark::Counter::kIsRate);
  state.counters["gaps"] = gaps;
}
BENCHMARK(BM_Track6Markers1024)->Unit(benchmark::kMillisecond);

// Detecting every marker in a whole frame (what a seed-less search would
// cost per frame; the tracker does this only around each seed).
void BM_DetectBlobsFullFrame1024(benchmark::State& state) {
  const auto& img = frames()[0];
  std::size_t n = 0;
  for (auto _ : state) {
    const auto blobs = dropfit::capture::detect_blobs(img.view());
    n = blobs.size();
    benchmark::DoNotOptimize(blobs.data());
  }
  state.counters["fps"] = benchmark::Counter(static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
  state.counters["blobs"] = static_cast<double>(n);
}
BENCHMARK(BM_DetectBlobsFullFrame1024)->Unit(benchmark::kMillisecond);

// Reading PNG frames (decoding included; files written once, page cache warm).
void BM_ReadPngFrame1024(benchmark::State& state) {
  namespace fs = std::filesystem;
  const fs::path dir = fs::temp_directory_path() / ("dropfit_tracking_bench_" + std::to_string(::getpid()));
  MarkerFootage f = footage();
  f.centres_px.conservativeResize(20, Eigen::NoChange);
  FootageOptions o = render_options();
  const auto files = dropfit::synth::write_footage_png(dir.string(), f, o);
  std::size_t k = 0;
  for (auto _ : state) {
    const Image8 img = dropfit::capture::read_image8(files[k++ % files.size()]);
    benchmark::DoNotOptimize(img.pixels.data());
  }
  state.counters["fps"] = benchmark::Counter(static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
  fs::remove_all(dir);
}
BENCHMARK(BM_ReadPngFrame1024)->Unit(benchmark::kMillisecond);

// Rendering one synthetic frame (the test footage's cost, for reference).
void BM_RenderFrame1024(benchmark::State& state) {
  const MarkerFootage f = footage();
  const dropfit::synth::FootageRenderer renderer(render_options());
  Image8 img;
  int k = 0;
  for (auto _ : state) {
    renderer.render(f, k++ % kFrames, img);
    benchmark::DoNotOptimize(img.pixels.data());
  }
  state.counters["fps"] = benchmark::Counter(static_cast<double>(state.iterations()), benchmark::Counter::kIsRate);
}
BENCHMARK(BM_RenderFrame1024)->Unit(benchmark::kMillisecond);

}  // namespace
