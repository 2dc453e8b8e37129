// An undeclared force-channel low-pass told from a clock offset: the
// filter's exact discretisation (fitting/force_lowpass.h) against a
// fine-step integration, and the loop's force_lowpass term (diagnosis.h,
// "Force channel") on sessions of the project's own generator
// (samples/generator, which shares no simulation code with fitting/) and on
// the shared continuum session c5 (read in place; skipped without ../shared,
// failing under CI=true).
#include <gtest/gtest.h>

#include <cmath>
#include <functional>
#include <iostream>
#include <numbers>
#include <vector>

#include "capture/io.h"
#include "diagnosis/diagnosis.h"
#include "fitting/force_lowpass.h"
#include "forceplate/forceplate.h"
#include "pipeline/pipeline.h"
#include "samples/generator/synth.h"
#include "support/shared_data.h"

namespace dropfit {
namespace {

// A force pulse with the content of an impact: a 30 ms half-sine and a
// 90 Hz ring, zero before t = 0 (and smooth there: it starts as t^2).
double pulse(double t) {
  if (t <= 0.0) return 0.0;
  const double ring = std::sin(2.0 * std::numbers::pi * 90.0 * t) * (1.0 - std::exp(-t / 0.003));
  return 6000.0 * std::pow(std::sin(std::numbers::pi * std::min(t, 0.06) / 0.06), 2) + 400.0 * ring * std::exp(-t / 0.02);
}

// The analog filter by RK4 at 1 us: the reference.
std::vector<double> reference(double corner_hz, double h, int n) {
  const double w = 2.0 * std::numbers::pi * corner_hz, dt = 1e-6;
  auto f = [&](double t, double z, double v) { return std::pair{v, w * w * (pulse(t) - z) - std::sqrt(2.0) * w * v}; };
  std::vector<double> out(n);
  double z = 0.0, v = 0.0, t = 0.0;
  const int per = static_cast<int>(std::lround(h / dt));
  for (int i = 0; i < n; ++i) {
    out[i] = z;
    for (int k = 0; k < per; ++k) {
      const auto [a1, b1] = f(t, z, v);
      const auto [a2, b2] = f(t + dt / 2, z + dt / 2 * a1, v + dt / 2 * b1);
      const auto [a3, b3] = f(t + dt / 2, z + dt / 2 * a2, v + dt / 2 * b2);
      const auto [a4, b4] = f(t + dt, z + dt * a3, v + dt * b3);
      z += dt / 6 * (a1 + 2 * a2 + 2 * a3 + a4);
      v += dt / 6 * (b1 + 2 * b2 + 2 * b3 + b4);
      t += dt;
    }
  }
  return out;
}

TEST(ForceLowpass, ExactDiscretisationMatchesTheAnalogFilter) {
  // The fitter's grid: half a plate sample (0.5 ms).
  const double h = 0.5e-3;
  const int n = 160;
  for (double corner : {250.0, 520.0, 2000.0}) {
    std::vector<double> y(n);
    for (int i = 0; i < n; ++i) y[i] = pulse(i * h);
    fitting::force_lowpass(y, h, corner);
    const std::vector<double> ref = reference(corner, h, n);
    double worst = 0.0;
    for (int i = 0; i < n; ++i) worst = std::max(worst, std::abs(y[i] - ref[i]));
    // The Catmull-Rom cubic between grid values (as the fitter interpolates
    // the force) errs by under 1 N on a 6 kN pulse with a 400 N 90 Hz ring
    // at this step (a plate's noise is 2-5 N); a quarter-sample step, as the
    // loop's profile uses, by under 0.1 N.
    EXPECT_LT(worst, 1.0) << corner << " Hz";
    std::vector<double> fine(2 * n);
    for (int i = 0; i < 2 * n; ++i) fine[i] = pulse(i * h / 2);
    fitting::force_lowpass(fine, h / 2, corner);
    double worst_fine = 0.0;
    for (int i = 0; i < n; ++i) worst_fine = std::max(worst_fine, std::abs(fine[2 * i] - ref[i]));
    EXPECT_LT(worst_fine, 0.1) << corner << " Hz";
  }
  EXPECT_NEAR(fitting::lowpass_delay_s(520.0), forceplate::butterworth_delay_s(520.0, 2), 1e-12);
  EXPECT_NEAR(fitting::lowpass_delay_s(520.0), 0.4328e-3, 0.0001e-3);
}

struct Loop {
  diagnosis::DiagnosisResult result;
  std::string report;
};

Loop run_loop(const Session& s) {
  Loop l;
  l.result = diagnosis::diagnose(pipeline::build(s, {.upto = pipeline::Stage::Trials}));
  l.report = l.result.report();
  if (std::getenv("DROPFIT_SHOW")) std::cerr << l.report;
  return l;
}

double estimate(const diagnosis::Effect& e, const std::string& name) {
  for (const auto& [k, v] : e.estimate)
    if (k == name) return v;
  return std::numeric_limits<double>::quiet_NaN();
}

Session lab_session(std::uint64_t seed, const std::function<void(synth::SynthOptions&)>& change) {
  synth::SynthOptions o = synth::lab_session_options(seed);
  change(o);
  return synth::make_session(o).session;
}

// A 250 Hz filter (0.90 ms lag) and a 3 ms clock offset: the filter's shape
// stands out of the plate noise; it is named with an interval that holds
// its corner, and the offset is the clock's.
TEST(ForceLowpass, UndeclaredFilterIsNamedAndTheOffsetIsTheClocks) {
  const Loop l = run_loop(lab_session(11, [](synth::SynthOptions& o) {
    o.faults.amplifier_lowpass_hz = 250.0;
    o.effects.time_offset_ms = 3.0;
  }));
  const diagnosis::Effect* f = l.result.find("force_lowpass");
  ASSERT_NE(f, nullptr) << l.report;
  EXPECT_NEAR(estimate(*f, "corner_hz"), 250.0, 40.0) << l.report;
  EXPECT_LE(estimate(*f, "corner_low_hz"), 250.0) << l.report;
  EXPECT_GE(estimate(*f, "corner_high_hz"), 250.0) << l.report;
  const diagnosis::Effect* t = l.result.find("time_offset");
  ASSERT_NE(t, nullptr) << l.report;
  EXPECT_NEAR(estimate(*t, "video_offset_ms"), 3.0, 0.3) << l.report;
}

// What the loop names, the results use: the whole pipeline on the same
// session keeps the mat fitted through the named filter as its final model
// (fit.json states the corner), and each trial's clock offset is read from
// that model's contacts: the clock's 3 ms, not 3 ms less the filter's lag.
TEST(ForceLowpass, NamedFilterIsInTheFinalFitAndEveryTrialsOffset) {
  const pipeline::SessionState state = pipeline::build(lab_session(11, [](synth::SynthOptions& o) {
    o.faults.amplifier_lowpass_hz = 250.0;
    o.effects.time_offset_ms = 3.0;
  }));
  const fitting::FitResult* final_fit = state.final_fit();
  ASSERT_NE(final_fit, nullptr);
  EXPECT_NEAR(final_fit->force_lowpass_hz, 250.0, 40.0);
  EXPECT_FALSE(final_fit->estimates.empty());
  int accepted = 0;
  for (const auto& t : state.trials) {
    if (!t.result.accepted) continue;
    ++accepted;
    EXPECT_EQ(t.result.force_lowpass_source, "named") << t.result.id;
    EXPECT_NEAR(t.result.force_lowpass_hz, final_fit->force_lowpass_hz, 1e-9) << t.result.id;
    // 0.3 ms: the must-show's tolerance; the lag left in would be 0.9 ms.
    EXPECT_NEAR(t.result.video_offset_s, 3e-3, 0.3e-3) << t.result.id;
  }
  EXPECT_GE(accepted, 4);
}

// A 350 Hz filter (0.64 ms): the mat's parameters absorb its shape to
// within the noise, so the lag is reported as ambiguous between the clock
// and the force channel, with a range of clock offsets that holds the true
// 3 ms (the offset read without a filter is 2.36 ms).
TEST(ForceLowpass, UnidentifiedFilterLeavesTheLagAmbiguous) {
  const Loop l = run_loop(lab_session(11, [](synth::SynthOptions& o) {
    o.faults.amplifier_lowpass_hz = 350.0;
    o.effects.time_offset_ms = 3.0;
  }));
  EXPECT_EQ(l.result.find("force_lowpass"), nullptr) << l.report;
  const diagnosis::Effect* t = l.result.find("time_offset");
  ASSERT_NE(t, nullptr) << l.report;
  EXPECT_LE(estimate(*t, "video_offset_low_ms"), 3.0) << l.report;
  EXPECT_GE(estimate(*t, "video_offset_high_ms"), 3.0) << l.report;
  EXPECT_NEAR(estimate(*t, "video_offset_ms"), 3.0 - 0.643, 0.3) << l.report;
}

// A layered mat whose top layer is 0.69 kg lighter than the declared
// split, with a weak Maxwell arm and no filter (the generator's independent
// world with its random effects, seed 1010). The mat stage names the
// Maxwell arm and stops at its noise gate; without the layer masses the
// plate force rises as through a 312 Hz low-pass (chi-square 158 lower),
// and a filter and a 0.72 ms clock offset were named where neither was.
// The layer masses refitted without a filter lower it by 154: the filter
// is not told from them and is not named, its rejection says why, and no
// clock offset is named.
TEST(ForceLowpass, LayerMassesRivalAFilter) {
  synth::SynthOptions o = synth::independent_world_options(1010);
  synth::add_random_effects(o, 1010);
  const Loop l = run_loop(synth::make_session(o).session);
  EXPECT_EQ(l.result.find("force_lowpass"), nullptr) << l.report;
  EXPECT_EQ(l.result.find("time_offset"), nullptr) << l.report;
  bool said = false;
  for (const auto& r : l.result.rejected)
    if (r.name == "force_lowpass" && r.reason.find("layer masses") != std::string::npos) said = true;
  EXPECT_TRUE(said) << l.report;
}

// The same session without the filter: no filter named, the offset the
// clock's.
TEST(ForceLowpass, CleanSessionNamesNoFilter) {
  const Loop l = run_loop(lab_session(11, [](synth::SynthOptions& o) { o.effects.time_offset_ms = 3.0; }));
  EXPECT_EQ(l.result.find("force_lowpass"), nullptr) << l.report;
  const diagnosis::Effect* t = l.result.find("time_offset");
  ASSERT_NE(t, nullptr) << l.report;
  EXPECT_NEAR(estimate(*t, "video_offset_ms"), 3.0, 0.3) << l.report;
}

// c5: a 520 Hz filter (0.43 ms) and a +3 ms clock offset on a linear chain
// (Model 4 is exact there, 3 N of plate noise). The filter's shape beyond
// its delay is within the noise once the mat's parameters are refitted (the
// profile rises by 0.4 from no filter to the true delay), so the split of
// the lag cannot be made: not named, and the clock offsets it allows (from
// the 2.58 ms read without a filter up to 0.6 ms more) hold the true 3 ms.
TEST(ForceLowpassContinuum, C5LagIsAmbiguousWithTheClocksOffsetInItsRange) {
  const auto dir = testsupport::shared_path("validation-continuum") / "c5-lowpass-offset" / "session";
  DROPFIT_NEED_SHARED(dir);
  const Loop l = run_loop(capture::read_session(dir.string()));
  EXPECT_EQ(l.result.find("force_lowpass"), nullptr) << l.report;
  const diagnosis::Effect* t = l.result.find("time_offset");
  ASSERT_NE(t, nullptr) << l.report;
  EXPECT_NEAR(estimate(*t, "video_offset_ms"), 3.0 - 0.433, 0.3) << l.report;
  EXPECT_LE(estimate(*t, "video_offset_low_ms"), 3.0) << l.report;
  EXPECT_GE(estimate(*t, "video_offset_high_ms"), 3.0) << l.report;
  EXPECT_LT(estimate(*t, "video_offset_high_ms") - estimate(*t, "video_offset_low_ms"), 1.0) << l.report;
}

}  // namespace
}  // namespace dropfit
