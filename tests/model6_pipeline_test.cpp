// Model 6 (the foam column) as the pipeline's candidate final model, on
// sessions of worlds that share no code with dropfit, against their truth:
//   - ../shared/validation-continuum c1, c2 and c6 (foam columns; c6 with a
//     baseline drift and a second landing): the loop's lumped final model
//     stays above the noise, Model 6 is fitted and chosen by held-out
//     prediction; every held-out trial's peak force and maximum face travel,
//     and every trial's clock offset (from the contacts Model 6 places),
//     against the truth; no time_offset named (there is none); fit.json
//     says model6 and why there is no MJCF. Asserted: held-out peaks
//     within 1.5 %, travel within 1 mm, offsets within 0.1 ms (truth 0;
//     docs/validation.md has the measured errors);
//   - ../shared/validation v1 and v2 (lumped chains): the loop's model
//     reaches the noise, so Model 6 is not fitted at all.
// Read in place, skipped without ../shared, failing under CI=true
// (tests/support/shared_data.h).
#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include <algorithm>
#include <atomic>
#include <cstdio>
#include <fstream>
#include <string>

#include "core/error.h"
#include "pipeline/model6_stage.h"
#include "pipeline/outputs.h"
#include "pipeline/pipeline.h"
#include "report/output.h"
#include "samples/generator/synth.h"
#include "support/shared_data.h"

namespace dropfit {
namespace {

using json = nlohmann::json;
namespace fs = std::filesystem;
using testsupport::shared_path;

struct Tolerance {
  double peak = 0.015;       // held-out peak force, relative
  double travel_m = 1.0e-3;  // held-out maximum face travel
  double offset_s = 0.1e-3;  // every trial's clock offset
};

// Every trial as Model 6 predicted it: simulated peak force and maximum face
// travel within the contact window.
void check_model6_final(const fs::path& dir, const Tolerance& tol) {
  DROPFIT_NEED_SHARED(dir);
  const pipeline::SessionState state = pipeline::build((dir / "session").string());
  std::ifstream in(dir / "truth.json");
  const json truth = json::parse(in);
  ASSERT_EQ(state.final_label(), "model6") << (state.model6 ? state.model6->reason : "Model 6 not fitted");
  const fitting::Model6FitResult& fit = *state.final_model6();
  std::printf("%s\n", state.model6->reason.c_str());
  for (const auto& t : truth["trials"]) {
    const std::string id = t["id"];
    SCOPED_TRACE(id);
    const auto rep = std::find_if(fit.trials.begin(), fit.trials.end(), [&](const auto& r) { return r.id == id; });
    ASSERT_NE(rep, fit.trials.end());
    double peak = 0.0, travel = 0.0;
    for (Eigen::Index i = 0; i < rep->simulation.t_s.size() && rep->simulation.t_s[i] <= rep->window_end_s; ++i) {
      peak = std::max(peak, rep->simulation.grf_n[i]);
      if (rep->simulation.t_s[i] >= 0.0) travel = std::max(travel, rep->simulation.impactor_m[i]);
    }
    const double peak_err = peak / t["peak_force_n"].get<double>() - 1.0;
    const double travel_err = travel - t["max_deformation_m"].get<double>();
    const auto st = std::find_if(state.trials.begin(), state.trials.end(),
                                 [&](const auto& s) { return s.result.id == id; });
    ASSERT_NE(st, state.trials.end());
    const double offset_err = st->result.video_offset_s - t["video_offset_s"].get<double>();
    std::printf("%s%s: peak %+.2f %%, travel %+.2f mm, offset %+.3f ms (SE %.3f ms; onset estimate %+.3f ms)\n",
                id.c_str(), rep->train ? " (train)" : "", 100.0 * peak_err, 1e3 * travel_err, 1e3 * offset_err,
                1e3 * st->result.video_offset_se_s, 1e3 * st->result.video_offset_onset_s);
    if (!rep->train) {
      EXPECT_LT(std::abs(peak_err), tol.peak);
      EXPECT_LT(std::abs(travel_err), tol.travel_m);
    }
    EXPECT_LT(std::abs(offset_err), tol.offset_s);
    // The interval the offset carries is finite and not wider than a frame.
    EXPECT_TRUE(std::isfinite(st->result.video_offset_se_s));
    EXPECT_LT(st->result.video_offset_se_s, 1e-3);
  }
  ASSERT_TRUE(state.loop);
  EXPECT_EQ(state.loop->find("time_offset"), nullptr) << "a clock offset named on a session without one";

  // The canonical fit.json is Model 6's, with why it has no MJCF; fits/model6/ beside it.
  report::OutputSet out;
  pipeline::add_run_outputs(out, state);
  const auto file = [&](const std::string& name) -> const std::string* {
    const auto it = out.files().find(name);
    return it == out.files().end() ? nullptr : &it->second;
  };
  ASSERT_NE(file("fit.json"), nullptr);
  ASSERT_NE(file("fits/model6/fit.json"), nullptr);
  EXPECT_EQ(file("mat.mjcf.xml"), nullptr);
  const json fj = json::parse(*file("fit.json"));
  EXPECT_EQ(fj["model"], "model6");
  EXPECT_EQ(fj["label"], "model6");
  EXPECT_TRUE(fj["mjcf"].is_null());
  EXPECT_NE(fj["mjcf_note"].get<std::string>().find("no MJCF"), std::string::npos);
  EXPECT_EQ(fj["estimates"].size(), 14u);  // c1, c2, c6 fit near the noise with the exponent held at 2
  EXPECT_TRUE(fj["choice"]["chosen"].get<bool>());

  // The held-out residual mapped for both candidates (the lumped final model
  // first, Model 6 second) in diagnosis.json and the report: on a foam the
  // lumped model's residual has a form (one state explains at least the
  // map's 30 % share), never "none".
  ASSERT_NE(file("diagnosis.json"), nullptr);
  const json dj = json::parse(*file("diagnosis.json"));
  ASSERT_EQ(dj["residual_maps"].size(), 2u);
  EXPECT_EQ(dj["residual_maps"][1]["model"], "model6");
  const json& lumped = dj["residual_maps"][0];
  EXPECT_NE(lumped["form"], "none") << lumped["proposal"];
  double best_r2 = 0.0;
  for (const auto& a : lumped["axes"])
    if (a["name"] != "recording_order") best_r2 = std::max(best_r2, a["r2"].get<double>());
  EXPECT_GE(best_r2, 0.3);
  const std::string& html = *file("report.html");
  EXPECT_NE(html.find("The held-out residual's form"), std::string::npos);
  EXPECT_NE(html.find("Held-out residual against deflection (mm)"), std::string::npos);
  EXPECT_NE(html.find("Held-out residual against time since contact (ms)"), std::string::npos);

  // Each trial's strain reach in the fitted column; a held-out trial that
  // drives a foam beyond the training trial's reach is a warning in fit.json
  // and in the report.
  ASSERT_EQ(fj["strain_reach"].size(), state.model6->fit->trials.size());
  for (const auto& r : fj["strain_reach"]) {
    EXPECT_GT(r["max_top_strain"].get<double>(), 0.3);
    EXPECT_LT(r["max_top_strain"].get<double>(), 0.95);
    if (!r["extrapolated"].get<bool>()) continue;
    EXPECT_FALSE(r["train"].get<bool>());
    const std::string head = r["id"].get<std::string>() + " drives the";
    bool warned = false;
    for (const auto& w : fj["warnings"]) warned = warned || w.get<std::string>().find(head) != std::string::npos;
    EXPECT_TRUE(warned) << head;
    EXPECT_NE(html.find(head), std::string::npos) << head;
  }
}

void check_not_triggered(const fs::path& dir) {
  DROPFIT_NEED_SHARED(dir);
  const pipeline::SessionState state = pipeline::build((dir / "session").string());
  EXPECT_FALSE(state.model6.has_value()) << state.model6->reason;
  EXPECT_NE(state.final_label(), "model6");
}

// Model 6 fitted early beside the loop (pipeline/model6_stage.h: EarlyModel6)
// is taken only on exactly the inputs the fit after the loop would use, and
// is then that fit to the last bit; on other inputs it is cancelled and not
// taken; a cancelled fit throws instead of returning.
// Model 6's training trial: the fastest accepted trial while two or more
// trials stay held out by both models; with three accepted trials and the
// rival trained on the middle one, the rival's (the paired choice would
// have one trial).
TEST(Model6Pipeline, TrainsOnTheDeepestImpactWhenTwoTrialsArePaired) {
  auto trials = [](std::vector<double> v) {
    std::vector<fitting::TrialData> out;
    for (size_t i = 0; i < v.size(); ++i) {
      out.emplace_back();
      out.back().id = "trial" + std::to_string(i + 1);
      out.back().impact_velocity_m_s = v[i];
    }
    return out;
  };
  using Ids = std::vector<std::string>;
  EXPECT_EQ(pipeline::model6_train_ids(trials({4.3, 6.5, 5.25, 4.8, 5.75}), {"trial3"}), Ids{"trial2"});
  EXPECT_EQ(pipeline::model6_train_ids(trials({4.3, 4.8, 5.25, 5.75}), {"trial2"}), Ids{"trial4"});
  EXPECT_EQ(pipeline::model6_train_ids(trials({4.3, 4.8, 5.25}), {"trial2"}), Ids{"trial2"});
  EXPECT_EQ(pipeline::model6_train_ids(trials({4.3, 4.8, 5.25}), {"trial3"}), Ids{"trial3"});
  EXPECT_TRUE(pipeline::model6_train_ids({}, {"trial3"}).empty());
}

TEST(Model6Pipeline, EarlyFitIsTheFitAfterTheLoopOrNone) {
  const fs::path dir = shared_path("validation-continuum") / "c1-foam";
  DROPFIT_NEED_SHARED(dir);
  pipeline::BuildOptions bo;
  bo.upto = pipeline::Stage::Trials;
  const pipeline::SessionState state = pipeline::build((dir / "session").string(), bo);
  std::vector<fitting::TrialData> data;
  for (const auto& d : state.fit_data)
    if (d.accepted) data.push_back(d);
  ASSERT_GE(data.size(), 3u);
  fitting::Model6FitOptions options = pipeline::model6_options(state.session.manifest);
  options.train_ids = {data[1].id};

  const fitting::Model6FitResult direct = fitting::fit_model6(data, options);
  pipeline::EarlyModel6 early;
  early.start(data, options);
  const std::optional<fitting::Model6FitResult> taken = early.take(data, options);
  ASSERT_TRUE(taken.has_value());
  EXPECT_EQ(taken->cost, direct.cost);
  ASSERT_EQ(taken->estimates.size(), direct.estimates.size());
  for (std::size_t i = 0; i < direct.estimates.size(); ++i) {
    EXPECT_EQ(taken->estimates[i].value, direct.estimates[i].value) << direct.estimates[i].name;
    EXPECT_EQ(taken->estimates[i].se, direct.estimates[i].se) << direct.estimates[i].name;
  }
  ASSERT_EQ(taken->trials.size(), direct.trials.size());
  for (std::size_t k = 0; k < direct.trials.size(); ++k)
    EXPECT_EQ(taken->trials[k].contact_shift_s, direct.trials[k].contact_shift_s) << direct.trials[k].id;

  // Another training trial, or one force sample changed: not taken.
  early.start(data, options);
  fitting::Model6FitOptions other = options;
  other.train_ids = {data[2].id};
  EXPECT_FALSE(early.take(data, other).has_value());
  early.start(data, options);
  std::vector<fitting::TrialData> changed = data;
  changed[0].grf_n[changed[0].grf_n.size() / 2] += 1e-9;
  EXPECT_FALSE(early.take(changed, options).has_value());

  std::atomic<bool> cancel{true};
  options.cancel = &cancel;
  EXPECT_THROW(fitting::fit_model6(data, options), Error);
}

// Generator foam-world sessions nobody tuned on, where the loop's lumped
// model stays far above the noise and Model 6 predicts every held-out trial
// better, yet the test on the drops of both channels in one number fails:
// Model 6 must be final (on the combined number alone Model 4 stays final,
// 15-28 % off).
// Asserted: Model 6 final, the drops' t below 2, every held-out peak within
// peak_tol of the truth and travel within 1 mm; each test: what decided.
diagnosis::HeldOutChoice check_generator_choice(std::uint64_t seed, double peak_tol) {
  const synth::SyntheticSession syn = synth::make_session(synth::foam_world_options(seed));
  const pipeline::SessionState state = pipeline::build(syn.session);
  if (!state.model6 || !state.model6->choice) {
    ADD_FAILURE() << "Model 6 not fitted";
    return {};
  }
  const diagnosis::HeldOutChoice& choice = *state.model6->choice;
  EXPECT_LT(choice.t, 2.0) << state.model6->reason;
  if (state.loop) EXPECT_EQ(state.loop->find("mat_change_between_trials"), nullptr);
  if (state.final_label() != "model6") {
    ADD_FAILURE() << "final model " << state.final_label() << ": " << state.model6->reason;
    return choice;
  }
  const fitting::Model6FitResult& fit = *state.final_model6();
  int held_out = 0;
  for (const auto& t : syn.truth.trials) {
    SCOPED_TRACE(t.id);
    const auto rep = std::find_if(fit.trials.begin(), fit.trials.end(), [&](const auto& r) { return r.id == t.id; });
    if (rep == fit.trials.end()) {
      ADD_FAILURE() << "not predicted";
      continue;
    }
    if (rep->train) continue;
    ++held_out;
    EXPECT_LT(std::abs(rep->prediction.peak_force_n.value / t.peak_force_n - 1.0), peak_tol);
    EXPECT_LT(std::abs(rep->prediction.max_deformation_m.value - t.max_deformation_m), 1e-3);
  }
  EXPECT_EQ(held_out, 4);
  return choice;
}

// Seed 2471: the column cuts each of the three paired trials' error 10-40
// fold, but one trial carries most of the lumped model's error (the drops'
// t 1.7); on the errors' logarithms t = 5.7. Measured: held-out peaks
// within 0.27 %, travel 0.21 mm (Model 4: 15.4 %).
TEST(Model6Pipeline, GeneratorFoamChosenOnTheErrorRatios) {
  EXPECT_GE(check_generator_choice(2471, 0.02).t_log, 2.0);
}

// Seed 2485: force 315 -> 62 noise SDs with per-trial ratios 1.2-4.7 (both
// channels in one number: t = 1.5, on the logarithms 1.9), travel 44 -> 2.9
// noise SDs, cut 8-16 fold in every trial (on the logarithms t = 10.3).
// Measured: held-out peaks within 2.72 %, travel 0.34 mm (Model 4: 27.6 %).
TEST(Model6Pipeline, GeneratorFoamChosenOnTheTravelAlone) {
  const diagnosis::HeldOutChoice c = check_generator_choice(2485, 0.03);
  EXPECT_LT(c.t_log, 2.0);
  EXPECT_NE(c.evidence.find("impactor travel alone"), std::string::npos) << c.evidence;
}

// A foam losing 3 % of its stiffness per trial, recorded out of speed order
// (seed 2510: 5.61, 5.51, 4.48, 4.52, 5.98 m/s): the loop's test on the
// lumped model reads that model's misfit with speed (scales 1.13-1.92,
// +3.0 +- 1.3 % per trial, not named), so the change is judged again on
// Model 6 before the held-out choice, each trial's scale the factor on
// every foam stress that matches its largest travel. Asserted: mat_change_between_trials named with a rate
// within 0.5 % of -3 % per trial (measured -2.8 +- 0.2 %), the held-out
// trials predicted with their trend scales (their peaks within 2.5 % of the
// truth, measured 0.1-2.1 %; 2.7 % unscaled) and every clock offset within
// 0.3 ms (each placed by the column at the trial's own scale: measured
// 0.03-0.27 ms; 0.83 ms unscaled). The clean foams of the two tests above
// name no change.
TEST(Model6Pipeline, GeneratorFoamSofteningIsJudgedOnModel6) {
  synth::SynthOptions o = synth::foam_world_options(2510);
  o.faults.softening_per_trial = 0.03;
  const synth::SyntheticSession syn = synth::make_session(o);
  const pipeline::SessionState state = pipeline::build(syn.session);
  ASSERT_EQ(state.final_label(), "model6") << (state.model6 ? state.model6->reason : "");
  ASSERT_TRUE(state.loop);
  const diagnosis::Effect* e = state.loop->find("mat_change_between_trials");
  ASSERT_NE(e, nullptr) << state.loop->report();
  double rate = std::numeric_limits<double>::quiet_NaN();
  for (const auto& [k, v] : e->estimate)
    if (k == "rate_per_trial") rate = v;
  EXPECT_NEAR(rate, -0.03, 0.005) << e->evidence;
  const fitting::Model6FitResult& fit = *state.final_model6();
  for (const auto& t : syn.truth.trials) {
    SCOPED_TRACE(t.id);
    const auto rep = std::find_if(fit.trials.begin(), fit.trials.end(), [&](const auto& r) { return r.id == t.id; });
    ASSERT_NE(rep, fit.trials.end());
    if (!rep->train) EXPECT_LT(std::abs(rep->simulated.peak_force_n / t.peak_force_n - 1.0), 0.025);
    const auto st = std::find_if(state.trials.begin(), state.trials.end(),
                                 [&](const auto& s) { return s.result.id == t.id; });
    ASSERT_NE(st, state.trials.end());
    EXPECT_LT(std::abs(st->result.video_offset_s - t.video_offset_s), 3e-4);
  }
}

TEST(Model6Pipeline, ContinuumC1FinalModelIsModel6) {
  check_model6_final(shared_path("validation-continuum") / "c1-foam", {});
}
TEST(Model6Pipeline, ContinuumC2FinalModelIsModel6) {
  check_model6_final(shared_path("validation-continuum") / "c2-foam", {});
}
TEST(Model6Pipeline, ContinuumC6DriftSecondImpactFinalModelIsModel6) {
  check_model6_final(shared_path("validation-continuum") / "c6-second-impact-drift", {});
}
TEST(Model6Pipeline, LumpedChainV1NotTriggered) { check_not_triggered(shared_path("validation") / "v1-realistic"); }
TEST(Model6Pipeline, LumpedChainV2NotTriggered) { check_not_triggered(shared_path("validation") / "v2-linear-control"); }

}  // namespace
}  // namespace dropfit
