// The whole diagnosis of a five-trial session (calibration, sync, force plate,
// mat), on a clean session and on one with a stiffening mat (the loop then
// refits the mat); and the pieces: residual analysis and Table 1 mode.
//
//   cmake --build build --target diagnosis_bench && ./build/bench/diagnosis_bench
#include <benchmark/benchmark.h>

#include <numbers>
#include <random>

#include "pipeline/pipeline.h"
#include "diagnosis/diagnosis.h"
#include "diagnosis/structure.h"
#include "samples/generator/synth.h"

namespace {

using namespace dropfit;

// What `dropfit diagnose` does: the pipeline's state up to the Model 4 fit,
// then the loop on it.
diagnosis::DiagnosisResult diagnose_session(const Session& session) {
  const auto st = pipeline::build(session, {.upto = pipeline::Stage::Fits, .models = {fitting::ModelKind::Model4}});
  return diagnosis::diagnose(st);
}

synth::SyntheticSession make(const std::string& effect, double magnitude) {
  synth::SynthOptions o;
  o.seed = 3;
  if (!effect.empty()) synth::set_effect(o.effects, effect, magnitude);
  return synth::make_session(o);
}

void BM_DiagnoseCleanSession(benchmark::State& state) {
  const auto s = make("", 0.0);
  for (auto _ : state) benchmark::DoNotOptimize(diagnose_session(s.session));
}
BENCHMARK(BM_DiagnoseCleanSession)->Unit(benchmark::kMillisecond)->Iterations(3);

void BM_DiagnoseStiffeningSession(benchmark::State& state) {
  const auto s = make("stiffness_nonlinearity", 4e6);
  for (auto _ : state) benchmark::DoNotOptimize(diagnose_session(s.session));
}
BENCHMARK(BM_DiagnoseStiffeningSession)->Unit(benchmark::kMillisecond)->Iterations(3);

// The slowest case: structure that no library effect explains (a plate
// frame ringing at 28 Hz after the impact), so every candidate is refitted
// and rejected.
void BM_DiagnoseUnexplainedSession(benchmark::State& state) {
  auto s = make("", 0.0);
  for (std::size_t i = 0; i < s.session.trials.size(); ++i) {
    ForceRecord& rec = s.session.trials[i].force;
    const double tc = s.truth.trials[i].contact_time_s;
    for (Eigen::Index k = 0; k < rec.t_s.size(); ++k) {
      const double t = rec.t_s(k) - tc;
      if (t <= 0.0) continue;
      const double ring = 250.0 * std::exp(-t / 0.15) * std::sin(2.0 * std::numbers::pi * 28.0 * t);
      for (int c = 4; c < 8; ++c) rec.data(k, c) += ring / 4.0;
    }
  }
  for (auto _ : state) benchmark::DoNotOptimize(diagnose_session(s.session));
}
BENCHMARK(BM_DiagnoseUnexplainedSession)->Unit(benchmark::kMillisecond)->Iterations(2);

void BM_AnalyseResidual(benchmark::State& state) {
  // Five trials of 200 samples, the nine state candidates.
  const int n = 1000;
  std::mt19937 rng(1);
  std::normal_distribution<double> g(0.0, 10.0);
  Eigen::VectorXd t(n), x(n), v(n), e(n);
  for (int i = 0; i < n; ++i) {
    const double ti = (i % 200) * 1e-3;
    t(i) = ti;
    x(i) = 0.1 * std::sin(std::numbers::pi * ti / 0.2);
    v(i) = 0.1 * std::numbers::pi / 0.2 * std::cos(std::numbers::pi * ti / 0.2);
    e(i) = 4e6 * x(i) * x(i) * x(i) + g(rng);
  }
  const auto cands = diagnosis::state_candidates(t, x, v);
  std::vector<Eigen::VectorXd> parts;
  for (int k = 0; k < 5; ++k) parts.push_back(e.segment(200 * k, 200));
  diagnosis::StructureOptions so;
  so.dt_s = 1e-3;
  for (auto _ : state) benchmark::DoNotOptimize(diagnosis::analyse_residual(parts, cands, so));
}
BENCHMARK(BM_AnalyseResidual)->Unit(benchmark::kMicrosecond);

void BM_Table1(benchmark::State& state) {
  const std::vector<fitting::TableTrial> table{{"1", 4.30, 0.088, 5593},
                                               {"2", 4.80, 0.099, 6341},
                                               {"3", 5.25, 0.100, 7054},
                                               {"4", 5.75, 0.113, 8398},
                                               {"5", 6.50, 0.118, 9597}};
  for (auto _ : state) benchmark::DoNotOptimize(diagnosis::diagnose_table(table));
}
BENCHMARK(BM_Table1)->Unit(benchmark::kMillisecond)->Iterations(3);

}  // namespace
