// Model 5 speed: one 0.3 s impact (the paper's trial 3: 24 kg at 5.25 m/s,
// Table 2 Model 5 parameters) on the default 9 x 6 grid (target < 10 ms; the
// paper's visual Nastran model took 28 s), how the time grows with the grid,
// and Model 4 for scale.
//
//   cmake --build build-NAME --target model5_bench && build-NAME/bench/model5_bench
#include <benchmark/benchmark.h>
#include <algorithm>

#include "fitting/model5.h"
#include "fitting/models.h"

namespace {

using namespace dropfit::fitting;

Impact trial3() {
  Impact im;
  im.mass_kg = 24.0;
  im.velocity_m_s = 5.25;
  im.duration_s = 0.3;
  im.output_dt_s = 1e-3;
  return im;
}

void BM_Model5_DefaultGrid(benchmark::State& state) {
  const MatParams p = paper_table2(ModelKind::Model5);
  const Model5Geometry geo;
  const Impact im = trial3();
  long steps = 0;
  for (auto _ : state) {
    const Model5Result r = simulate_model5_detailed(p, geo, im);
    benchmark::DoNotOptimize(r.peak_grf_n);
    steps = r.steps;
  }
  state.counters["steps"] = static_cast<double>(steps);
  state.counters["cells"] = geo.nodes_x * geo.nodes_y;
}
BENCHMARK(BM_Model5_DefaultGrid)->Unit(benchmark::kMillisecond);

// Grid n_x x (2 n_x / 3) over the 0.90 x 0.60 m mat. Finer cells are lighter
// while the shear pair stiffness stays S: the stable step shrinks like the
// cell size, so the cost grows like cells^1.5 once shear sets the step.
void BM_Model5_Grid(benchmark::State& state) {
  const MatParams p = paper_table2(ModelKind::Model5);
  Model5Geometry geo;
  geo.nodes_x = static_cast<int>(state.range(0));
  geo.nodes_y = std::max(1, static_cast<int>(2 * state.range(0) / 3));
  const Impact im = trial3();
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
BENCHMARK(BM_Model5_Grid)->Arg(1)->Arg(3)->Arg(6)->Arg(9)->Arg(12)->Arg(18)->Arg(27)->Unit(benchmark::kMillisecond);

void BM_Model4_ForScale(benchmark::State& state) {
  const MatParams p = paper_table2(ModelKind::Model5);
  const Impact im = trial3();
  for (auto _ : state) {
    const Simulation s = simulate(ModelKind::Model4, p, im);
    benchmark::DoNotOptimize(s.grf_n.data());
  }
}
BENCHMARK(BM_Model4_ForScale)->Unit(benchmark::kMillisecond);

}  // namespace
