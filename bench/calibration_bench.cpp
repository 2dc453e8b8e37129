// calibration/ and reconstruction/ timings on the two-camera test scene of
// tests/support/cameras.h. Targets: a full two-camera calibration with its
// check report under 5 ms; a 5 s, 1000 Hz, 6-marker, 2-camera trial
// reconstructed under 20 ms.
#include <benchmark/benchmark.h>

#include "../tests/support/cameras.h"
#include "calibration/calibration.h"
#include "reconstruction/reconstruction.h"

namespace {

using namespace dropfit;

void BM_FitDlt(benchmark::State& state) {
  const auto camera = testsupport::two_cameras()[0];
  const auto markers = testsupport::calibration_markers();
  testsupport::PixelNoise noise(0.25, 1);
  std::vector<calibration::Correspondence> points;
  for (const auto& m : markers)
    if (!m.is_check) points.push_back({m.id, m.lab_m, camera.project(m.lab_m) + noise()});
  calibration::DltOptions options;
  options.refine = state.range(0) > 0;
  options.fit_distortion = state.range(0) > 1;
  for (auto _ : state) benchmark::DoNotOptimize(calibration::fit_dlt("cam1", points, options));
}
// 0: linear only, 1: refined (dlt11), 2: with distortion (dlt16).
BENCHMARK(BM_FitDlt)->Arg(0)->Arg(1)->Arg(2)->Unit(benchmark::kMicrosecond);

// The whole calibration: two cameras fitted, 10 check markers, leave-one-out
// for 10 fit markers and the outlier search.
void BM_CalibrateTwoCameras(benchmark::State& state) {
  const double k1 = state.range(0) ? -0.2 : 0.0;
  const auto cameras = testsupport::two_cameras(k1);
  const auto markers = testsupport::calibration_markers();
  const auto views = testsupport::observe(cameras, markers, 0.25, 1);
  calibration::CalibrationOptions options;
  options.dlt.fit_distortion = state.range(0) > 0;
  for (auto _ : state) benchmark::DoNotOptimize(calibration::calibrate(markers, views, options));
}
// 0: dlt11, 1: dlt16 on a distorting lens.
BENCHMARK(BM_CalibrateTwoCameras)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

// A 5 s trial at 1000 Hz: 6 markers falling and swaying, 2 cameras, 0.25 px
// noise, 2 % of the samples missing in one camera.
struct TrialScene {
  std::vector<calibration::Camera> cameras;
  Eigen::MatrixXd uv;
  int n_points = 6;
};

TrialScene trial_scene(bool distorted) {
  const auto truth = testsupport::two_cameras(distorted ? -0.2 : 0.0);
  std::vector<calibration::Camera> cameras;
  for (const auto& c : truth) cameras.push_back(c.as_camera());
  const int n_frames = 5000, n_points = 6, n_cameras = 2;
  testsupport::PixelNoise noise(0.25, 3);
  std::mt19937 engine(5);
  std::uniform_real_distribution<double> unit(0.0, 1.0);
  Eigen::MatrixXd uv(n_frames, 2 * n_points * n_cameras);
  for (int f = 0; f < n_frames; ++f) {
    const double t = 1e-3 * f;
    for (int p = 0; p < n_points; ++p) {
      const Eigen::Vector3d X(-0.3 + 0.12 * p + 0.02 * std::sin(3.0 * t + p), 0.1 * std::cos(2.0 * t),
                              0.1 + 0.5 * std::abs(std::cos(1.3 * t + 0.2 * p)));
      for (int c = 0; c < n_cameras; ++c) {
        const Eigen::Vector2d px = unit(engine) < 0.02 && c == 1 ? Eigen::Vector2d::Constant(NAN)
                                                                  : Eigen::Vector2d(truth[c].project(X) + noise());
        uv.row(f).segment<2>(2 * (p * n_cameras + c)) = px.transpose();
      }
    }
  }
  return {cameras, uv, n_points};
}

void BM_ReconstructTrial(benchmark::State& state) {
  const TrialScene scene = trial_scene(state.range(1) > 0);
  const bool refine = state.range(0) > 0;
  for (auto _ : state)
    benchmark::DoNotOptimize(reconstruction::reconstruct(scene.cameras, scene.uv, scene.n_points, refine));
  state.SetItemsProcessed(state.iterations() * scene.uv.rows() * scene.n_points);
}
// {refine, distortion}
BENCHMARK(BM_ReconstructTrial)->Args({0, 0})->Args({1, 0})->Args({1, 1})->Unit(benchmark::kMillisecond);

// The same trial's checks of the rays as the pipeline runs them: every
// point's epipolar distance once, then the cameras' sub-frame offset and the
// markers digitised off their point (the edge scan and its stretches).
void BM_RayChecksTrial(benchmark::State& state) {
  const TrialScene scene = trial_scene(state.range(0) > 0);
  for (auto _ : state) {
    const auto series = reconstruction::epipolar_series(scene.cameras, scene.uv, scene.n_points);
    benchmark::DoNotOptimize(reconstruction::subframe_offset(series));
    benchmark::DoNotOptimize(reconstruction::marker_slips(series));
  }
  state.SetItemsProcessed(state.iterations() * scene.uv.rows() * scene.n_points);
}
// {distortion}
BENCHMARK(BM_RayChecksTrial)->Arg(0)->Arg(1)->Unit(benchmark::kMillisecond);

}  // namespace
