// Identifiability and the intervals beyond the linearisation: Model 4's
// conjugate basin (the layers' two frequencies met by a second pair of
// springs), the profile-likelihood intervals, and the clock-shift SE a
// held-out trial inherits from the parameters. On sessions of the
// project's independent world (samples/generator) with a linear mat, so
// that Model 4 is the world's model and the truth is known.
#include <gtest/gtest.h>

#include <Eigen/Eigenvalues>
#include <cmath>
#include <string>
#include <vector>

#include "fitting/detail/identify.h"
#include "fitting/fit.h"
#include "pipeline/pipeline.h"
#include "samples/generator/synth.h"

namespace dropfit {
namespace {

using fitting::MatParams;

// The squared natural frequencies of the layers under a held impactor:
// eigenvalues of M^-1 K, K = [[k1 + k2, -k2], [-k2, k2 + k3]].
Eigen::Vector2d layer_eigenvalues(double a, double kt, double kb, double m1, double m2) {
  Eigen::Matrix2d k;
  k << (a + kt) / m1, -kt / m1, -kt / m2, (kt + kb) / m2;
  Eigen::EigenSolver<Eigen::Matrix2d> es(k);
  Eigen::Vector2d ev = es.eigenvalues().real();
  if (ev[0] > ev[1]) std::swap(ev[0], ev[1]);
  return ev;
}

TEST(Identify, TheConjugateStartSharesTheLayersFrequencies) {
  fitting::FitOptions o;
  o.model = fitting::ModelKind::Model4;
  const fitting::internal::ParamSpace space = fitting::internal::make_space(o, 1.5e5);
  MatParams p;
  p.k1_n_m = 4.96e4, p.k2_n_m = 4.147e5, p.k3_n_m = 2.656e6;
  p.r1_n_s_m = 89.06, p.r2_n_s_m = 18.82, p.r3_n_s_m = 690.9;
  p.m1_kg = 2.44, p.m2_kg = 3.66;
  fitting::internal::ParamSpace s = space;
  s.base.m1_kg = 2.44, s.base.m2_kg = 3.66;
  const Eigen::VectorXd uc = fitting::internal::conjugate_start(s, s.from_mat(p));
  ASSERT_EQ(uc.size(), s.size());
  const MatParams c = s.to_mat(uc.data());
  // Both frequencies (and both damping "frequencies") kept to 1e-9.
  const Eigen::Vector2d a = layer_eigenvalues(p.k1_n_m, p.k2_n_m, p.k3_n_m, 2.44, 3.66);
  const Eigen::Vector2d b = layer_eigenvalues(c.k1_n_m, c.k2_n_m, c.k3_n_m, 2.44, 3.66);
  EXPECT_NEAR(b[0] / a[0], 1.0, 1e-9);
  EXPECT_NEAR(b[1] / a[1], 1.0, 1e-9);
  const Eigen::Vector2d ra = layer_eigenvalues(p.r1_n_s_m, p.r2_n_s_m, p.r3_n_s_m, 2.44, 3.66);
  const Eigen::Vector2d rb = layer_eigenvalues(c.r1_n_s_m, c.r2_n_s_m, c.r3_n_s_m, 2.44, 3.66);
  EXPECT_NEAR(rb[0] / ra[0], 1.0, 1e-9);
  EXPECT_NEAR(rb[1] / ra[1], 1.0, 1e-9);
  // The other pair: (1.033e6, 1.111e6) N/m, the world's truth for this
  // fit (1.002e6, 1.124e6) within 4 %.
  EXPECT_NEAR(c.k2_n_m, 1.002e6, 0.04 * 1.002e6);
  EXPECT_NEAR(c.k3_n_m, 1.124e6, 0.04 * 1.124e6);
  EXPECT_NEAR(c.k1_n_m / p.k1_n_m, 1.0, 1e-12);
}

// The conjugate's springs can lie within 20 % of the optimum's while its
// dampings are exchanged between the layers: another basin, searched. The
// multi-start's optimum on the generator's seed 1104 (k2 5.28e5, k3 1.58e6
// N/m; r2 102, r3 1055 N s/m) has its conjugate at k2 6.12e5, k3 1.37e6, r2
// 283, r3 603: the springs 15 % away, the dampings a factor 2.8 and 1.75;
// the truth there is 5.89e5, 1.39e6, 314, 497.
TEST(Identify, AConjugateThatExchangesOnlyTheDampingIsSearched) {
  fitting::FitOptions o;
  o.model = fitting::ModelKind::Model4;
  fitting::internal::ParamSpace s = fitting::internal::make_space(o, 1.0e5);
  s.base.m1_kg = 2.44, s.base.m2_kg = 3.66;
  MatParams p;
  p.k1_n_m = 31628.8, p.k2_n_m = 528257.0, p.k3_n_m = 1.57655e6;
  p.r1_n_s_m = 232.064, p.r2_n_s_m = 101.857, p.r3_n_s_m = 1055.01;
  p.m1_kg = 2.44, p.m2_kg = 3.66;
  const Eigen::VectorXd uc = fitting::internal::conjugate_start(s, s.from_mat(p));
  ASSERT_EQ(uc.size(), s.size());
  const MatParams c = s.to_mat(uc.data());
  EXPECT_NEAR(c.k2_n_m, 6.116e5, 0.001 * 6.116e5);
  EXPECT_NEAR(c.k3_n_m, 1.368e6, 0.001 * 1.368e6);
  EXPECT_NEAR(c.r2_n_s_m, 282.77, 0.3);
  EXPECT_NEAR(c.r3_n_s_m, 602.74, 0.6);
}

struct WorldFit {
  synth::SyntheticSession session;
  pipeline::SessionState state;
  fitting::FitResult fit;
};

// The coverage script's session of `seed` (scripts/coverage: independent
// world, linear mat), fitted as `dropfit fit --model 4 --train trial3`.
WorldFit fit_linear_world(std::uint64_t seed) {
  synth::SynthOptions o = synth::independent_world_options(seed);
  synth::set_effect(o.effects, "stiffness_nonlinearity", 0.0);
  WorldFit w{synth::make_session(o), {}, {}};
  w.state = pipeline::build(w.session.session, {.upto = pipeline::Stage::Trials});
  fitting::FitOptions fo = w.state.baseline_fit_options;
  fo.model = fitting::ModelKind::Model4;
  fo.train_ids = {"trial3"};
  fo.sensitivity = false;
  w.fit = fitting::fit(w.state.fit_data, fo);
  return w;
}

const fitting::ParameterEstimate& estimate(const fitting::FitResult& f, const std::string& name) {
  for (const auto& e : f.estimates)
    if (e.name == name) return e;
  throw std::runtime_error("no estimate " + name);
}

bool holds(const fitting::ParameterEstimate& e, double truth) { return e.ci_low <= truth && truth <= e.ci_high; }

}  // namespace

// Seed 7012 (scripts/coverage's g013): the training trial's drop does not
// tell the two layers apart. The conjugate basin fits as well (k2 4.3e5
// against 6.8e5 N/m), so k2, k3, r2 and r3 are not identifiable and their
// intervals span both basins, the truth inside; the best basin's own
// interval is kept beside.
TEST(Identify, ExchangeableLayersAreNotIdentifiableAndTheirIntervalsSpanBoth) {
  const WorldFit w = fit_linear_world(7012);
  const MatParams& truth = w.session.truth.params;
  ASSERT_EQ(w.fit.alternatives.size(), 1u) << w.fit.report();
  // fit.json's statistic is the one the basin passed: at most chi-square(1)'s 3.84.
  EXPECT_GE(w.fit.alternatives[0].delta_chi2, 0.0);
  EXPECT_LE(w.fit.alternatives[0].delta_chi2, 3.84);
  for (const std::string name : {"k2_n_m", "k3_n_m", "r2_n_s_m", "r3_n_s_m"}) {
    const auto& e = estimate(w.fit, name);
    EXPECT_FALSE(e.identifiable) << name;
    EXPECT_EQ(e.interval, "basins") << name;
    EXPECT_TRUE(holds(e, fitting::get_parameter(truth, name))) << name;
    const double other = fitting::get_parameter(w.fit.alternatives[0].params, name);
    EXPECT_TRUE(e.ci_low <= other && other <= e.ci_high) << name;
    EXPECT_LE(e.ci_low, e.basin_ci_low) << name;
    EXPECT_GE(e.ci_high, e.basin_ci_high) << name;
    EXPECT_NE(e.note.find("another basin"), std::string::npos) << name;
  }
  // The two basins' k2 differ by more than a third (measured 6.8e5 and 4.3e5).
  EXPECT_GT(estimate(w.fit, "k2_n_m").ci_high / estimate(w.fit, "k2_n_m").ci_low, 1.5);
}

// A warm single start near the optimum (the loop's refits) skips the
// search; search_identifiability runs it for a refit a lab reads: the same
// conjugate basin found, the same parameters declared not identifiable.
TEST(Identify, AWarmRefitSearchesWhenAsked) {
  const WorldFit w = fit_linear_world(7012);
  fitting::FitOptions fo = w.state.baseline_fit_options;
  fo.model = fitting::ModelKind::Model4;
  fo.train_ids = {"trial3"};
  fo.sensitivity = false;
  fo.initial = w.fit.params;
  fo.starts = 1;
  const fitting::FitResult quick = fitting::fit(w.state.fit_data, fo);
  EXPECT_TRUE(quick.alternatives.empty());
  fo.search_identifiability = true;
  const fitting::FitResult searched = fitting::fit(w.state.fit_data, fo);
  ASSERT_EQ(searched.alternatives.size(), 1u) << searched.report();
  for (const std::string name : {"k2_n_m", "k3_n_m", "r2_n_s_m", "r3_n_s_m"}) {
    EXPECT_FALSE(estimate(searched, name).identifiable) << name;
    EXPECT_EQ(estimate(searched, name).interval, "basins") << name;
  }
}

// Seed 7015 (g016): the multi-start ended in the conjugate basin (k2 0.41,
// k3 2.4 times the truth) at a cost the data reject; the search from its
// conjugate reaches the truth's basin, which leads by a likelihood ratio
// over 3.84, so every parameter keeps a (Wald) interval holding the truth.
TEST(Identify, TheConjugateSearchReachesTheTruthsBasin) {
  const WorldFit w = fit_linear_world(7015);
  const MatParams& truth = w.session.truth.params;
  EXPECT_TRUE(w.fit.alternatives.empty()) << w.fit.report();
  for (const auto& e : w.fit.estimates) {
    if (!e.free) continue;
    const double t = fitting::get_parameter(truth, e.name);
    EXPECT_TRUE(e.identifiable) << e.name;
    EXPECT_TRUE(holds(e, t)) << e.name << " " << e.ci_low << " " << t << " " << e.ci_high;
    EXPECT_LT(std::abs(e.value / t - 1.0), 0.05) << e.name;  // measured within 2 %
  }
}

// Seed 7054: the best optimum is the conjugate basin, and the truth's basin
// trails it by a likelihood-ratio statistic of 4.7, just beyond 3.84 (the
// test's own 5 %). The intervals exclude the truth's basin as the test
// says, but the SEs carry its posterior share (9 %): every parameter's error
// is then within 4 of its SE, where this basin's own SE puts it beyond 5.
TEST(Identify, ATrailingBasinsShareWidensTheStandardErrors) {
  const WorldFit w = fit_linear_world(7054);
  const MatParams& truth = w.session.truth.params;
  EXPECT_TRUE(w.fit.alternatives.empty()) << w.fit.report();
  for (const std::string name : {"k1_n_m", "k2_n_m", "k3_n_m", "r1_n_s_m", "r2_n_s_m", "r3_n_s_m"}) {
    const auto& e = estimate(w.fit, name);
    const double error = std::abs(e.value - fitting::get_parameter(truth, name));
    EXPECT_TRUE(e.identifiable) << name;
    ASSERT_TRUE(std::isfinite(e.basin_se)) << name;
    EXPECT_GT(error, 5.0 * e.basin_se) << name;
    EXPECT_LT(error, 4.0 * e.se) << name;
    EXPECT_GT(e.se, 2.0 * e.basin_se) << name;
  }
  bool said = false;
  for (const auto& m : w.fit.warnings) said = said || m.find("another basin fits less well") != std::string::npos;
  EXPECT_TRUE(said) << w.fit.report();
}

// Seed 7000 (g001): a well-determined session keeps its Wald intervals,
// each holding the truth, none declared not identifiable.
TEST(Identify, AWellDeterminedSessionKeepsItsIntervals) {
  const WorldFit w = fit_linear_world(7000);
  const MatParams& truth = w.session.truth.params;
  EXPECT_TRUE(w.fit.alternatives.empty());
  for (const auto& e : w.fit.estimates) {
    if (!e.free) continue;
    EXPECT_TRUE(e.identifiable) << e.name;
    EXPECT_FALSE(e.interval.empty()) << e.name;
    EXPECT_TRUE(holds(e, fitting::get_parameter(truth, e.name))) << e.name;
    EXPECT_LT(e.ci_high / e.ci_low, 1.2) << e.name;  // measured at most 1.07 (r2)
    EXPECT_FALSE(std::isfinite(e.basin_se)) << e.name;  // no other basin shares it
  }
}

// The fitted contact instants on the force clock against the truth, each
// trial's error in its standard error: a held-out trial's SE holds what it
// inherits from the parameters (before: 1-2 us against errors of 5-25 us).
TEST(Identify, HeldOutContactInstantsHaveSEsOfTheirErrorsSize) {
  const WorldFit w = fit_linear_world(7015);
  double ss = 0.0;
  int n = 0;
  for (const auto& rep : w.fit.trials) {
    const trial::TrialResult* tr = nullptr;
    for (const auto& t : w.state.trials)
      if (t.result.id == rep.id) tr = &t.result;
    ASSERT_NE(tr, nullptr);
    const synth::TrialTruth* tt = nullptr;
    for (const auto& t : w.session.truth.trials)
      if (t.id == rep.id) tt = &t;
    ASSERT_NE(tt, nullptr);
    ASSERT_TRUE(std::isfinite(rep.contact_shift_se_s)) << rep.id;
    const double err = tr->contact_time_s + rep.contact_shift_s - tt->contact_time_s;
    ss += (err / rep.contact_shift_se_s) * (err / rep.contact_shift_se_s);
    ++n;
    EXPECT_GT(rep.contact_shift_se_s, 4e-6) << rep.id;
  }
  ASSERT_EQ(n, 5);
  const double rms_z = std::sqrt(ss / n);
  EXPECT_LT(rms_z, 2.0);
  EXPECT_GT(rms_z, 0.2);
}

}  // namespace dropfit
