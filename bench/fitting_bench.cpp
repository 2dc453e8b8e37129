// Speed of the mat models and their fitters (Release build):
//   BM_SimulateModel4        one 0.3 s Model 4 impact at 1 kHz (target < 20 us)
//   BM_SimulateModel4Rk4     the same with an effect on (RK4 path)
//   BM_SimulateModel{1,3}    the smaller models
//   BM_FitModel4OneTrial     Ceres multi-start fit to one trial with kinematics (target < 200 ms)
//   BM_AnnealModel4OneTrial  Corana annealing on the same objective, usual settings
//   BM_FitModel5WarmStart    Model 5 as `dropfit run` fits it: five trials, warm start from
//                            a nearby optimum (Model 4's), one start, 30 iterations, exact
//                            derivatives on 2 threads, predictions and sensitivity
//                            (target < 0.5 s wall)
#include <benchmark/benchmark.h>

#include <random>

#include "fitting/fit.h"
#include "fitting/model5.h"
#include "fitting/models.h"

namespace {

using namespace dropfit::fitting;

void simulate_bench(benchmark::State& state, ModelKind kind, bool effect) {
  MatParams p = paper_table2(kind, 1.5);
  if (effect) p.k1_cubic_n_m3 = 1e7;
  Impact imp;
  imp.velocity_m_s = 5.25;
  imp.duration_s = 0.3;
  double sink = 0.0;
  for (auto _ : state) {
    const Simulation s = simulate(kind, p, imp);
    sink += s.grf_n[20];
    imp.velocity_m_s += 1e-9;  // keep the call honest
  }
  benchmark::DoNotOptimize(sink);
}

void BM_SimulateModel4(benchmark::State& s) { simulate_bench(s, ModelKind::Model4, false); }
void BM_SimulateModel4Rk4(benchmark::State& s) { simulate_bench(s, ModelKind::Model4, true); }
void BM_SimulateModel1(benchmark::State& s) { simulate_bench(s, ModelKind::Model1, false); }
void BM_SimulateModel3(benchmark::State& s) { simulate_bench(s, ModelKind::Model3, false); }

TrialData noisy_trial(double v) {
  const MatParams truth = paper_table2(ModelKind::Model4);
  Impact imp;
  imp.velocity_m_s = v;
  imp.duration_s = 0.15;
  const Simulation s = simulate(ModelKind::Model4, truth, imp);
  std::mt19937 rng(3);
  std::normal_distribution<double> nd(0.0, 1.0);
  TrialData t;
  t.id = "trial3";
  t.impact_velocity_m_s = v;
  t.t_s = s.t_s;
  t.grf_n = s.grf_n;
  t.impactor_m = s.impactor_m;
  t.surface_m = s.surface_m;
  for (Eigen::Index i = 0; i < t.t_s.size(); ++i) {
    t.grf_n[i] += 20.0 * nd(rng);
    t.impactor_m[i] += 0.0005 * nd(rng);
    t.surface_m[i] += 0.0005 * nd(rng);
  }
  return t;
}

void BM_FitModel4OneTrial(benchmark::State& state) {
  const std::vector<TrialData> trials = {noisy_trial(5.25)};
  FitOptions o;
  o.model = ModelKind::Model4;
  o.sensitivity = false;
  long sims = 0;
  double cost = 0.0;
  for (auto _ : state) {
    const FitResult r = fit(trials, o);
    sims = r.evaluations;
    cost = r.cost;
    benchmark::DoNotOptimize(r.params.k1_n_m);
  }
  state.counters["simulations"] = static_cast<double>(sims);
  state.counters["cost"] = cost;
}

void BM_AnnealModel4OneTrial(benchmark::State& state) {
  const std::vector<TrialData> trials = {noisy_trial(5.25)};
  FitOptions o;
  o.model = ModelKind::Model4;
  o.sensitivity = false;
  o.optimizer = Optimizer::Annealing;
  o.anneal.eps = 1e-6;
  long sims = 0;
  double cost = 0.0;
  for (auto _ : state) {
    const FitResult r = fit(trials, o);
    sims = r.evaluations;
    cost = r.cost;
  }
  state.counters["simulations"] = static_cast<double>(sims);
  state.counters["cost"] = cost;
}

void BM_FitModel5WarmStart(benchmark::State& state) {
  const MatParams truth = paper_table2(ModelKind::Model5);
  std::vector<TrialData> trials;
  std::mt19937 rng(5);
  std::normal_distribution<double> nd(0.0, 1.0);
  char id = '1';
  for (double v : {4.3, 4.8, 5.25, 5.75, 6.5}) {
    Impact imp;
    imp.velocity_m_s = v;
    imp.duration_s = 0.15;
    const Simulation s = simulate_model5(truth, Model5Geometry{}, imp);
    TrialData t;
    t.id = std::string("trial") + id++;
    t.impact_velocity_m_s = v;
    t.t_s = s.t_s;
    t.grf_n = s.grf_n;
    t.impactor_m = s.impactor_m;
    for (Eigen::Index i = 0; i < t.t_s.size(); ++i) {
      t.grf_n[i] += 20.0 * nd(rng);
      t.impactor_m[i] += 0.0005 * nd(rng);
    }
    trials.push_back(t);
  }
  FitOptions o;
  o.model = ModelKind::Model5;
  o.initial = truth;  // a nearby optimum: Model 4's, as the pipeline gives it
  o.initial.k1_n_m *= 1.3;
  o.initial.r3_n_s_m *= 0.7;
  o.starts = 1;
  o.max_iterations = 30;
  long sims = 0;
  double cost = 0.0;
  for (auto _ : state) {
    const FitResult r = fit(trials, o);
    sims = r.evaluations;
    cost = r.cost;
  }
  state.counters["simulations"] = static_cast<double>(sims);
  state.counters["cost"] = cost;
}

}  // namespace

BENCHMARK(BM_FitModel5WarmStart)->Unit(benchmark::kMillisecond)->UseRealTime();
BENCHMARK(BM_SimulateModel4)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_SimulateModel4Rk4)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_SimulateModel1)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_SimulateModel3)->Unit(benchmark::kMicrosecond);
BENCHMARK(BM_FitModel4OneTrial)->Unit(benchmark::kMillisecond)->MeasureProcessCPUTime();
BENCHMARK(BM_AnnealModel4OneTrial)->Unit(benchmark::kMillisecond)->Iterations(1)->MeasureProcessCPUTime();
