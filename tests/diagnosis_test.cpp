// Closing the loop on sessions with known truth: the generator injects one
// effect (or several, or one outside the library), the diagnosis must name
// exactly what was injected, with the error after at most half the error
// before, and add nothing to a purely linear control session. Plus the
// paper's real Table 1. Everything in memory.
#include "diagnosis/diagnosis.h"

#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <nlohmann/json.hpp>
#include <numbers>

#include "pipeline/pipeline.h"
#include "samples/generator/synth.h"

namespace dropfit::diagnosis {
namespace {

constexpr std::uint64_t kSeed = 3;

synth::SyntheticSession session_with(const std::vector<std::pair<std::string, double>>& effects,
                                     fitting::ModelKind model = fitting::ModelKind::Model4) {
  synth::SynthOptions o;
  o.seed = kSeed;
  o.model = model;
  for (const auto& [name, magnitude] : effects) synth::set_effect(o.effects, name, magnitude);
  return synth::make_session(o);
}

// The loop runs on the state the pipeline builds (calibration stage's
// choice, every trial, the fits' data).
DiagnosisResult diagnose(const Session& session, DiagnosisOptions options = {}) {
  return dropfit::diagnosis::diagnose(pipeline::build(session, {.upto = pipeline::Stage::Trials}), options);
}

double error(const ErrorSet& e, const std::string& key) {
  for (const auto& [k, v] : e)
    if (k == key) return v;
  ADD_FAILURE() << "no error value " << key;
  return std::numeric_limits<double>::quiet_NaN();
}

double estimate(const Effect& e, const std::string& key) { return error(e.estimate, key); }

// The injected effect is the only one named, and its error at least halves.
const Effect& expect_only(const DiagnosisResult& r, const std::string& name, const std::string& key) {
  EXPECT_EQ(r.effects.size(), 1u) << r.report();
  const Effect* e = r.find(name);
  if (!e) {
    ADD_FAILURE() << name << " not found\n" << r.report();
    static const Effect none;
    return none;
  }
  EXPECT_LE(error(e->error_after, key), 0.5 * error(e->error_before, key)) << r.report();
  EXPECT_FALSE(r.unexplained) << r.report();
  return *e;
}

TEST(Diagnosis, LinearControlSessionAddsNothing) {
  const auto s = session_with({});
  const DiagnosisResult r = diagnose(s.session);
  EXPECT_TRUE(r.effects.empty()) << r.report();
  EXPECT_FALSE(r.unexplained) << r.report();
  EXPECT_EQ(r.baseline_model, "model4");
}

TEST(Diagnosis, LensDistortion) {
  const auto s = session_with({{"lens_distortion", -0.2}});
  const DiagnosisResult r = diagnose(s.session);
  const Effect& e = expect_only(r, "lens_distortion", "check_rms_mm");
  EXPECT_EQ(e.stage, "calibration");
  // The fitted k1 of each camera, against the injected one (the DLT absorbs
  // part of it, and the fit's centre and focal differ a little from the truth).
  EXPECT_NEAR(estimate(e, "cam1_k1"), -0.2, 0.05) << r.report();
}

TEST(Diagnosis, OutlierMarker) {
  const auto s = session_with({{"outlier_marker", 60.0}});
  const DiagnosisResult r = diagnose(s.session);
  const Effect& e = expect_only(r, "outlier_marker", "check_rms_mm");
  EXPECT_EQ(e.stage, "calibration");
  double largest = 0.0;
  for (const auto& [k, v] : e.estimate)
    if (k.ends_with("_loo_error_mm")) largest = std::max(largest, v);
  EXPECT_GT(largest, 10.0) << r.report();
}

// A label slip between two fit markers far apart (the archive's session of
// seed 1107: c07 and c15 swapped in cam2, 751 px apart, the camera's fit at
// 112 px RMS). Every leave-one-out fold keeps one of the pair, so all
// markers' held-out errors are large (median 210 mm, one at 6949 mm) and
// c15 was not among those that stand out; the pair is found by exchanging
// every pair's images in each camera, and decided on the log errors (on the
// raw ones the one huge error gave t = 1.7 for a fall from 661 to 0.4 mm).
TEST(Diagnosis, AGrossLabelSwapBetweenFarMarkersIsFound) {
  synth::SynthOptions o = synth::independent_world_options(1107);
  synth::add_random_effects(o, 1107);
  const auto s = synth::make_session(o);
  const CalibrationDiagnosis d = diagnose_calibration(pipeline::calibration_markers(s.session.frame),
                                                      pipeline::camera_views(s.session.images));
  std::vector<std::string> dropped = d.dropped_markers;
  std::sort(dropped.begin(), dropped.end());
  EXPECT_EQ(dropped, (std::vector<std::string>{"c07", "c15"}));
  ASSERT_EQ(d.effects.size(), 1u);
  EXPECT_EQ(d.effects[0].name, "outlier_marker");
  EXPECT_NE(d.effects[0].evidence.find("label swap"), std::string::npos) << d.effects[0].evidence;
  // The bar: check RMS back under 1 mm (measured 0.4-0.5 mm per axis).
  EXPECT_LT(1000.0 * d.after.check_rms_m.maxCoeff(), 1.0);
  EXPECT_TRUE(d.remaining.empty());
}

TEST(Diagnosis, TimeOffset) {
  const auto s = session_with({{"time_offset", 5.0}});
  const DiagnosisResult r = diagnose(s.session);
  const Effect& e = expect_only(r, "time_offset", "offset_error_ms_max");
  EXPECT_EQ(e.stage, "sync");
  EXPECT_NEAR(estimate(e, "video_offset_ms"), 5.0, 0.5);
}

TEST(Diagnosis, BaselineDrift) {
  const auto s = session_with({{"baseline_drift", 40.0}});
  const DiagnosisResult r = diagnose(s.session);
  const Effect& e = expect_only(r, "baseline_drift", "heldout_still_rms_n");
  EXPECT_EQ(e.stage, "forceplate");
  EXPECT_NEAR(estimate(e, "drift_n_s"), 40.0, 8.0);
}

TEST(Diagnosis, ForceScale) {
  const auto s = session_with({{"force_scale", 1.06}});
  const DiagnosisResult r = diagnose(s.session);
  const Effect& e = expect_only(r, "force_scale", "impulse_error_pct_rms");
  EXPECT_EQ(e.stage, "forceplate");
  // Impulse against momentum ending in the impactor's free flight: within 0.5 %.
  EXPECT_NEAR(estimate(e, "gain"), 1.06, 0.005);
  EXPECT_NE(e.evidence.find("free flight after separation in 5 of 5"), std::string::npos) << e.evidence;
}

// The video ends 0.15 s after the trigger (digitising often stops there),
// long before the plate is still: the scale and the drift are still found,
// the scale from the free flight the video does see, the drift from the
// still parts of the 5 s force record after the video.
TEST(Diagnosis, ForceScaleAndDriftWhenTheVideoEndsEarly) {
  synth::SynthOptions o;
  o.seed = kSeed;
  o.n_frames = o.trigger_frame + 150;
  synth::set_effect(o.effects, "force_scale", 1.04);
  synth::set_effect(o.effects, "baseline_drift", 40.0);
  const auto s = synth::make_session(o);
  DiagnosisOptions opt;
  opt.mat = false;  // the plate's effects only
  const DiagnosisResult r = diagnose(s.session, opt);
  const Effect* scale = r.find("force_scale");
  ASSERT_NE(scale, nullptr) << r.report();
  EXPECT_NEAR(estimate(*scale, "gain"), 1.04, 0.005) << r.report();
  const Effect* drift = r.find("baseline_drift");
  ASSERT_NE(drift, nullptr) << r.report();
  // 40 N/s injected; the still samples after the video span seconds: 10 %.
  EXPECT_NEAR(estimate(*drift, "drift_n_s"), 40.0, 4.0) << r.report();
  EXPECT_EQ(r.effects.size(), 2u) << r.report();
}

TEST(Diagnosis, StiffnessNonlinearity) {
  const auto s = session_with({{"stiffness_nonlinearity", 4e6}});
  const DiagnosisResult r = diagnose(s.session);
  const Effect& e = expect_only(r, "stiffness_nonlinearity", "heldout_rms_force_pct_peak");
  EXPECT_EQ(e.stage, "mat");
  EXPECT_NEAR(estimate(e, "k1_cubic_n_m3"), 4e6, 1e6);
  EXPECT_LE(error(e.error_after, "heldout_peak_force_pct_max"), 0.5 * error(e.error_before, "heldout_peak_force_pct_max"));
}

TEST(Diagnosis, Hysteresis) {
  const auto s = session_with({{"hysteresis", 800.0}});
  const DiagnosisResult r = diagnose(s.session);
  const Effect& e = expect_only(r, "hysteresis", "heldout_rms_force_pct_peak");
  EXPECT_NEAR(estimate(e, "r1_unload_n_s_m"), 800.0, 160.0);
}

// The Maxwell arm shows in both channels; refitted it brings the held-out
// force from 1.3 % to 0.04 % of peak.
TEST(Diagnosis, RateDependence) {
  const auto s = session_with({{"rate_dependence", 6e5}});
  const DiagnosisResult r = diagnose(s.session);
  const Effect& e = expect_only(r, "rate_dependence", "heldout_rms_force_pct_peak");
  EXPECT_NEAR(estimate(e, "maxwell_tau_s"), 0.01, 0.005);
}

// Model 4's springs and dampers absorb a redistribution of its layer masses
// (its surface is the impactor's face, so m1's travel is never seen; see
// docs/diagnosis.md), so layer_mass is tested in the Model 3 world, where the
// top layer moves with the impactor and the masses identify.
// DISABLED (open in issue 11's note): the rewritten mat stage refits
// layer_mass here and the held-out impactor travel falls from 16.2 to 1.1
// noise SDs, but the held-out force rises from 23 to 36 noise SDs, so the
// candidate is rejected ("the other channel gets worse"). Not yet traced.
TEST(Diagnosis, DISABLED_LayerMass) {
  const auto s = session_with({{"layer_mass", -1.5}}, fitting::ModelKind::Model3);
  const auto state = pipeline::build(s.session, {.upto = pipeline::Stage::Trials});
  DiagnosisOptions o;
  o.mat_stage.fit = state.baseline_fit_options;
  o.mat_stage.fit.model = fitting::ModelKind::Model3;
  o.mat_stage_fit_set = true;
  const DiagnosisResult r = dropfit::diagnosis::diagnose(state, o);
  EXPECT_EQ(r.baseline_model, "model3");
  const Effect& e = expect_only(r, "layer_mass", "heldout_rms_force_pct_peak");
  EXPECT_NEAR(estimate(e, "m1_kg"), 2.44 - 1.5, 0.1) << r.report();
  EXPECT_NEAR(estimate(e, "m1_kg") + estimate(e, "m2_kg"), 6.1, 1e-9);
}

TEST(Diagnosis, SeveralEffectsAtOnce) {
  const auto s = session_with({{"lens_distortion", -0.2}, {"baseline_drift", 40.0}, {"stiffness_nonlinearity", 4e6}});
  const DiagnosisResult r = diagnose(s.session);
  EXPECT_EQ(r.effects.size(), 3u) << r.report();
  for (const char* name : {"lens_distortion", "baseline_drift", "stiffness_nonlinearity"}) {
    const Effect* e = r.find(name);
    ASSERT_NE(e, nullptr) << name << "\n" << r.report();
  }
  EXPECT_FALSE(r.unexplained) << r.report();
}

// A force-plate frame ringing after the impact (Models-and-methods: "a force
// plate mounted under an elastic surface can show spurious low-frequency
// oscillation of its own frame"): not in the library.
TEST(Diagnosis, EffectOutsideTheLibraryIsLeftUnexplained) {
  auto s = session_with({});
  const double f_hz = 28.0, amp_n = 250.0, decay_s = 0.15;
  for (std::size_t i = 0; i < s.session.trials.size(); ++i) {
    ForceRecord& rec = s.session.trials[i].force;
    const double tc = s.truth.trials[i].contact_time_s;
    for (Eigen::Index k = 0; k < rec.t_s.size(); ++k) {
      const double t = rec.t_s(k) - tc;
      if (t <= 0.0) continue;
      const double ring = amp_n * std::exp(-t / decay_s) * std::sin(2.0 * std::numbers::pi * f_hz * t);
      for (int c = 4; c < 8; ++c) rec.data(k, c) += ring / 4.0;  // Fz1..Fz4
    }
  }
  const DiagnosisResult r = diagnose(s.session);
  EXPECT_TRUE(r.effects.empty()) << r.report();
  EXPECT_TRUE(r.unexplained) << r.report();
}

// A mat whose stiffness changes from trial to trial (not with velocity): each
// trial made with its own k1, spliced into one session.
TEST(Diagnosis, StiffnessThatDependsOnTheTrialNumberIsLeftUnexplained) {
  const std::vector<double> k1_factor{1.0, 1.25, 0.85, 1.2, 0.9};
  synth::SynthOptions base;
  base.seed = kSeed;
  auto s = synth::make_session(base);
  for (std::size_t i = 0; i < k1_factor.size(); ++i) {
    synth::SynthOptions o = base;
    o.impact_velocities_m_s = {base.impact_velocities_m_s[i]};
    o.use_default_params = false;
    o.params = synth::default_mat_params(fitting::ModelKind::Model4, o.layers);
    o.params.k1_n_m *= k1_factor[i];
    TrialRecording one = synth::make_session(o).session.trials.front();
    one.spec = s.session.trials[i].spec;
    s.session.trials[i] = std::move(one);
  }
  const DiagnosisResult r = diagnose(s.session);
  EXPECT_TRUE(r.effects.empty()) << r.report();
  EXPECT_TRUE(r.unexplained) << r.report();
}

// Three fit markers mislabelled in one camera: more than the calibration
// stage may drop (two), so its residual stays unexplained, and the later
// stages are not assessed on a calibration it called bad (the injected
// clock offset is then not named from it).
TEST(Diagnosis, UnresolvedCalibrationLeavesLaterStagesNotAssessed) {
  auto s = session_with({{"time_offset", 5.0}});
  int moved = 0;
  for (auto& o : s.session.images[0].observations) {
    for (const auto& m : s.session.frame)
      if (m.id == o.id && m.role == MarkerRole::Fit && moved < 3) {
        o.image_px.x() += 40.0 + 25.0 * moved;  // gross, and different for each
        ++moved;
        break;
      }
  }
  ASSERT_EQ(moved, 3);
  const DiagnosisResult r = diagnose(s.session);
  EXPECT_TRUE(r.unexplained) << r.report();
  EXPECT_EQ(r.not_assessed, (std::vector<std::string>{"sync", "forceplate", "mat"})) << r.report();
  for (const auto& e : r.effects) EXPECT_EQ(e.stage, "calibration") << r.report();
  const auto j = nlohmann::json::parse(diagnosis_json(r));
  EXPECT_EQ(j.at("not_assessed").size(), 3u);
}

TEST(Diagnosis, PaperTable1StiffeningFromPeakForces) {
  // samples/paper/table1.csv (Mills, Pain & Yeadon 2006, Table 1).
  const std::vector<fitting::TableTrial> table{{"1", 4.30, 0.088, 5593},
                                               {"2", 4.80, 0.099, 6341},
                                               {"3", 5.25, 0.100, 7054},
                                               {"4", 5.75, 0.113, 8398},
                                               {"5", 6.50, 0.118, 9597}};
  const TableDiagnosis t = diagnose_table(table);
  ASSERT_EQ(t.effects.size(), 1u);
  const Effect& e = t.effects.front();
  EXPECT_EQ(e.name, "stiffness_nonlinearity");
  // The linear model over-predicts the slowest trial and under-predicts the
  // fastest (the paper's Model 1: +3.5 % and -9.1 %).
  EXPECT_GT(t.heldout_pct_before(0), 0.0);
  EXPECT_LT(t.heldout_pct_before(4), -5.0);
  // With stiffening every held-out trial is within 4 % (3.5 % measured, on
  // trial 1; the aim of 3 % is not reached: trial 4 lies 4 % above
  // the chord of its neighbours, which no smooth stiffening curve follows),
  // and the worst trial's error falls to at most half.
  EXPECT_LE(t.heldout_pct_after.cwiseAbs().maxCoeff(), 4.0) << t.heldout_pct_after.transpose();
  EXPECT_LE(t.heldout_pct_after.cwiseAbs().maxCoeff(), 0.5 * t.heldout_pct_before.cwiseAbs().maxCoeff());
  EXPECT_GT(e.estimate.back().second, 0.0);
}

// The independent world (its own integrator, random plausible mat, dish
// markers, corner base markers, gaps) with the effects given and nothing else.
synth::SyntheticSession independent_with(std::uint64_t seed,
                                         const std::vector<std::pair<std::string, double>>& effects) {
  synth::SynthOptions o = synth::independent_world_options(seed);
  for (const auto& [name, magnitude] : effects) synth::set_effect(o.effects, name, magnitude);
  return synth::make_session(o);
}

std::vector<std::string> names_of(const DiagnosisResult& r) {
  std::vector<std::string> n;
  for (const auto& e : r.effects) n.push_back(e.name);
  std::sort(n.begin(), n.end());
  return n;
}

// Stiffening and a lower unloading stiffness together: alone, the
// stiffening refit does not bring the held-out error down beyond noise and
// the unloading one trades force for travel (the other channel gets
// worse), so forward selection over single effects named nothing. Refitted
// as a pair they explain both channels, and each beats its member alone.
TEST(Diagnosis, TwoMatEffectsThatNeitherPassesAlone) {
  const double cubic = 2.05e6, h = 0.26;
  const auto s = independent_with(511, {{"stiffness_nonlinearity", cubic}, {"hysteresis_elastic", h}});
  const DiagnosisResult r = diagnose(s.session);
  EXPECT_EQ(names_of(r), (std::vector<std::string>{"hysteresis", "stiffness_nonlinearity"})) << r.report();
  EXPECT_FALSE(r.unexplained) << r.report();
  for (const auto& e : r.effects) {
    // The bar for mat effects: held-out error after at most a third
    // of before, on both channels.
    EXPECT_LE(error(e.error_after, "heldout_force_rms_noise_sd"),
              error(e.error_before, "heldout_force_rms_noise_sd") / 3.0)
        << r.report();
    EXPECT_LE(error(e.error_after, "heldout_impactor_rms_noise_sd"),
              error(e.error_before, "heldout_impactor_rms_noise_sd") / 3.0)
        << r.report();
  }
  // Parameters against the truth: 3 % on the cubic term and 0.02 on h
  // (measured 0.2 % and 0.001 here; the tolerance is what a one-trial fit
  // at 1.5 N noise per channel is expected to hold on other seeds).
  const Effect* st = r.find("stiffness_nonlinearity");
  const Effect* hy = r.find("hysteresis");
  ASSERT_TRUE(st && hy) << r.report();
  EXPECT_NEAR(estimate(*st, "k1_cubic_n_m3"), cubic, 0.03 * cubic) << r.report();
  EXPECT_NEAR(estimate(*hy, "k1_unload_ratio"), h, 0.02) << r.report();
}

// Lens distortion alone: once the calibration stage has fitted k1, the face
// still reads about 1 mm low at the mat top (k1 is known to a few percent);
// measured from the surface markers' rest height (same cameras, same error)
// the travel carries no offset, and no mat effect is named to absorb one
// (before, a false "hysteresis" was).
TEST(Diagnosis, LensDistortionNamesNoMatEffect) {
  const auto s = independent_with(609, {{"lens_distortion_px", 1.2}});
  const DiagnosisResult r = diagnose(s.session);
  EXPECT_EQ(names_of(r), (std::vector<std::string>{"lens_distortion"})) << r.report();
  EXPECT_FALSE(r.unexplained) << r.report();
}

// Two sessions of an archive made after the loop's design was fixed
// (scripts/make-archive 20 DIR --seed 700: sessions s002 and s003, the
// independent world). s002 is a clean linear mat whose two lower layers are
// about equally stiff (k2 0.98e6, k3 0.93e6 N/m): the fitter's starts all
// had distinct springs and every run stopped with a damping on its floor,
// 16 noise SDs off, so the loop called the control unexplained. s003 has
// baseline drift and a force scale only: the effect-free multi-start stuck
// (cost 26 400) while a candidate's refit found the basin, and the loop
// named a false hysteresis for it.
synth::SyntheticSession independent_session(std::uint64_t seed) {
  synth::SynthOptions o = synth::independent_world_options(seed);
  synth::add_random_effects(o, o.seed);
  return synth::make_session(o);
}

// The names of effects (injected or named), sorted.
template <typename E>
std::vector<std::string> sorted_names(const std::vector<E>& effects) {
  std::vector<std::string> names;
  for (const auto& e : effects) names.push_back(e.name);
  std::sort(names.begin(), names.end());
  return names;
}

// The loop on an independent session: exactly the injected effects named,
// and nothing left unexplained.
DiagnosisResult diagnose_expecting_truth(const synth::SyntheticSession& s) {
  DiagnosisResult r = diagnose(s.session);
  EXPECT_EQ(sorted_names(r.effects), sorted_names(s.truth.effects)) << r.report();
  EXPECT_FALSE(r.unexplained) << r.report();
  return r;
}

TEST(Diagnosis, CleanMatWithEqualLowerLayersIsFittedToTheNoise) {
  const auto s = independent_session(701);
  ASSERT_TRUE(s.truth.effects.empty());
  diagnose_expecting_truth(s);
}

TEST(Diagnosis, AStuckBaselineIsNotCreditedToAnEffect) {
  const auto s = independent_session(702);
  const std::vector<std::string> truth = sorted_names(s.truth.effects);
  ASSERT_EQ(truth, (std::vector<std::string>{"baseline_drift", "force_scale"}));
  diagnose_expecting_truth(s);
}

// Session s012 of the same archive (seed 711): a clean mat, and lens
// distortion (k1 -0.65, 1.3 px at the farthest trial marker) that the
// calibration stage corrects. The corrected cameras still read the mat
// 1.5 mm low; measured from the surveyed mat top the face arrived 0.29 ms
// early, the travel residual followed the face's velocity (1 mm), and the
// mat stage named a hysteresis and left the rest unexplained. Measured
// from the surface markers' rest height (trial.h: contact height) it is
// gone.
TEST(Diagnosis, LensDistortionLeavesNoTravelResidualForTheMat) {
  const auto s = independent_session(711);
  const std::vector<std::string> truth = sorted_names(s.truth.effects);
  ASSERT_EQ(truth, (std::vector<std::string>{"lens_distortion"}));
  diagnose_expecting_truth(s);
}

// Session s016 of the same archive (seed 715): stiffening and a weak
// Maxwell arm (27 kN/m, tau 28 ms, beside k1 80 kN/m). The arm's stiffness
// had the series springs' floor (0.3 k_eff, 32 kN/m here), so its refit
// ended on the bound and the arm was not named.
TEST(Diagnosis, AWeakMaxwellArmBesideStiffeningIsNamed) {
  const auto s = independent_session(715);
  const std::vector<std::string> truth = sorted_names(s.truth.effects);
  ASSERT_EQ(truth, (std::vector<std::string>{"rate_dependence", "stiffness_nonlinearity"}));
  const DiagnosisResult r = diagnose_expecting_truth(s);
  const Effect* arm = r.find("rate_dependence");
  ASSERT_NE(arm, nullptr);
  // Within 15 % of the true arm (27 097 N/m, 28.4 ms).
  EXPECT_NEAR(estimate(*arm, "maxwell_k_n_m") / 27097.1, 1.0, 0.15) << r.report();
  EXPECT_NEAR(estimate(*arm, "maxwell_tau_s") / 0.0284, 1.0, 0.15) << r.report();
}

// Session s008 of a second archive made after the design was fixed
// (scripts/make-archive 20 DIR --seed 800: seed 807): stiffening and a
// Maxwell arm beside drift, a force scale and a swapped marker. The first
// round named an unloading damping that stood in for both (held-out force
// 73 -> 52 noise SDs); the pair found next explained everything (1.8), and
// the damping stayed named until the selection got its backward step.
TEST(Diagnosis, AnEffectMadeRedundantByLaterOnesIsTakenOut) {
  const auto s = independent_session(807);
  const DiagnosisResult r = diagnose_expecting_truth(s);
  EXPECT_EQ(r.find("hysteresis"), nullptr) << r.report();
}

TEST(DiagnosisJson, MapsOntoTheSpec) {
  DiagnosisResult r;
  r.baseline_model = "model4";
  r.effects.push_back({"mat", "stiffness_nonlinearity", "residual correlates with deformation cubed (r = 0.93)",
                       {{"rms_force_pct_peak", 9.8}, {"heldout_peak_force_pct_max", 9.6}},
                       {{"rms_force_pct_peak", 2.1}, {"heldout_peak_force_pct_max", std::nan("")}},
                       {{"k1_cubic_n_m3", 4e6}}});
  r.unexplained = false;
  const auto j = nlohmann::json::parse(diagnosis_json(r));
  EXPECT_EQ(j["baseline_model"], "model4");
  ASSERT_EQ(j["effects"].size(), 1u);
  EXPECT_EQ(j["effects"][0]["stage"], "mat");
  EXPECT_EQ(j["effects"][0]["name"], "stiffness_nonlinearity");
  EXPECT_DOUBLE_EQ(j["effects"][0]["error_before"]["rms_force_pct_peak"].get<double>(), 9.8);
  EXPECT_DOUBLE_EQ(j["effects"][0]["error_after"]["rms_force_pct_peak"].get<double>(), 2.1);
  EXPECT_TRUE(j["effects"][0]["error_after"]["heldout_peak_force_pct_max"].is_null());
  EXPECT_EQ(j["unexplained"], false);
}

}  // namespace
}  // namespace dropfit::diagnosis

namespace dropfit::diagnosis {
namespace {

// The trajectory estimate's bias (diagnosis.h) on the model's own impact.
TEST(TrajectoryEstimateBias, MatInertiaAndThePlatesGainReadAsClockOffset) {
  using fitting::ModelKind;
  const fitting::MatParams table2 = fitting::paper_table2(ModelKind::Model4);
  // A massless mat: the plate reads the impactor's force, nothing to correct.
  const double massless_s = trajectory_estimate_bias_s(ModelKind::Model1, fitting::paper_table2(ModelKind::Model1),
                                                       5.0, 24.0, 9.81);
  // The paper's layered mat (2.44 + 3.66 kg): its inertia delays the plate force.
  const double layered_s = trajectory_estimate_bias_s(ModelKind::Model4, table2, 5.0, 24.0, 9.81);
  // The same with a plate reading 3 % high, and with a 7 N/s drift from contact.
  PlateCorrection gain;
  gain.gain = 1.03;
  const double gained_s = trajectory_estimate_bias_s(ModelKind::Model4, table2, 5.0, 24.0, 9.81, gain);
  PlateCorrection drift;
  drift.drift = drift.drift_from_contact = true;
  drift.drift_n_s = 7.0;
  const double drifted_s = trajectory_estimate_bias_s(ModelKind::Model4, table2, 5.0, 24.0, 9.81, drift, 0.5);
  std::printf("bias: massless %.3f ms, layered %.3f ms, gain 1.03 %.3f ms, drift 7 N/s %.3f ms\n", 1e3 * massless_s,
              1e3 * layered_s, 1e3 * gained_s, 1e3 * drifted_s);
  EXPECT_NEAR(massless_s, 0.0, 0.01e-3);
  EXPECT_LT(layered_s, -0.05e-3);
  EXPECT_GT(layered_s, -1.0e-3);
  EXPECT_GT(std::abs(gained_s - layered_s), 0.05e-3);
  EXPECT_TRUE(std::isnan(trajectory_estimate_bias_s(ModelKind::Model4, table2, -1.0, 24.0, 9.81)));
}

}  // namespace
}  // namespace dropfit::diagnosis
