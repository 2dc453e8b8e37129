// Speed of Model 6 (the foam column) and of a run that chooses it (Release):
//   BM_SimulateModel6       one 0.12 s impact of the fitter's column (5 + 3
//                           elements, 0.25 ms steps) at 5.25 m/s, doubles
//   BM_FitModel6            fit_model6 on a five-trial session of the
//                           generator's foam world (seed 2401), trained on the
//                           median trial, every trial predicted (wall time:
//                           the derivative passes run on two threads)
//   BM_RunContinuumC1       pipeline::build through the loop on
//                           ../shared/validation-continuum/c1-foam (five
//                           trials; Models 1-5, the loop, Model 6 chosen);
//                           skipped without ../shared
#include <benchmark/benchmark.h>

#include <filesystem>

#include "fitting/model6.h"
#include "fitting/model6_fit.h"
#include "pipeline/model6_stage.h"
#include "pipeline/pipeline.h"
#include "samples/generator/synth.h"

namespace {

using namespace dropfit;

void BM_SimulateModel6(benchmark::State& state) {
  const fitting::Model6FitOptions o;
  fitting::Model6Params p;
  fitting::Impact imp;
  imp.velocity_m_s = 5.25;
  imp.duration_s = 0.12;
  imp.output_dt_s = 5e-4;
  double sink = 0.0;
  for (auto _ : state) {
    const fitting::Simulation s = fitting::simulate_model6(p, o.geometry, imp);
    sink += s.grf_n[20];
    imp.velocity_m_s += 1e-9;
  }
  benchmark::DoNotOptimize(sink);
}

void BM_FitModel6(benchmark::State& state) {
  const synth::SyntheticSession s = synth::make_session(synth::foam_world_options(2401));
  const pipeline::SessionState st = pipeline::build(s.session, {.upto = pipeline::Stage::Trials});
  const fitting::Model6FitOptions o = pipeline::model6_options(s.session.manifest);
  long iterations = 0;
  for (auto _ : state) iterations = fitting::fit_model6(st.fit_data, o).iterations;
  state.counters["lm_iterations"] = static_cast<double>(iterations);
}

void BM_RunContinuumC1(benchmark::State& state) {
  const auto dir = std::filesystem::path(DROPFIT_SOURCE_DIR) / ".." / "shared" / "validation-continuum" / "c1-foam" /
                   "session";
  if (!std::filesystem::exists(dir)) {
    state.SkipWithError("../shared/validation-continuum is absent");
    return;
  }
  for (auto _ : state) benchmark::DoNotOptimize(pipeline::build(dir.string()).final_label());
}

}  // namespace

BENCHMARK(BM_SimulateModel6)->Unit(benchmark::kMillisecond);
BENCHMARK(BM_FitModel6)->Unit(benchmark::kMillisecond)->Iterations(1)->UseRealTime();
BENCHMARK(BM_RunContinuumC1)->Unit(benchmark::kMillisecond)->Iterations(1)->UseRealTime();
