// Reading and writing a session of realistic size: 2 cameras, 6 points,
// 40 calibration markers, 3 trials of 1500 video frames and 5000 force
// samples (eight-channel); and committing the output set of a five-trial
// `dropfit run` (report/output.h). Run: build/bench/capio_bench
#include <benchmark/benchmark.h>
#include <fmt/format.h>
#include <unistd.h>

#include <cmath>
#include <filesystem>

#include "capture/io.h"
#include "report/output.h"

namespace {

namespace fs = std::filesystem;
using namespace dropfit;

Session make_session() {
  Session s;
  Manifest& m = s.manifest;
  m.impactor.base_markers = {"imp_base_front", "imp_base_back"};
  m.mat.surface_markers = {"mat_n", "mat_s", "mat_e", "mat_w"};
  m.mat.layers = {{"carpet", 0.005, 0.0}, {"stiff", 0.05, 2.44}, {"soft", 0.15, 3.66}};
  m.video.cameras = {"cam1", "cam2"};
  m.video.points = {"imp_base_front", "imp_base_back", "mat_n", "mat_s", "mat_e", "mat_w"};
  m.video.trigger_frame = 500;
  for (int i = 0; i < 40; ++i) {
    s.frame.push_back({fmt::format("c{}", i), {0.01 * i, -0.02 * i, 0.3 * (i % 2)}, MarkerRole::Fit});
  }
  for (const std::string& cam : m.video.cameras) {
    CalibrationImage image{cam, {}};
    for (const auto& marker : s.frame) image.observations.push_back({marker.id, {412.31 + marker.lab_m.x(), 288.07}});
    s.images.push_back(image);
  }
  for (int t = 0; t < 3; ++t) {
    const std::string id = fmt::format("trial{}", t + 1);
    m.trials.push_back({id, "trials/" + id});
    TrialRecording trial;
    trial.spec = m.trials.back();
    trial.tracks.points = m.video.points;
    trial.tracks.cameras = m.video.cameras;
    trial.tracks.uv_px.resize(1500, 24);
    for (int f = 0; f < 1500; ++f)
      for (int c = 0; c < 24; ++c) trial.tracks.uv_px(f, c) = 300.0 + 20.0 * c + std::sin(0.01 * f + c);
    trial.force.sample_rate_hz = 1000.0;
    trial.force.pretrigger_samples = 500;
    trial.force.t_s.resize(5000);
    trial.force.data.resize(5000, 8);
    for (int i = 0; i < 5000; ++i) {
      trial.force.t_s(i) = (i - 500) * 1e-3;
      for (int c = 0; c < 8; ++c) trial.force.data(i, c) = 100.0 * std::sin(0.003 * i + c);
    }
    s.trials.push_back(trial);
  }
  return s;
}

fs::path bench_dir() { return fs::temp_directory_path() / fmt::format("dropfit_capio_bench_{}", ::getpid()); }

void BM_WriteSession(benchmark::State& state) {
  const Session s = make_session();
  const fs::path dir = bench_dir();
  for (auto _ : state) capture::write_session(dir.string(), s);
  fs::remove_all(dir);
}
BENCHMARK(BM_WriteSession)->Unit(benchmark::kMillisecond);

void BM_ReadSession(benchmark::State& state) {
  const fs::path dir = bench_dir();
  capture::write_session(dir.string(), make_session());
  for (auto _ : state) benchmark::DoNotOptimize(capture::read_session(dir.string()));
  fs::remove_all(dir);
}
BENCHMARK(BM_ReadSession)->Unit(benchmark::kMillisecond);

// The files of a five-trial `dropfit run` (as many and about as large as
// the demo session's: per trial seven files of 10-200 kB, five fits with
// five series each, the session's tables, report and JSON), committed into
// a folder that holds the previous run's: staged, every file and folder
// fsynced, swapped in, the old results removed. Wall time: the fsyncs wait
// on the disk, not the CPU.
void BM_CommitRunOutputs(benchmark::State& state) {
  report::OutputSet out;
  auto text = [](std::size_t bytes) { return std::string(bytes, '7'); };
  for (int t = 1; t <= 5; ++t) {
    const std::string dir = fmt::format("trials/trial{}/", t);
    for (const char* name : {"trial.json", "xyzres.csv", "grf.mot", "series.csv", "residuals.csv", "xyzpts.csv",
                             "markers.trc"})
      out.add(dir + name, text(60000));
    out.add(fmt::format("series/trial{}.csv", t), text(150000));
    for (int m = 1; m <= 5; ++m) out.add(fmt::format("fits/model{}/series/trial{}.csv", m, t), text(150000));
  }
  for (int m = 1; m <= 5; ++m) out.add(fmt::format("fits/model{}/fit.json", m), text(40000));
  for (const char* name : {"report.html", "summary.csv", "fit.json", "diagnosis.json", "dlt_coefficients.csv"})
    out.add(name, text(100000));
  const fs::path dir = bench_dir() / "out";
  out.commit(dir.string());
  for (auto _ : state) out.commit(dir.string());
  fs::remove_all(bench_dir());
}
BENCHMARK(BM_CommitRunOutputs)->Unit(benchmark::kMillisecond)->UseRealTime();

}  // namespace
