// Knowing when the instrument is wrong: faults a lab meets, one at a time,
// on lab sessions of the project's own generator (samples/generator, which
// shares no simulation code with fitting/), and on the shared continuum
// sessions c3-c6 (../shared/validation-continuum; skipped when absent).
// Every case must end in a clear error, the affected trials rejected with
// the reason, or results within their stated uncertainty; and the clean
// session must not be touched by the checks.
#include <fmt/format.h>
#include <fmt/ranges.h>
#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstdlib>
#include <filesystem>
#include <fstream>
#include <functional>
#include <nlohmann/json.hpp>
#include <sstream>

#include "capture/io.h"
#include "pipeline/outputs.h"
#include "pipeline/pipeline.h"
#include "pipeline/wiring.h"
#include "core/error.h"
#include "diagnosis/diagnosis.h"
#include "samples/generator/synth.h"

namespace dropfit {
namespace {

namespace fs = std::filesystem;

bool contains(const std::string& s, const std::string& part) { return s.find(part) != std::string::npos; }

Session lab_session(std::uint64_t seed, const std::function<void(synth::SynthOptions&)>& change = {}) {
  synth::SynthOptions o = synth::lab_session_options(seed);
  if (change) change(o);
  return synth::make_session(o).session;
}

struct Outcome {
  pipeline::SessionState state;
  diagnosis::ScreenResult screen;
  diagnosis::DiagnosisResult loop;
  int accepted() const {
    int n = 0;
    for (const auto& t : state.trials) n += t.result.accepted ? 1 : 0;
    return n;
  }
  std::string reasons() const {
    std::string s;
    for (const auto& t : state.trials) s += t.result.id + ": " + (t.result.accepted ? "accepted" : t.result.reject_reason) + "\n";
    return s + loop.report();
  }
};

// The state as the pipeline builds it, the screen, then the loop (the mat
// stage only when asked: it refits every candidate).
Outcome run(const Session& session, bool mat = false) {
  Outcome r;
  // The pipeline screens the trials as it builds the state; a second screen
  // finds nothing new and reports what the first rejected.
  r.state = pipeline::build(session, {.upto = pipeline::Stage::Trials});
  r.screen = diagnosis::screen_trials(r.state);
  diagnosis::DiagnosisOptions o;
  o.mat = mat;
  bool any = false;
  for (const auto& t : r.state.trials) any = any || t.result.accepted;
  if (any) r.loop = diagnosis::diagnose(r.state, o);
  // DROPFIT_SHOW=1: every trial's verdict and the loop's report (for docs/validation.md).
  if (std::getenv("DROPFIT_SHOW")) std::cerr << r.reasons();
  return r;
}

const diagnosis::Effect* effect(const diagnosis::DiagnosisResult& r, const std::string& name) { return r.find(name); }

double estimate(const diagnosis::Effect& e, const std::string& name) {
  for (const auto& [k, v] : e.estimate)
    if (k == name) return v;
  return std::numeric_limits<double>::quiet_NaN();
}

// ---- The clean session: nothing rejected, nothing named at the plate --------

TEST(InstrumentFaults, CleanLabSessionPassesEveryCheck) {
  const Outcome r = run(lab_session(11));
  EXPECT_EQ(r.accepted(), 5) << r.reasons();
  EXPECT_TRUE(r.screen.rejected.empty()) << r.reasons();
  EXPECT_EQ(effect(r.loop, "force_scale"), nullptr) << r.reasons();
}

// ---- Channel faults: the eight channels cannot be one rigid plate's ---------

TEST(InstrumentFaults, DeadChannelRejectsEveryTrialNamingIt) {
  const Outcome r = run(lab_session(11, [](synth::SynthOptions& o) { o.faults.dead_channel = 4; }));  // Fz1
  EXPECT_EQ(r.accepted(), 0) << r.reasons();
  for (const auto& t : r.state.trials) {
    EXPECT_TRUE(contains(t.result.reject_reason, "rigid plate")) << t.result.reject_reason;
    EXPECT_TRUE(contains(t.result.reject_reason, "Fz1 reads almost nothing")) << t.result.reject_reason;
  }
}

TEST(InstrumentFaults, ExchangedShearAndVerticalColumnsAreRejected) {
  const Outcome r = run(lab_session(11, [](synth::SynthOptions& o) {
    o.faults.exchange_a = 0;  // Fx12
    o.faults.exchange_b = 4;  // Fz1
  }));
  EXPECT_EQ(r.accepted(), 0) << r.reasons();
  for (const auto& t : r.state.trials) {
    EXPECT_TRUE(contains(t.result.reject_reason, "twist")) << t.result.reject_reason;
    EXPECT_TRUE(contains(t.result.reject_reason, "Fx12 carries a vertical share")) << t.result.reject_reason;
  }
}

TEST(InstrumentFaults, SignReversedChannelIsRejected) {
  const Outcome r = run(lab_session(11, [](synth::SynthOptions& o) { o.faults.reversed_channel = 6; }));  // Fz3
  EXPECT_EQ(r.accepted(), 0) << r.reasons();
  for (const auto& t : r.state.trials)
    EXPECT_TRUE(contains(t.result.reject_reason, "Fz3 reads tension")) << t.result.reject_reason;
}

// A dead channel in one trial only: that trial rejected, the others kept.
TEST(InstrumentFaults, OneTrialsDeadChannelRejectsThatTrialOnly) {
  const Outcome r = run(lab_session(11, [](synth::SynthOptions& o) {
    o.faults.dead_channel = 7;
    o.faults.trials = {2};
  }));
  EXPECT_EQ(r.accepted(), 4) << r.reasons();
  EXPECT_FALSE(r.state.trials[2].result.accepted);
  EXPECT_TRUE(contains(r.state.trials[2].result.reject_reason, "Fz4")) << r.reasons();
  EXPECT_FALSE(r.state.fit_data[2].accepted);
}

// ---- Saturation: the clipped trials rejected, never fitted -------------------

TEST(InstrumentFaults, SaturatedTrialsAreRejectedTheOthersKept) {
  // The lab mat's vertical channels peak at 1.4-2.2 kN over 4.3-6.5 m/s: a
  // 1.8 kN range clips the faster trials. Which ones: from the truth (the
  // noise-free channels of the true plate force at the true centre of pressure).
  synth::SynthOptions o = synth::lab_session_options(11);
  o.faults.saturation_n = 1800.0;
  const synth::SyntheticSession ss = synth::make_session(o);
  std::vector<bool> clipped;
  for (const auto& tt : ss.truth.trials) {
    int above = 0;  // samples with a vertical channel beyond the range
    for (Eigen::Index j = 0; j < tt.plate_fz_noise_free_n.size(); ++j) {
      const double fz = tt.plate_fz_noise_free_n(j);
      const Eigen::Vector3d f(tt.shear_fraction.x() * fz, tt.shear_fraction.y() * fz, fz);
      const double top =
          synth::kistler_channels(f, tt.cop_m, o.plate_a_m, o.plate_b_m, o.plate_az0_m).tail<4>().maxCoeff();
      above += top > 1.01 * o.faults.saturation_n ? 1 : 0;
    }
    // Cut by more than 1 % for at least the detector's run (a clip within the
    // noise of a channel's peak loses a few newtons and is not told from it).
    clipped.push_back(above >= forceplate::ProcessOptions{}.saturation_flat_samples);
  }
  ASSERT_GE(std::count(clipped.begin(), clipped.end(), true), 2);
  ASSERT_GE(std::count(clipped.begin(), clipped.end(), false), 1);
  const Outcome r = run(ss.session);
  for (std::size_t i = 0; i < clipped.size(); ++i) {
    EXPECT_EQ(r.state.trials[i].result.accepted, !clipped[i]) << i << "\n" << r.reasons();
    if (clipped[i]) {
      EXPECT_TRUE(contains(r.state.trials[i].result.reject_reason, "saturated")) << r.reasons();
    }
  }
  EXPECT_EQ(effect(r.loop, "force_scale"), nullptr) << r.reasons();
}

// ---- Gain and mass: named, both causes ---------------------------------------

TEST(InstrumentFaults, PlateGainIsNamedWithTheMassItCouldEqually) {
  const Outcome r = run(lab_session(11, [](synth::SynthOptions& o) { o.effects.force_scale = 0.75; }));
  EXPECT_EQ(r.accepted(), 5) << r.reasons();
  const diagnosis::Effect* e = effect(r.loop, "force_scale");
  ASSERT_NE(e, nullptr) << r.reasons();
  EXPECT_NEAR(estimate(*e, "gain"), 0.75, 0.01) << r.reasons();
  EXPECT_TRUE(contains(e->evidence, "cannot tell a plate gain from a wrong declared mass")) << e->evidence;
}

TEST(InstrumentFaults, WrongDeclaredMassIsNamedAsGainOrMass) {
  const Outcome r = run(lab_session(11, [](synth::SynthOptions& o) { o.faults.declared_mass_kg = 30.0; }));
  const diagnosis::Effect* e = effect(r.loop, "force_scale");
  ASSERT_NE(e, nullptr) << r.reasons();
  // The plate reads the true 24 kg: as a gain, 24 / 30; as a mass, 24 kg.
  EXPECT_NEAR(estimate(*e, "gain"), 0.8, 0.01) << r.reasons();
  EXPECT_NEAR(estimate(*e, "impactor_mass_if_gain_is_1_kg"), 24.0, 0.3) << r.reasons();
}

// The gain the loop divides out of every force could equally be the
// declared mass: every fit.json the run writes says so, with the mass and
// how far every force and stiffness is off if the mass is the cause (the
// true 24 kg declared as 30: gain 0.8, forces 25 % too high).
TEST(InstrumentFaults, WrongDeclaredMassCaveatTravelsWithEveryFit) {
  const pipeline::SessionState state =
      pipeline::build(lab_session(11, [](synth::SynthOptions& o) { o.faults.declared_mass_kg = 30.0; }));
  const std::vector<std::string> caveats = pipeline::session_caveats(state);
  ASSERT_EQ(caveats.size(), 1u);
  const std::string& c = caveats.front();
  EXPECT_TRUE(contains(c, "where the manifest declares 30.00 kg")) << c;
  const auto at = c.find("an impactor of ");
  ASSERT_NE(at, std::string::npos) << c;
  EXPECT_NEAR(std::stod(c.substr(at + 15)), 24.0, 0.3) << c;
  const auto pct = c.find(" % too high");
  ASSERT_NE(pct, std::string::npos) << c;
  EXPECT_NEAR(std::stod(c.substr(c.rfind(' ', pct - 1) + 1)), 25.0, 1.5) << c;
  report::OutputSet out;
  pipeline::add_run_outputs(out, state);
  int files = 0;
  for (const auto& [name, text] : out.files()) {
    if (name.size() < 8 || name.compare(name.size() - 8, 8, "fit.json") != 0) continue;
    ++files;
    const nlohmann::json fj = nlohmann::json::parse(text);
    const auto& w = fj["warnings"];
    EXPECT_NE(std::find(w.begin(), w.end(), c), w.end()) << name;
  }
  EXPECT_GE(files, 3);
}

// A plate gain seen in two trials only (the others rejected, or never
// recorded): the information criterion has no degrees of freedom left
// (AICc undefined on two ratios), and it cannot veto a gain each trial's
// held-out error at least halves under. Asserted: gain 1.2 named within
// 0.01 on a two-trial session.
TEST(InstrumentFaults, PlateGainIsNamedOnTwoTrials) {
  const Outcome r = run(lab_session(11, [](synth::SynthOptions& o) {
    o.effects.force_scale = 1.2;
    o.impact_velocities_m_s = {4.6, 5.8};
  }));
  ASSERT_EQ(r.accepted(), 2) << r.reasons();
  const diagnosis::Effect* e = effect(r.loop, "force_scale");
  ASSERT_NE(e, nullptr) << r.reasons();
  EXPECT_NEAR(estimate(*e, "gain"), 1.2, 0.01) << e->evidence;
}

// A drift that grows past half the impactor's weight over the record (40
// N/s: 200 N by the end of a 5 s record, m g = 235 N): each still window is
// measured against the level the windows before it held (the impactor is
// caught), not the nearer of 0 and m g, which flipped the late windows to
// m g and left "a periodic oscillation" with nothing named. Asserted: the
// drift named within 1 N/s, nothing left at the plate.
TEST(InstrumentFaults, LargeBaselineDriftIsNamed) {
  const Outcome r = run(lab_session(11, [](synth::SynthOptions& o) { o.effects.baseline_drift_n_s = 40.0; }));
  const diagnosis::Effect* e = effect(r.loop, "baseline_drift");
  ASSERT_NE(e, nullptr) << r.reasons();
  EXPECT_NEAR(estimate(*e, "drift_n_s"), 40.0, 1.0) << e->evidence;
  for (const auto& rem : r.loop.remaining) EXPECT_NE(rem.stage, "forceplate") << rem.name << ": " << rem.description;
}

// ---- Manifest plausibility ------------------------------------------------------

struct TempDir {
  fs::path path;
  TempDir() {
    path = fs::temp_directory_path() / fmt::format("dropfit-faults-{}", ::getpid());
    fs::create_directories(path);
  }
  ~TempDir() { fs::remove_all(path); }
};

std::string read_text(const fs::path& p) {
  std::ifstream in(p);
  std::stringstream s;
  s << in.rdbuf();
  return s.str();
}

int line_of(const std::string& text, const std::string& part) {
  const auto at = text.find(part);
  return at == std::string::npos ? -1 : 1 + static_cast<int>(std::count(text.begin(), text.begin() + at, '\n'));
}

TEST(InstrumentFaults, ImplausibleGravityIsAnErrorNamingFieldAndLine) {
  TempDir dir;
  const fs::path file = dir.path / "session.toml";
  Manifest m = lab_session(11).manifest;
  m.gravity_m_s2 = 1e-300;
  capture::write_manifest(file.string(), m);
  const std::string text = read_text(file);
  try {
    capture::read_manifest(file.string());
    FAIL() << "gravity 1e-300 accepted";
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), "session.gravity_m_s2");
    EXPECT_EQ(e.line(), line_of(text, "gravity_m_s2"));
    EXPECT_TRUE(contains(e.reason(), "outside the physical range")) << e.what();
  }
  // Declared on purpose: accepted.
  m.outside_physical_range = {"session.gravity_m_s2"};
  capture::write_manifest(file.string(), m);
  EXPECT_DOUBLE_EQ(capture::read_manifest(file.string()).gravity_m_s2, 1e-300);
}

TEST(InstrumentFaults, MassInGramsIsAnError) {
  TempDir dir;
  const fs::path file = dir.path / "session.toml";
  Manifest m = lab_session(11).manifest;
  m.impactor.mass_kg = 24000.0;
  capture::write_manifest(file.string(), m);
  try {
    capture::read_manifest(file.string());
    FAIL() << "24000 kg accepted";
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), "impactor.mass_kg");
    EXPECT_EQ(e.line(), line_of(read_text(file), "mass_kg = 24000"));
  }
}

TEST(InstrumentFaults, TrialsSharingAFolderAreAnInputError) {
  TempDir dir;
  const fs::path file = dir.path / "session.toml";
  Manifest m = lab_session(11).manifest;
  for (auto& t : m.trials) t.dir = "trials/trial1";
  m.trials[1].dir = "trials/./trial1/";
  capture::write_manifest(file.string(), m);
  try {
    capture::read_manifest(file.string());
    FAIL() << "five trials reading one folder accepted";
  } catch (const InputError& e) {
    EXPECT_EQ(e.field(), "trial[1].dir");
    EXPECT_TRUE(contains(e.reason(), "as trial[0] does")) << e.what();
  }
}

// The same recording under two ids without the manifest saying so (files
// copied into two folders): the screen rejects the copies.
TEST(InstrumentFaults, CopiedRecordingsAreRejectedAsOneDrop) {
  Session s = lab_session(11);
  for (int i = 1; i < 5; ++i) {
    s.trials[i].force = s.trials[0].force;
    s.trials[i].tracks = s.trials[0].tracks;
  }
  const Outcome r = run(s);
  EXPECT_EQ(r.accepted(), 1) << r.reasons();
  for (int i = 1; i < 5; ++i)
    EXPECT_TRUE(contains(r.state.trials[i].result.reject_reason, "one drop counted twice")) << r.reasons();
}

// ---- One bad trial never sinks the session ------------------------------------

TEST(InstrumentFaults, TrialWithoutContactIsLeftOutOfEveryFit) {
  Session s = lab_session(11);
  ForceRecord& f = s.trials[2].force;
  const Eigen::Index quiet = f.pretrigger_samples / 2;
  for (Eigen::Index i = 0; i < f.data.rows(); ++i) f.data.row(i) = f.data.row(i % quiet);  // the plate's noise only
  Outcome r = run(s);
  EXPECT_EQ(r.accepted(), 4) << r.reasons();
  EXPECT_TRUE(contains(r.state.trials[2].result.reject_reason, "no trigger")) << r.reasons();
  EXPECT_FALSE(r.state.fit_data[2].accepted);
  pipeline::fit_models(r.state, {fitting::ModelKind::Model1, fitting::ModelKind::Model4});
  EXPECT_EQ(r.state.fits.size(), 2u) << fmt::format("{}", fmt::join(r.state.all_notes(), "\n"));
  for (const auto& fit : r.state.fits)
    for (const auto& t : fit.trials) EXPECT_NE(t.id, "trial3");
}

// ---- Time between trials -------------------------------------------------------

TEST(InstrumentFaults, SofteningBetweenTrialsIsNamedWithItsRate) {
  const Outcome r = run(lab_session(11,
                                [](synth::SynthOptions& o) {
                                  o.impact_velocities_m_s = {4.8, 6.5, 5.25, 4.3, 5.75};
                                  o.faults.softening_per_trial = 0.04;
                                }),
                    true);
  const diagnosis::Effect* e = effect(r.loop, "mat_change_between_trials");
  ASSERT_NE(e, nullptr) << r.reasons();
  EXPECT_NEAR(estimate(*e, "rate_per_trial"), -0.04, 0.01) << r.reasons();
  for (const char* wrong : {"hysteresis", "stiffness_nonlinearity", "rate_dependence", "time_offset", "force_scale"})
    EXPECT_EQ(effect(r.loop, wrong), nullptr) << wrong << "\n" << r.reasons();
}

// What the loop names, the results use: the whole pipeline on the same
// session predicts each held-out trial with its own stiffness (the trend
// fitted without it), so the final model's held-out peaks come within 1 %
// and its travel within 1 mm (one mat for all: 2-5 % and 2-4 mm), and every
// trial's clock offset, read from those contacts, within 0.1 ms of the
// true 0 (one mat for all: up to 0.9 ms).
TEST(InstrumentFaults, SofteningBetweenTrialsIsUsedByTheFinalModel) {
  const pipeline::SessionState s = pipeline::build(lab_session(11, [](synth::SynthOptions& o) {
    o.impact_velocities_m_s = {4.8, 6.5, 5.25, 4.3, 5.75};
    o.faults.softening_per_trial = 0.04;
  }));
  const fitting::FitResult* f = s.final_fit();
  ASSERT_NE(f, nullptr);
  ASSERT_EQ(s.final_label(), "closed_loop");
  int held_out = 0;
  for (const auto& t : f->trials) {
    if (t.train) continue;
    ++held_out;
    EXPECT_LT(std::abs(t.comparison.peak_force_pct_diff), 1.0) << t.id;
    EXPECT_LT(std::abs(t.max_deformation_mm_diff), 1.0) << t.id;
  }
  EXPECT_EQ(held_out, 4);
  for (const auto& t : s.trials) EXPECT_NEAR(t.result.video_offset_s, 0.0, 1e-4) << t.result.id;
}

TEST(InstrumentFaults, ShuffledOrderWithoutSofteningNamesNoChange) {
  const Outcome r = run(lab_session(11, [](synth::SynthOptions& o) { o.impact_velocities_m_s = {4.8, 6.5, 5.25, 4.3, 5.75}; }),
                    true);
  EXPECT_EQ(effect(r.loop, "mat_change_between_trials"), nullptr) << r.reasons();
}

// ---- Amplifier low-pass: the plate's lag, not the clock's ----------------------

// Trial results with the force processed as the manifest declares it (the
// pipeline passes [forceplate] lowpass_hz to forceplate::ProcessOptions).
std::vector<double> offsets_ms(const Session& s, double lowpass_hz) {
  const auto cameras = pipeline::cameras_of(pipeline::choose_calibration(s).after);
  std::vector<double> out;
  for (const auto& t : s.trials) {
    auto po = pipeline::force_options(s.manifest, t.force);
    po.lowpass_hz = lowpass_hz;
    const auto force = forceplate::process(pipeline::raw_resultants(s.manifest, t.force), po);
    const auto traj = reconstruction::reconstruct(cameras, t.tracks.uv_px, t.tracks.n_points());
    const auto r = trial::analyse(force, traj, pipeline::trial_options(s.manifest, t.spec.id));
    out.push_back(1e3 * r.video_offset_s);
  }
  return out;
}

TEST(InstrumentFaults, DeclaredLowPassIsTakenOutOfTheClock) {
  const Session s = lab_session(11, [](synth::SynthOptions& o) {
    o.faults.amplifier_lowpass_hz = 350.0;
    o.effects.time_offset_ms = 3.0;
  });
  EXPECT_NEAR(forceplate::butterworth_delay_s(350.0, 2), 0.643e-3, 0.001e-3);
  const auto declared = offsets_ms(s, 350.0), undeclared = offsets_ms(s, 0.0);
  for (std::size_t i = 0; i < declared.size(); ++i) {
    EXPECT_NEAR(declared[i] - undeclared[i], 0.643, 0.01);
    std::cerr << "offset declared " << declared[i] << " ms, undeclared " << undeclared[i] << " ms\n";
  }
}

// ---- A second impact: the first contact analysed, no plate effect -------------

TEST(InstrumentFaults, SecondImpactIsNoForceScale) {
  const Outcome r = run(lab_session(11, [](synth::SynthOptions& o) { o.catch_at_apex = false; }));
  EXPECT_EQ(r.accepted(), 5) << r.reasons();
  EXPECT_EQ(effect(r.loop, "force_scale"), nullptr) << r.reasons();
}

// ---- The shared continuum sessions ------------------------------------------------

std::string continuum(const std::string& name) {
  return std::string(DROPFIT_SOURCE_DIR) + "/../shared/validation-continuum/" + name + "/session";
}

bool have_continuum(const std::string& name) {
  if (fs::exists(continuum(name))) return true;
  const char* ci = std::getenv("CI");
  if (ci && std::string(ci) == "true") ADD_FAILURE() << "../shared/validation-continuum absent under CI";
  return false;
}

TEST(InstrumentFaultsContinuum, C3ClippedTrialsAreRejected) {
  if (!have_continuum("c3-saturation")) GTEST_SKIP() << "../shared absent";
  const Outcome r = run(capture::read_session(continuum("c3-saturation")));
  // Trials 4 and 5 hold the 2150 N channel range for 14 and more samples;
  // trial 3 touches it for two samples (a few newtons of its 7.4 kN peak);
  // trials 1 and 2 stay below it.
  for (int i : {3, 4}) {
    EXPECT_FALSE(r.state.trials[i].result.accepted) << r.reasons();
    EXPECT_TRUE(contains(r.state.trials[i].result.reject_reason, "saturated")) << r.reasons();
  }
  for (int i : {0, 1}) EXPECT_TRUE(r.state.trials[i].result.accepted) << r.reasons();
  EXPECT_EQ(effect(r.loop, "force_scale"), nullptr) << r.reasons();
}

TEST(InstrumentFaultsContinuum, C4SofteningIsNamed) {
  if (!have_continuum("c4-softening")) GTEST_SKIP() << "../shared absent";
  const Outcome r = run(capture::read_session(continuum("c4-softening")), true);
  const diagnosis::Effect* e = effect(r.loop, "mat_change_between_trials");
  ASSERT_NE(e, nullptr) << r.reasons();
  EXPECT_NEAR(estimate(*e, "rate_per_trial"), -0.03, 0.01) << r.reasons();
  for (const char* wrong : {"hysteresis", "stiffness_nonlinearity", "rate_dependence", "time_offset"})
    EXPECT_EQ(effect(r.loop, wrong), nullptr) << wrong << "\n" << r.reasons();
}

// c5: a +3 ms clock offset and an amplifier low-pass at 520 Hz (0.43 ms)
// nobody declared. Drop data cannot tell a pure delay of the force channel
// from a clock offset (both move the force against the video alike), so
// undeclared the loop reads the clock offset less the filter's delay; with
// the low-pass declared (the state rebuilt as the pipeline builds it from
// [forceplate] lowpass_hz) the offset is the clock's.
pipeline::SessionState with_declared_lowpass(const Session& s, double lowpass_hz) {
  pipeline::SessionState state = pipeline::build(s, {.upto = pipeline::Stage::Trials});
  for (std::size_t i = 0; i < s.trials.size(); ++i) {
    auto po = pipeline::force_options(s.manifest, s.trials[i].force);
    po.lowpass_hz = lowpass_hz;
    auto force = forceplate::process(pipeline::raw_resultants(s.manifest, s.trials[i].force), po);
    auto result = trial::analyse(force, state.trials[i].trajectories, pipeline::trial_options(s.manifest, s.trials[i].spec.id));
    state.fit_data[i] = pipeline::fitting_trial(s.manifest, result);
    state.trials[i].result = std::move(result);
    state.trials[i].force = std::move(force);
  }
  return state;
}

TEST(InstrumentFaultsContinuum, C5ClockOffsetIsTheClocksOnceTheLowPassIsDeclared) {
  if (!have_continuum("c5-lowpass-offset")) GTEST_SKIP() << "../shared absent";
  const Session s = capture::read_session(continuum("c5-lowpass-offset"));
  const double delay_ms = 1e3 * forceplate::butterworth_delay_s(520.0, 2);
  const diagnosis::DiagnosisResult undeclared = diagnosis::diagnose(pipeline::build(s, {.upto = pipeline::Stage::Trials}));
  const diagnosis::DiagnosisResult declared = diagnosis::diagnose(with_declared_lowpass(s, 520.0));
  if (std::getenv("DROPFIT_SHOW")) std::cerr << undeclared.report() << declared.report();
  const diagnosis::Effect* u = effect(undeclared, "time_offset");
  const diagnosis::Effect* d = effect(declared, "time_offset");
  ASSERT_NE(u, nullptr) << undeclared.report();
  ASSERT_NE(d, nullptr) << declared.report();
  EXPECT_NEAR(estimate(*d, "video_offset_ms"), 3.0, 0.3) << declared.report();
  EXPECT_NEAR(estimate(*u, "video_offset_ms"), 3.0 - delay_ms, 0.3) << undeclared.report();
  for (const auto* r : {&undeclared, &declared})
    for (const char* wrong : {"force_scale", "baseline_drift"}) EXPECT_EQ(effect(*r, wrong), nullptr) << r->report();
}

TEST(InstrumentFaultsContinuum, C6SecondImpactIsNoForceScale) {
  if (!have_continuum("c6-second-impact-drift")) GTEST_SKIP() << "../shared absent";
  const Outcome r = run(capture::read_session(continuum("c6-second-impact-drift")));
  EXPECT_EQ(r.accepted(), 5) << r.reasons();
  EXPECT_EQ(effect(r.loop, "force_scale"), nullptr) << r.reasons();
  EXPECT_NE(effect(r.loop, "baseline_drift"), nullptr) << r.reasons();
}

}  // namespace
}  // namespace dropfit
