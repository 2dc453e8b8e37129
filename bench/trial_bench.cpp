// One trial processed end to end from plain values: eight force channels to
// resultants, zeroing, trigger and onset (forceplate), then the trial's
// free-fall fit, synchronisation, deformation, tilt and series (trial).
// 5000 force samples and 5000 video frames, as a 5 s record at 1000 Hz.
#include <benchmark/benchmark.h>

#include <cmath>
#include <random>

#include "forceplate/forceplate.h"
#include "trial/trial.h"

namespace {

struct Input {
  Eigen::VectorXd t_s;
  Eigen::MatrixXd channels;
  dropfit::reconstruction::Trajectories markers;
  dropfit::forceplate::ProcessOptions force_options;
  dropfit::trial::TrialOptions trial_options;
};

// A 24 kg impactor at 5.25 m/s onto a Hunt-Crossley mat, 0.5 mm marker and
// 2 N plate noise, video 3 ms off the declared clock.
Input make_input() {
  const int n = 5000, pre = 500, frames = 5000, trigger_frame = 2500;
  const double m = 24.0, g = 9.81, v_c = 5.25, k = 2.8e5, alpha = 0.3, top = 0.205, offset = 0.003;
  const double h = 1e-5;
  std::vector<double> pen, force;
  double x = 0.0, v = v_c;
  auto f_of = [&](double xx, double vv) { return xx > 0 ? std::max(0.0, k * std::pow(xx, 1.5) * (1 + alpha * vv)) : 0.0; };
  for (int i = 0; i * h < 4.6; ++i) {
    pen.push_back(x);
    force.push_back(f_of(x, v));
    const double a = g - f_of(x, v) / m;  // semi-implicit Euler is plenty for a benchmark
    v += h * a;
    x += h * v;
  }
  auto at = [&](const std::vector<double>& y, double tau) {
    if (tau <= 0) return 0.0;
    const std::size_t i = std::min(static_cast<std::size_t>(tau / h), y.size() - 2);
    return y[i];
  };
  int k_trig = 0;
  while (at(force, 0.37e-3 + k_trig * 1e-3) < 25.0) ++k_trig;
  const double tau_trig = 0.37e-3 + k_trig * 1e-3;
  std::mt19937 rng(1);
  std::normal_distribution<double> unit(0.0, 1.0);
  Input in;
  in.t_s.resize(n);
  in.channels.resize(n, 8);
  for (int i = 0; i < n; ++i) {
    const double tau = tau_trig + (i - pre) * 1e-3;
    in.t_s[i] = (i - pre) * 1e-3;
    const double fz = at(force, tau);
    for (int c = 0; c < 8; ++c) in.channels(i, c) = (c >= 4 ? fz / 4 : 0.0) + unit(rng);
  }
  in.markers.lab_m.setConstant(frames, 18, std::nan(""));
  in.markers.residual_px.setConstant(frames, 6, 0.3);
  for (int i = 0; i < frames; ++i) {
    const double tau = (i - trigger_frame) * 1e-3 - offset + tau_trig;
    if (tau < -v_c / g) continue;
    const double z = tau <= 0 ? top + v_c * (-tau) - 0.5 * g * tau * tau : top - at(pen, tau);
    const double xs[6] = {0.1, -0.1, 0.0, 0.0, 0.4, -0.4}, ys[6] = {0, 0, 0.25, -0.25, 0, 0};
    for (int p = 0; p < 6; ++p) {
      const double zp = p < 2 ? z : top - 0.15 * std::max(0.0, tau > 0 ? at(pen, tau) : 0.0);
      in.markers.lab_m(i, 3 * p) = xs[p] + 5e-4 * unit(rng);
      in.markers.lab_m(i, 3 * p + 1) = ys[p] + 5e-4 * unit(rng);
      in.markers.lab_m(i, 3 * p + 2) = zp + 5e-4 * unit(rng);
    }
  }
  in.force_options.pretrigger_samples = pre;
  auto& o = in.trial_options;
  o.id = "bench";
  o.trigger_frame = trigger_frame;
  o.base_markers = {0, 1};
  o.surface_markers = {2, 3, 4, 5};
  o.mat_top_z_m = top;
  return in;
}

void BM_ForceplateAndTrial(benchmark::State& state) {
  const Input in = make_input();
  const dropfit::forceplate::PlateGeometry plate;
  bool accepted = false;
  for (auto _ : state) {
    const auto raw = dropfit::forceplate::from_eight_channels(in.t_s, in.channels, plate);
    const auto force = dropfit::forceplate::process(raw, in.force_options);
    const auto result = dropfit::trial::analyse(force, in.markers, in.trial_options);
    accepted = result.accepted;
    benchmark::DoNotOptimize(result.impact_velocity_m_s);
  }
  state.counters["accepted"] = accepted ? 1 : 0;
}
BENCHMARK(BM_ForceplateAndTrial)->Unit(benchmark::kMillisecond);

void BM_ForceplateOnly(benchmark::State& state) {
  const Input in = make_input();
  const dropfit::forceplate::PlateGeometry plate;
  for (auto _ : state) {
    const auto raw = dropfit::forceplate::from_eight_channels(in.t_s, in.channels, plate);
    const auto force = dropfit::forceplate::process(raw, in.force_options);
    benchmark::DoNotOptimize(force.contact_time_s);
  }
}
BENCHMARK(BM_ForceplateOnly)->Unit(benchmark::kMillisecond);

}  // namespace
