// The diagnosis stages on the independent validation sessions
// (../shared/validation, see its README): what each must name and what it
// must not. Skipped when ../shared is absent.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <nlohmann/json.hpp>
#include <numbers>

#include "capture/io.h"
#include "pipeline/pipeline.h"
#include "pipeline/wiring.h"
#include "diagnosis/diagnosis.h"
#include "support/shared_data.h"

namespace dropfit::diagnosis {
namespace {

std::string validation(const std::string& name) {
  return (testsupport::shared_path("validation") / name / "session").string();
}

CalibrationDiagnosis calibration_of(const std::string& name) {
  const Session s = capture::read_session(validation(name));
  return diagnose_calibration(pipeline::calibration_markers(s.frame), pipeline::camera_views(s.images));
}

bool named(const std::vector<Effect>& effects, const std::string& name) {
  for (const auto& e : effects)
    if (e.name == name) return true;
  return false;
}

std::string report(const CalibrationDiagnosis& d) {
  DiagnosisResult r;
  append(r, d);
  return r.report();
}

TEST(ValidationCalibration, CleanSessionsNameNothing) {
  for (const std::string name : {"v1-realistic", "v2-linear-control", "v3-hysteresis", "v4-rate",
                                 "v6-formats-drift-scale"}) {
    DROPFIT_NEED_SHARED(validation(name));
    const CalibrationDiagnosis d = calibration_of(name);
    EXPECT_TRUE(d.effects.empty()) << name << "\n" << report(d);
    EXPECT_TRUE(d.remaining.empty()) << name << "\n" << report(d);
  }
}

TEST(ValidationCalibration, SwappedPairAndLensDistortion) {
  DROPFIT_NEED_SHARED(validation("v5-outlier-lens-offset"));
  const CalibrationDiagnosis d = calibration_of("v5-outlier-lens-offset");
  std::cerr << report(d);
  EXPECT_TRUE(named(d.effects, "outlier_marker")) << report(d);
  EXPECT_TRUE(named(d.effects, "lens_distortion")) << report(d);
  EXPECT_TRUE(d.remaining.empty()) << report(d);
}

}  // namespace
}  // namespace dropfit::diagnosis

namespace dropfit::diagnosis {
namespace {

// Calibration, sync and force plate on the pipeline's state (the mat stage
// is the lead's, tested elsewhere): exactly the session's injected effects
// of those stages.
std::vector<std::string> upstream_effects(const std::string& name, DiagnosisResult* out = nullptr) {
  const Session s = capture::read_session(validation(name));
  const auto state = pipeline::build(s, {.upto = pipeline::Stage::Trials});
  DiagnosisOptions o;
  o.mat = false;
  const DiagnosisResult r = diagnose(state, o);
  std::vector<std::string> names;
  for (const auto& e : r.effects) names.push_back(e.name);
  std::sort(names.begin(), names.end());
  if (out) *out = r;
  return names;
}

TEST(ValidationUpstream, EachSessionNamesExactlyItsInjectedEffects) {
  const std::vector<std::pair<std::string, std::vector<std::string>>> cases{
      {"v1-realistic", {}},
      {"v2-linear-control", {}},
      {"v3-hysteresis", {}},
      {"v4-rate", {}},
      {"v5-outlier-lens-offset", {"lens_distortion", "outlier_marker", "time_offset"}},
      {"v6-formats-drift-scale", {"baseline_drift", "force_scale"}}};
  for (const auto& [name, expected] : cases) {
    DROPFIT_NEED_SHARED(validation(name));
    DiagnosisResult r;
    EXPECT_EQ(upstream_effects(name, &r), expected) << name << "\n" << r.report();
    EXPECT_FALSE(r.unexplained) << name << "\n" << r.report();
    std::cerr << name << "\n" << r.report();
  }
}

}  // namespace
}  // namespace dropfit::diagnosis

namespace dropfit::diagnosis {
namespace {

double value(const ErrorSet& e, const std::string& key) {
  for (const auto& [k, v] : e)
    if (k == key) return v;
  ADD_FAILURE() << "no value " << key;
  return std::numeric_limits<double>::quiet_NaN();
}

// v5: cam1's c13 and c15 swapped, k1 = -0.10 on both cameras, video 3 ms ahead.
TEST(ValidationUpstream, V5ParametersAndHeldOutErrors) {
  DROPFIT_NEED_SHARED(validation("v5-outlier-lens-offset"));
  DiagnosisResult r;
  upstream_effects("v5-outlier-lens-offset", &r);
  const Effect* outlier = r.find("outlier_marker");
  ASSERT_NE(outlier, nullptr) << r.report();
  EXPECT_NE(outlier->evidence.find("c13 and c15"), std::string::npos) << outlier->evidence;
  EXPECT_NE(outlier->evidence.find("label swap"), std::string::npos) << outlier->evidence;
  // The target: check RMS back under 1 mm once the pair is out.
  EXPECT_GT(value(outlier->error_before, "check_rms_mm"), 10.0);
  EXPECT_LT(value(outlier->error_after, "check_rms_mm"), 1.0);
  const Effect* lens = r.find("lens_distortion");
  ASSERT_NE(lens, nullptr) << r.report();
  // k1 = -0.10 injected; 18 markers at 0.2 px give a jackknife SE of about
  // 0.02-0.03, and the DLT absorbs a little of it: within 0.05.
  EXPECT_NEAR(value(lens->estimate, "cam1_k1"), -0.10, 0.05);
  EXPECT_NEAR(value(lens->estimate, "cam2_k1"), -0.10, 0.05);
  EXPECT_LT(value(lens->error_after, "cv_rms_mm"), 0.8 * value(lens->error_before, "cv_rms_mm"));
  const Effect* offset = r.find("time_offset");
  ASSERT_NE(offset, nullptr) << r.report();
  // 3 ms injected; the contact instant reads the plate's onset lag
  // (0.4-0.55 ms on this layered mat) with it.
  EXPECT_NEAR(value(offset->estimate, "video_offset_ms"), 3.0, 0.7);
}

// v6: drift 25 N over the 5 s record, all channels scaled by 1.05.
TEST(ValidationUpstream, V6ParametersAndHeldOutErrors) {
  DROPFIT_NEED_SHARED(validation("v6-formats-drift-scale"));
  DiagnosisResult r;
  upstream_effects("v6-formats-drift-scale", &r);
  const Effect* drift = r.find("baseline_drift");
  ASSERT_NE(drift, nullptr) << r.report();
  // 5 N/s; 1.5 N noise over thousands of still samples: within 0.5 N/s.
  EXPECT_NEAR(value(drift->estimate, "drift_n_s"), 5.0, 0.5);
  EXPECT_LT(value(drift->error_after, "heldout_still_rms_n"), 0.5 * value(drift->error_before, "heldout_still_rms_n"));
  const Effect* scale = r.find("force_scale");
  ASSERT_NE(scale, nullptr) << r.report();
  // The target: the scale within 0.5 %.
  EXPECT_NEAR(value(scale->estimate, "gain"), 1.05, 0.005);
  EXPECT_LT(value(scale->estimate, "gain_se"), 0.005);
  EXPECT_LT(value(scale->error_after, "impulse_error_pct_rms"), 0.2 * value(scale->error_before, "impulse_error_pct_rms"));
}

// The loop's plate correction refits every model on the corrected force:
// the earlier fits' warnings go with them (one set of notes, not two).
TEST(ValidationUpstream, PlateCorrectionRefitKeepsOneSetOfFitNotes) {
  DROPFIT_NEED_SHARED(validation("v6-formats-drift-scale"));
  pipeline::BuildOptions options;
  options.models = {fitting::ModelKind::Model2, fitting::ModelKind::Model4};
  const pipeline::SessionState state = pipeline::build(validation("v6-formats-drift-scale"), options);
  ASSERT_TRUE(state.loop.has_value());
  int corrected = 0, fit_notes = 0;
  const std::vector<std::string> notes = state.all_notes();
  for (const std::string& note : notes) {
    corrected += note.find("every trial's force and every fit") != std::string::npos ? 1 : 0;
    if (note.rfind("model4: ", 0) == 0 || note.rfind("model2: ", 0) == 0) ++fit_notes;
    EXPECT_EQ(std::count(notes.begin(), notes.end(), note), 1) << note;
  }
  EXPECT_EQ(corrected, 1);
  // The refit Model 2 and 4 warn of their weakly pinned parameters (as a
  // clean fit would: the force is corrected, the data no richer).
  EXPECT_GE(fit_notes, 2);
  // Both stand on the corrected force (the state's fit data once corrected),
  // in the order asked: each the fit the fitter makes of it directly (the
  // same deterministic multi-start, so the same optimum to rounding).
  ASSERT_EQ(state.fits.size(), 2u);
  const std::vector<fitting::TrialData>& corrected_data = state.fit_data;
  for (std::size_t k = 0; k < 2; ++k) {
    ASSERT_EQ(state.fits[k].model, options.models[k]);
    const fitting::FitResult direct =
        fitting::fit(corrected_data, pipeline::fit_options(state.session.manifest, options.models[k]));
    EXPECT_NEAR(state.fits[k].params.k1_n_m, direct.params.k1_n_m, 1e-6 * direct.params.k1_n_m);
    EXPECT_NEAR(state.fits[k].params.r1_n_s_m, direct.params.r1_n_s_m, 1e-6 * direct.params.r1_n_s_m);
  }
}

// Without a plate correction the models other than the loop's baseline are
// fitted after the loop, on the same data: the fits the fits stage alone
// makes, in the order asked (Model 5 warm-started from Model 4 as there).
TEST(ValidationUpstream, ModelsFittedAfterTheLoopAreTheFitsStages) {
  DROPFIT_NEED_SHARED(validation("v2-linear-control"));
  const Session session = capture::read_session(validation("v2-linear-control"));
  pipeline::BuildOptions options;
  options.models = {fitting::ModelKind::Model2, fitting::ModelKind::Model4, fitting::ModelKind::Model5};
  options.upto = pipeline::Stage::Fits;
  const pipeline::SessionState fits_only = pipeline::build(session, options);
  options.upto = pipeline::Stage::Loop;
  const pipeline::SessionState looped = pipeline::build(session, options);
  ASSERT_TRUE(looped.loop.has_value());
  ASSERT_FALSE(looped.loop->plate_correction.drift);
  ASSERT_EQ(looped.fits.size(), 3u);
  ASSERT_EQ(fits_only.fits.size(), 3u);
  EXPECT_TRUE(looped.models_after_loop.empty());
  for (std::size_t k = 0; k < 3; ++k) {
    ASSERT_EQ(looped.fits[k].model, options.models[k]);
    EXPECT_NEAR(looped.fits[k].params.k1_n_m, fits_only.fits[k].params.k1_n_m, 1e-9 * fits_only.fits[k].params.k1_n_m);
    EXPECT_NEAR(looped.fits[k].params.r1_n_s_m, fits_only.fits[k].params.r1_n_s_m,
                1e-9 * fits_only.fits[k].params.r1_n_s_m);
    EXPECT_EQ(looped.fits[k].warnings, fits_only.fits[k].warnings);
  }
}

// Clean sessions: the free-flight balance gives 1 within 0.5 % on each.
TEST(ValidationUpstream, ImpulseBalanceIsOneOnCleanSessions) {
  for (const std::string name : {"v1-realistic", "v2-linear-control", "v3-hysteresis", "v4-rate"}) {
    DROPFIT_NEED_SHARED(validation(name));
    const Session s = capture::read_session(validation(name));
    const auto state = pipeline::build(s, {.upto = pipeline::Stage::Trials});
    int n = 0;
    for (const PlateTrial& t : plate_trials(state, 0.0)) {
      const ImpulseBalance b = impulse_balance(t, {}, state.impactor_mass_kg, state.gravity_m_s2);
      if (!std::isfinite(b.ratio)) continue;
      ++n;
      EXPECT_NEAR(b.ratio, 1.0, 0.005) << name << " " << t.id;
      EXPECT_EQ(b.method, "free flight");
    }
    EXPECT_GE(n, 3) << name;
  }
}

}  // namespace
}  // namespace dropfit::diagnosis

namespace dropfit::diagnosis {
namespace {

// The whole loop (every stage, the mat's included) on the pipeline's state:
// each session names exactly what its README's table says a correct
// diagnosis names, and leaves nothing unexplained (the linear control:
// nothing named, nothing unexplained).
TEST(ValidationLoop, EachSessionIsNamedExactly) {
  const std::vector<std::pair<std::string, std::vector<std::string>>> cases{
      {"v1-realistic", {"stiffness_nonlinearity"}},
      {"v2-linear-control", {}},
      {"v3-hysteresis", {"hysteresis"}},
      {"v4-rate", {"rate_dependence"}},
      {"v5-outlier-lens-offset", {"lens_distortion", "outlier_marker", "stiffness_nonlinearity", "time_offset"}},
      {"v6-formats-drift-scale", {"baseline_drift", "force_scale", "stiffness_nonlinearity"}}};
  for (const auto& [name, expected] : cases) {
    DROPFIT_NEED_SHARED(validation(name));
    const DiagnosisResult r = diagnose(pipeline::build(capture::read_session(validation(name)), {.upto = pipeline::Stage::Trials}),
                                       DiagnosisOptions{});
    std::vector<std::string> names;
    for (const auto& e : r.effects) names.push_back(e.name);
    std::sort(names.begin(), names.end());
    EXPECT_EQ(names, expected) << name << "\n" << r.report();
    EXPECT_FALSE(r.unexplained) << name << "\n" << r.report();
    EXPECT_TRUE(r.not_assessed.empty()) << name << "\n" << r.report();
  }
}

// The linear control mat read by a plate that rings after each impact: an
// effect outside the library (the independent world's generator has a
// `resonance` of this shape, off in the six sessions). 100 N at 150 Hz,
// rising over 3 ms and decaying over 30 ms from the true contact, added to
// Fz1-Fz4 in memory. Nothing may be named for it, and the structure is left
// unexplained with its frequency within 5 % (each held-out contact holds
// only 55-65 samples, so the period is found in their sum; the strongest bin
// of one trial was 12 % off).
TEST(ValidationLoop, APlateRingingIsLeftUnexplainedWithItsFrequency) {
  DROPFIT_NEED_SHARED(validation("v2-linear-control"));
  std::ifstream in(validation("v2-linear-control") + "/../truth.json");
  const nlohmann::json truth = nlohmann::json::parse(in);
  Session s = capture::read_session(validation("v2-linear-control"));
  const double f_hz = 150.0, amp_n = 100.0, rise_s = 0.003, decay_s = 0.030;
  for (TrialRecording& t : s.trials) {
    double tc = std::numeric_limits<double>::quiet_NaN();
    for (const auto& tt : truth["trials"])
      if (tt["id"] == t.spec.id) tc = tt["contact_time_s"].get<double>();
    ASSERT_TRUE(std::isfinite(tc)) << t.spec.id;
    for (Eigen::Index k = 0; k < t.force.t_s.size(); ++k) {
      const double u = t.force.t_s(k) - tc;
      if (u <= 0.0) continue;
      const double ring = amp_n * (1.0 - std::exp(-u / rise_s)) * std::exp(-u / decay_s) *
                          std::sin(2.0 * std::numbers::pi * f_hz * u);
      for (int c = 4; c < 8; ++c) t.force.data(k, c) += ring / 4.0;  // Fz1..Fz4
    }
  }
  const DiagnosisResult r = diagnose(pipeline::build(s, {.upto = pipeline::Stage::Trials}), DiagnosisOptions{});
  EXPECT_TRUE(r.effects.empty()) << r.report();
  EXPECT_TRUE(r.unexplained) << r.report();
  ASSERT_EQ(r.remaining.size(), 1u) << r.report();
  EXPECT_EQ(r.remaining[0].name, "periodic_oscillation") << r.report();
  EXPECT_NEAR(r.remaining[0].frequency_hz, f_hz, 0.05 * f_hz) << r.report();
}

}  // namespace
}  // namespace dropfit::diagnosis
