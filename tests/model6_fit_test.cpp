// Model 6 (the foam column) fitted on continuum-mat sessions, trained on
// the deepest impact (the fastest trial, as the pipeline trains it) and
// predicting the others, against the truth:
//   - ../shared/validation-continuum c1 and c2 (a world that shares no code
//     with dropfit; read in place, skipped without ../shared, failing under
//     CI=true);
//   - sessions of the generator's own foam world (samples/generator/foam.h:
//     another elastic law and integrator than Model 6's), other foams.
// Asserted on c1 and c2, per trial: the held-out peak force within 2 % of
// the truth, the maximum face travel within 1.5 mm, the video-force clock
// offset from the fitted contact instant within 0.3 ms; and the training
// fit near the noise (RMS under 4 noise SDs on both channels: 2.0 and 0.9
// on c1, 2.8 and 1.0 on c2, whose plate noise is a few newtons). The
// generator's foams (densification (e_d / (e_d - e))^n - 1 over an
// exponential plateau, not Model 6's tanh plateau and (e / (e_d - e))^n)
// are asserted at the same held-out targets; their deepest impact shows
// the two laws' different densification, so the training force is held
// to 8 noise SDs (seeds 2401, 2407, 2425: 6.7, 5.9, 4.7; travel 0.7-1.3).
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <sstream>
#include <string>

#include "capture/io.h"
#include "core/error.h"
#include "pipeline/pipeline.h"
#include "diagnosis/model_choice.h"
#include "fitting/model6_fit.h"
#include "samples/generator/synth.h"

namespace dropfit {
namespace {

namespace fs = std::filesystem;
using json = nlohmann::json;

struct TruthTrial {
  std::string id;
  double peak_n = 0.0, max_deformation_m = 0.0, offset_s = 0.0;
};

fitting::Model6FitOptions options_for(const Manifest& m) {
  fitting::Model6FitOptions o;
  if (m.mat.layers.size() < 2) throw Error("a foam column needs two declared layers");
  o.geometry.top_thickness_m = m.mat.layers[0].thickness_m;
  o.geometry.base_thickness_m = m.mat.layers[1].thickness_m;
  o.top_mass_kg = m.mat.layers[0].mass_kg;
  o.base_mass_kg = m.mat.layers[1].mass_kg;
  o.geometry.area_m2 = m.impactor.footprint_m[0] * m.impactor.footprint_m[1];
  return o;
}

struct Tolerance {
  double peak = 0.02, travel_m = 1.5e-3, offset_s = 3e-4, force_sd = 4.0, travel_sd = 4.0;
};

// Fits Model 6 on the session (into *out when given) and checks every
// held-out trial against the truth.
void check_session(const Session& session, const std::vector<TruthTrial>& truth, const Tolerance& tol = {},
                   fitting::Model6FitResult* out = nullptr) {
  pipeline::SessionState state = pipeline::build(session, {.upto = pipeline::Stage::Trials});
  const fitting::Model6FitOptions o = options_for(session.manifest);
  const fitting::Model6FitResult fit = fitting::fit_model6(state.fit_data, o);
  if (out) *out = fit;
  EXPECT_LT(fit.force_rms_sigma, tol.force_sd);
  EXPECT_LT(fit.impactor_rms_sigma, tol.travel_sd);
  std::printf("model6 fit %.2f s, %ld iterations, training RMS force %.2f, travel %.2f noise SDs\n", fit.seconds,
              fit.iterations, fit.force_rms_sigma, fit.impactor_rms_sigma);
  // Chosen over the lumped chain by held-out prediction on both channels.
  fitting::FitOptions m4 = state.baseline_fit_options;
  m4.sensitivity = false;
  const fitting::FitResult chain = fitting::fit(state.fit_data, m4);
  const diagnosis::HeldOutChoice choice =
      diagnosis::choose_by_held_out(state.fit_data, "model4", chain.trials, "model6", fit.trials);
  EXPECT_EQ(choice.chosen, "model6") << choice.evidence;
  std::printf("%s\n", choice.evidence.c_str());
  for (const TruthTrial& t : truth) {
    SCOPED_TRACE(t.id);
    const auto rep = std::find_if(fit.trials.begin(), fit.trials.end(), [&](const auto& r) { return r.id == t.id; });
    ASSERT_NE(rep, fit.trials.end());
    const auto st = std::find_if(state.trials.begin(), state.trials.end(),
                                 [&](const auto& s) { return s.result.id == t.id; });
    ASSERT_NE(st, state.trials.end());
    ASSERT_TRUE(st->result.accepted) << st->result.reject_reason;
    double sim_peak = 0.0, sim_travel = 0.0;
    for (Eigen::Index i = 0; i < rep->simulation.t_s.size(); ++i) {
      if (rep->simulation.t_s[i] > rep->window_end_s) break;
      sim_peak = std::max(sim_peak, rep->simulation.grf_n[i]);
      if (rep->simulation.t_s[i] >= 0.0) sim_travel = std::max(sim_travel, rep->simulation.impactor_m[i]);
    }
    EXPECT_NEAR(sim_peak / t.peak_n, 1.0, tol.peak) << "peak " << sim_peak << " against " << t.peak_n;
    EXPECT_NEAR(sim_travel, t.max_deformation_m, tol.travel_m);
    const double offset = st->result.video_offset_s - rep->contact_shift_s;
    EXPECT_NEAR(offset, t.offset_s, tol.offset_s);
    std::printf("%s%s: peak %+.2f %%, travel %+.2f mm, offset error %+.3f ms (onset estimate %+.3f ms)\n",
                t.id.c_str(), rep->train ? " (train)" : "", 100.0 * (sim_peak / t.peak_n - 1.0),
                1e3 * (sim_travel - t.max_deformation_m), 1e3 * (offset - t.offset_s),
                1e3 * (st->result.video_offset_s - t.offset_s));
  }
}

fs::path continuum_root() { return fs::path(DROPFIT_SOURCE_DIR) / ".." / "shared" / "validation-continuum"; }

bool shared_present() {
  if (fs::exists(continuum_root())) return true;
  const char* ci = std::getenv("CI");
  if (ci && std::string(ci) == "true") ADD_FAILURE() << "CI=true and " << continuum_root() << " is missing";
  return false;
}

void check_shared(const std::string& name) {
  if (!shared_present()) GTEST_SKIP() << "../shared/validation-continuum is absent";
  const fs::path dir = continuum_root() / name;
  std::ifstream in(dir / "truth.json");
  const json truth = json::parse(in);
  std::vector<TruthTrial> tt;
  for (const auto& t : truth["trials"])
    tt.push_back({t["id"], t["peak_force_n"], t["max_deformation_m"], t["video_offset_s"]});
  fitting::Model6FitResult fit;
  check_session(capture::read_session((dir / "session").string()), tt, {}, &fit);
  for (const auto& r : fit.reach)
    std::printf("%s%s: max strain top %.3f, base %.3f%s\n", r.id.c_str(), r.train ? " (train)" : "", r.max_top_strain,
                r.max_base_strain, r.extrapolated ? " (extrapolated)" : "");
}

TEST(Model6Fit, SharedContinuumC1) { check_shared("c1-foam"); }
TEST(Model6Fit, SharedContinuumC2) { check_shared("c2-foam"); }

std::vector<TruthTrial> truth_of(const synth::SyntheticSession& s) {
  std::vector<TruthTrial> tt;
  for (const auto& t : s.truth.trials) tt.push_back({t.id, t.peak_force_n, t.max_deformation_m, t.video_offset_s});
  return tt;
}

void check_generator(std::uint64_t seed, const Tolerance& tol, fitting::Model6FitResult* out = nullptr) {
  const synth::SyntheticSession s = synth::make_session(synth::foam_world_options(seed));
  check_session(s.session, truth_of(s), tol, out);
}

const Tolerance kGeneratorFoam{0.02, 1.5e-3, 3e-4, 8.0, 4.0};

// Seed 2401: trained on its fastest trial (trial2, 5.95 m/s; the others
// 4.43-4.97 m/s), which takes the base foam to 0.40 strain, about twice
// what the others reach: every held-out trial lies inside the training
// reach, none is flagged as an extrapolation.
TEST(Model6Fit, GeneratorFoam) {
  fitting::Model6FitResult fit;
  check_generator(2401, kGeneratorFoam, &fit);
  ASSERT_EQ(fit.train_ids, std::vector<std::string>{"trial2"});
  ASSERT_EQ(fit.reach.size(), 5u);
  for (const auto& r : fit.reach) {
    SCOPED_TRACE(r.id);
    EXPECT_FALSE(r.extrapolated);
    if (r.train)
      EXPECT_NEAR(r.max_base_strain, 0.40, 0.03);
    else
      EXPECT_LT(r.max_base_strain, 0.30);
  }
  EXPECT_TRUE(fit.warnings.empty());
  // The column's parameters are its effective values: an SE, no interval
  // (base_densification_pa ends at its bound here, and its note says so).
  ASSERT_EQ(fit.estimates.size(), 14u);
  for (const auto& e : fit.estimates) {
    SCOPED_TRACE(e.name);
    EXPECT_GT(e.se, 0.0);
    EXPECT_TRUE(std::isnan(e.ci_low) && std::isnan(e.ci_high));
    EXPECT_NE(e.note.find(e.at_bound ? "the bound" : "effective value"), std::string::npos);
  }
}
TEST(Model6Fit, GeneratorFoamWithinTargets) { check_generator(2407, kGeneratorFoam); }

// Seed 2425 (a stiff base foam): from the generic start alone the search
// ends in a basin far from the noise; the second start (the base foam's
// stresses doubled or halved, screened) ends in one of a fraction of its
// cost. Asserted: the held-out targets, and the fit's cost under half the
// cost the generic start alone reaches (docs/models.md gives both).
TEST(Model6Fit, GeneratorFoamSecondStart) {
  const synth::SyntheticSession s = synth::make_session(synth::foam_world_options(2425));
  fitting::Model6FitResult fit;
  check_session(s.session, truth_of(s), kGeneratorFoam, &fit);
  const pipeline::SessionState state = pipeline::build(s.session, {.upto = pipeline::Stage::Trials});
  fitting::Model6FitOptions o = options_for(s.session.manifest);
  o.start_base_scales.clear();
  const fitting::Model6FitResult first_only = fitting::fit_model6(state.fit_data, o);
  std::printf("cost %.1f with the second start, %.1f from the generic start alone\n", fit.cost, first_only.cost);
  EXPECT_LT(fit.cost, 0.5 * first_only.cost);
}

// Every trial's 95 % prediction intervals on a generator foam the column
// fits well (seed 2407: training residual 5.9 and 1.3 noise SDs, held-out
// peaks within 0.5 % of the truth). Asserted: each interval exists, is
// finite and of a size a lab can use (peak force SE between 0.01 % and 3 %
// of the peak, time to peak SE between 1 us and 1 ms, travel SE between
// 0.01 and 3 mm); a training trial's is +-1.96 SE, a held-out trial's
// +-t SE with t from 1.96 up to Student's 3.182 (3 degrees of freedom: its
// discrepancy scaled by the 3 other held-out trials); the model's
// discrepancy only widens them, and so does
// its cross-validated scale (a training trial's not at all); every trial's
// true peak force and largest travel lie inside their interval. The time
// to peak's interval can be narrower than its error (its coverage over
// many foams is in docs/validation.md): asserted only within 0.2 ms of the
// truth.
TEST(Model6Fit, PredictionIntervalsHoldTheTruth) {
  const synth::SyntheticSession s = synth::make_session(synth::foam_world_options(2407));
  const pipeline::SessionState state = pipeline::build(s.session, {.upto = pipeline::Stage::Trials});
  fitting::Model6FitOptions o = options_for(s.session.manifest);
  const fitting::Model6FitResult fit = fitting::fit_model6(state.fit_data, o);
  fitting::Model6FitResult bare = fit, raw = fit;
  o.cross_validate_discrepancy = false;
  fitting::add_model6_prediction_intervals(state.fit_data, o, raw);
  o.model_discrepancy = false;
  fitting::add_model6_prediction_intervals(state.fit_data, o, bare);
  ASSERT_EQ(fit.trials.size(), s.truth.trials.size());
  EXPECT_EQ(fit.discrepancy.size(), fit.trials.size());
  EXPECT_TRUE(bare.discrepancy.empty());
  for (size_t k = 0; k < fit.trials.size(); ++k) {
    const fitting::Prediction& p = fit.trials[k].prediction;
    const auto& truth = s.truth.trials[k];
    SCOPED_TRACE(fit.trials[k].id);
    ASSERT_EQ(truth.id, fit.trials[k].id);
    const fitting::PredictionInterval* iv[3] = {&p.peak_force_n, &p.time_to_peak_s, &p.max_deformation_m};
    for (const auto* i : iv) {
      ASSERT_TRUE(std::isfinite(i->value) && std::isfinite(i->se) && std::isfinite(i->low) && std::isfinite(i->high));
      const double half = 0.5 * (i->high - i->low), eps = 1e-9 * std::abs(i->value);
      EXPECT_NEAR(0.5 * (i->high + i->low), i->value, eps);
      if (fit.trials[k].train) {
        EXPECT_NEAR(half, 1.959964 * i->se, eps);
      } else {
        EXPECT_GE(half, 1.959964 * i->se - eps);
        EXPECT_LE(half, 3.182446 * i->se + eps);
      }
    }
    EXPECT_GT(p.peak_force_n.se, 1e-4 * p.peak_force_n.value);
    EXPECT_LT(p.peak_force_n.se, 0.03 * p.peak_force_n.value);
    EXPECT_GT(p.time_to_peak_s.se, 1e-6);
    EXPECT_LT(p.time_to_peak_s.se, 1e-3);
    EXPECT_GT(p.max_deformation_m.se, 1e-5);
    EXPECT_LT(p.max_deformation_m.se, 3e-3);
    const fitting::Prediction& b = bare.trials[k].prediction;
    EXPECT_GE(p.peak_force_n.se, b.peak_force_n.se);
    EXPECT_GE(p.max_deformation_m.se, b.max_deformation_m.se);
    EXPECT_EQ(b.peak_force_n.value, p.peak_force_n.value);
    // The cross-validated scale only widens a held-out trial's interval
    // and leaves a training trial's as its own misfit states it.
    const fitting::Prediction& r = raw.trials[k].prediction;
    const double tol = 1.0 + 1e-12;
    EXPECT_GE(p.peak_force_n.se * tol, r.peak_force_n.se);
    EXPECT_GE(p.time_to_peak_s.se * tol, r.time_to_peak_s.se);
    EXPECT_GE(p.max_deformation_m.se * tol, r.max_deformation_m.se);
    EXPECT_NEAR(fit.discrepancy[k].peak_force_scale, p.peak_force_n.se / r.peak_force_n.se, 1e-9);
    if (fit.trials[k].train) {
      EXPECT_DOUBLE_EQ(p.peak_force_n.se, r.peak_force_n.se);
    }
    EXPECT_GE(truth.peak_force_n, p.peak_force_n.low);
    EXPECT_LE(truth.peak_force_n, p.peak_force_n.high);
    EXPECT_GE(truth.max_deformation_m, p.max_deformation_m.low);
    EXPECT_LE(truth.max_deformation_m, p.max_deformation_m.high);
    EXPECT_NEAR(p.time_to_peak_s.value, truth.time_to_peak_s, 2e-4);
    ASSERT_EQ(p.force_low_n.size(), fit.trials[k].simulation.t_s.size());
    EXPECT_TRUE(p.force_low_n.allFinite() && p.force_high_n.allFinite());
    EXPECT_TRUE((p.force_high_n.array() >= p.force_low_n.array()).all());
  }
}

}  // namespace
}  // namespace dropfit
