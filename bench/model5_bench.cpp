// Model 5 speed: one 0.3 s impact (the paper's trial 3: 24 kg at 5.25 m/s)
// on the default 9 x 6 grid, at the paper's Table 2 Model 5 parameters
// ("typical"), at the corners of the fitter's bounds (every stiffness
// 2e3 or 3e7 N/m, every damping 3 or 3e4 N s/m; fitting/fit.h: the start
// ranges widened 10x) and at the dearest points inside them (see corner()), with the current scheme (fitting/model5_impl.h: the
// vertical elements implicit) and the explicit leapfrog reference
// (bench/model5_leapfrog.h, its step capped by the stiffest element); the
// Jet version (8 derivatives) for the fitter; how the time grows with the
// grid; Model 4 for scale.
//
//   cmake --build build --target model5_bench && build/bench/model5_bench
#include <benchmark/benchmark.h>
#include <ceres/jet.h>

#include <algorithm>
#include <vector>

#include "bench/model5_impact.h"
#include "bench/model5_leapfrog.h"
#include "fitting/model5.h"
#include "fitting/model5_impl.h"
#include "fitting/models.h"

namespace {

using namespace dropfit::fitting;

using dropfit::bench::model5_trial3;
using dropfit::bench::simulate_model5_leapfrog;

// 0 typical (Table 2), 1 k min r min, 2 k min r max, 3 k max r min, 4 k max r max
// (every element); inside the bounds, where the step is set by an
// overdamped element's creep (fitting/model5.h, Integration): 5 every
// element k 3e7 N/m, r 6000 N s/m (near critical on element 1's cells: a
// creep of 8 000 1/s, 35 600 steps before fast creeps were left to the
// stiff limit), 6 element 1 alone at k 1e7 N/m, r 5600 N s/m (creep just
// below the 2 000 1/s resolved: the most steps while the creep limit held
// for the whole run; now only while the face presses), 7 every element k 1e6 N/m,
// r 3e4 N s/m (heavily damped: the largest error, see docs/models.md);
// long contacts with a creep-limited step (the dearest points of the scan,
// bench/model5_scan.cpp; 4 960, 8 102 and 7 310 steps with the creep limit
// held whenever the face pressed): 8 k1 2.8e7, r1 1.5e4, k2 8.9e4, k3
// 3.8e4, the rest Table 2; 9 k 3.47e3, 2.89e7, 4.88e5 N/m, r 4.15, 1.84e4,
// 162 N s/m (element 2 creeps under a soft element 1); 10 k 2.43e7, 2.79e7,
// 2.58e3 N/m, r 1.42e4, 283, 94.2 N s/m.
MatParams corner(int which) {
  MatParams p = paper_table2(ModelKind::Model5);
  if (which == 0) return p;
  auto set = [&p](double k1, double k2, double k3, double r1, double r2, double r3) {
    p.k1_n_m = k1, p.k2_n_m = k2, p.k3_n_m = k3;
    p.r1_n_s_m = r1, p.r2_n_s_m = r2, p.r3_n_s_m = r3;
    return p;
  };
  if (which == 8) return set(2.8e7, 8.9e4, 3.8e4, 1.5e4, p.r2_n_s_m, p.r3_n_s_m);
  if (which == 9) return set(3.47e3, 2.89e7, 4.88e5, 4.15, 1.84e4, 162.0);
  if (which == 10) return set(2.43e7, 2.79e7, 2.58e3, 1.42e4, 283.0, 94.2);
  if (which == 5) {
    p.k1_n_m = p.k2_n_m = p.k3_n_m = 3e7;
    p.r1_n_s_m = p.r2_n_s_m = p.r3_n_s_m = 6000.0;
    return p;
  }
  if (which == 6) {
    p.k1_n_m = 1e7;
    p.r1_n_s_m = 5600.0;
    return p;
  }
  if (which == 7) {
    p.k1_n_m = p.k2_n_m = p.k3_n_m = 1e6;
    p.r1_n_s_m = p.r2_n_s_m = p.r3_n_s_m = 3e4;
    return p;
  }
  const double k = (which == 3 || which == 4) ? 3e7 : 2e3;
  const double r = (which == 2 || which == 4) ? 3e4 : 3.0;
  p.k1_n_m = p.k2_n_m = p.k3_n_m = k;
  p.r1_n_s_m = p.r2_n_s_m = p.r3_n_s_m = r;
  return p;
}

void BM_Model5(benchmark::State& state) {
  const MatParams p = corner(static_cast<int>(state.range(0)));
  const Model5Geometry geo;
  const Impact im = model5_trial3();
  long steps = 0;
  for (auto _ : state) {
    const Model5Result r = simulate_model5_detailed(p, geo, im);
    benchmark::DoNotOptimize(r.peak_grf_n);
    steps = r.steps;
  }
  state.counters["steps"] = static_cast<double>(steps);
}
BENCHMARK(BM_Model5)->DenseRange(0, 10)->Unit(benchmark::kMillisecond)->MeasureProcessCPUTime();

void BM_Model5Leapfrog(benchmark::State& state) {
  const MatParams p = corner(static_cast<int>(state.range(0)));
  const Model5Geometry geo;
  const Impact im = model5_trial3();
  long steps = 0;
  for (auto _ : state) {
    const Model5Result r = simulate_model5_leapfrog(p, geo, im);
    benchmark::DoNotOptimize(r.peak_grf_n);
    steps = r.steps;
  }
  state.counters["steps"] = static_cast<double>(steps);
}
BENCHMARK(BM_Model5Leapfrog)->DenseRange(0, 10)->Unit(benchmark::kMillisecond);

// The fitter's path: the three series it fits, in doubles and with Jets
// carrying 8 derivatives (k1..k3, r1..r3, m1, m2).
void BM_Model5Series(benchmark::State& state) {
  const Model5ParamsT<double> p = model5_params(corner(static_cast<int>(state.range(0))));
  const Model5Geometry geo;
  const Impact im = model5_trial3();
  std::vector<double> grf, imp, surf;
  for (auto _ : state) {
    simulate_model5_t<double>(p, geo, im, 301, &grf, &imp, &surf);
    benchmark::DoNotOptimize(grf.data());
  }
}
BENCHMARK(BM_Model5Series)->DenseRange(0, 10)->Unit(benchmark::kMillisecond);

void BM_Model5Jet8(benchmark::State& state) {
  using J = ceres::Jet<double, 8>;
  const Model5ParamsT<double> d = model5_params(corner(static_cast<int>(state.range(0))));
  Model5ParamsT<J> p;
  p.k1_n_m = J(d.k1_n_m, 0);
  p.k2_n_m = J(d.k2_n_m, 1);
  p.k3_n_m = J(d.k3_n_m, 2);
  p.r1_n_s_m = J(d.r1_n_s_m, 3);
  p.r2_n_s_m = J(d.r2_n_s_m, 4);
  p.r3_n_s_m = J(d.r3_n_s_m, 5);
  p.m1_kg = J(d.m1_kg, 6);
  p.m2_kg = J(d.m2_kg, 7);
  p.r1_unload_n_s_m = J(d.r1_unload_n_s_m);
  const Model5Geometry geo;
  const Impact im = model5_trial3();
  std::vector<J> grf, imp, surf;
  for (auto _ : state) {
    simulate_model5_t<J>(p, geo, im, 301, &grf, &imp, &surf);
    benchmark::DoNotOptimize(grf.data());
  }
}
BENCHMARK(BM_Model5Jet8)->DenseRange(0, 10)->Unit(benchmark::kMillisecond);

// Grid n_x x (2 n_x / 3) over the 0.90 x 0.60 m mat. Finer cells are lighter
// while the shear pair stiffness stays S: the explicit shear sets the step
// once it is below max_step_s, so the cost grows like cells^1.5 there.
void BM_Model5_Grid(benchmark::State& state) {
  const MatParams p = paper_table2(ModelKind::Model5);
  Model5Geometry geo;
  geo.nodes_x = static_cast<int>(state.range(0));
  geo.nodes_y = std::max(1, static_cast<int>(2 * state.range(0) / 3));
  const Impact im = model5_trial3();
  long steps = 0;
  double dt = 0.0;
  for (auto _ : state) {
    const Model5Result r = simulate_model5_detailed(p, geo, im);
    benchmark::DoNotOptimize(r.peak_grf_n);
    steps = r.steps;
    dt = r.step_s;
  }
  state.counters["cells"] = geo.nodes_x * geo.nodes_y;
  state.counters["steps"] = static_cast<double>(steps);
  state.counters["dt_us"] = dt * 1e6;
}
BENCHMARK(BM_Model5_Grid)->Arg(1)->Arg(3)->Arg(6)->Arg(9)->Arg(12)->Arg(18)->Unit(benchmark::kMillisecond);

void BM_Model4_ForScale(benchmark::State& state) {
  const MatParams p = paper_table2(ModelKind::Model5);
  const Impact im = model5_trial3();
  for (auto _ : state) {
    const Simulation s = simulate(ModelKind::Model4, p, im);
    benchmark::DoNotOptimize(s.grf_n.data());
  }
}
BENCHMARK(BM_Model4_ForScale)->Unit(benchmark::kMillisecond);

}  // namespace
