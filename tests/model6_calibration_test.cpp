// Model 6's uncertainty calibrations (fitting/model6_calibration.h): the
// cross-validated discrepancy of the prediction intervals and the clock
// offsets' Birge and common-bias widening, and the common timing
// discrepancy (fitting/model6_fit.h), on hand-computed values.
#include "fitting/model6_calibration.h"
#include "fitting/model6_fit.h"

#include <gtest/gtest.h>

#include <cmath>
#include <limits>
#include <vector>

namespace dropfit::fitting {
namespace {

// Four held-out peaks: residuals of 300, -250, 200 and 100 N against a
// parameter SD of 10 N, a discrepancy SD of 50 N and a plate noise of 20 N.
std::vector<HeldOutCheck> four_peaks(double discrepancy_var) {
  std::vector<HeldOutCheck> c;
  for (double r : {300.0, -250.0, 200.0, 100.0}) c.push_back({r, 100.0, discrepancy_var, 400.0});
  return c;
}

TEST(Model6Calibration, DiscrepancyScaledByTheOtherTrialsOnly) {
  const std::vector<double> v = cross_validated_discrepancy_var(four_peaks(2500.0));
  ASSERT_EQ(v.size(), 4u);
  // Trial 1 from trials 2-4: (62000 + 39500 + 9500) / 7500 = 14.8 times
  // its 2500 N^2; trial 4 from trials 1-3: (89500 + 62000 + 39500) / 7500.
  EXPECT_NEAR(v[0], 2500.0 * 111000.0 / 7500.0, 1e-6);
  EXPECT_NEAR(v[3], 2500.0 * 191000.0 / 7500.0, 1e-6);
  // The largest own residual does not set its own interval: trial 1's
  // variance is the smallest of the four.
  EXPECT_LT(v[0], v[1]);
  EXPECT_LT(v[0], v[3]);
}

TEST(Model6Calibration, NeverNarrowerThanTheTrainingMisfit) {
  std::vector<HeldOutCheck> c = four_peaks(2500.0);
  for (HeldOutCheck& x : c) x.residual *= 0.05;  // 15 N and less: inside the stated SD
  for (double v : cross_validated_discrepancy_var(c)) EXPECT_DOUBLE_EQ(v, 2500.0);
}

TEST(Model6Calibration, WholeVarianceScaledWithoutDiscrepancy) {
  // No training misfit in the quantity: the others' excess over their
  // stated variance (111000 N^2 for trial 1) is shared in proportion to the
  // stated variance (100 N^2 of their 300), carried as its discrepancy.
  const std::vector<double> v = cross_validated_discrepancy_var(four_peaks(0.0));
  EXPECT_NEAR(v[0], 100.0 * 111000.0 / 300.0, 1e-6);
}

TEST(Model6Calibration, ExcessGrowsWithTheDistanceFromTraining) {
  // The four peaks at energy distances 0.1, 0.2, 0.3 and 0.5 from the
  // training impact: shape w = distance^2 x 2500 N^2. Trial 4 from trials
  // 1-3: excesses 87000, 59500, 37000 N^2 over w = 25, 100, 225, each
  // e / w weighted by w^2 / (3000 + kappa^2 w)^2: kappa^2 = 1315.865 at the
  // fixed point (computed apart, in double precision), so 2500 + 625 x
  // kappa^2; trial 1 from trials 2-4 (59500, 37000, 7000 over 100, 225,
  // 625): kappa^2 = 237.046, 2500 + 25 x kappa^2.
  std::vector<HeldOutCheck> c = four_peaks(2500.0);
  const double d[4] = {0.1, 0.2, 0.3, 0.5};
  for (int i = 0; i < 4; ++i) c[i].distance = d[i];
  const std::vector<double> v = cross_validated_discrepancy_var(c);
  EXPECT_NEAR(v[3], 824915.591, 1e-2);
  EXPECT_NEAR(v[0], 8426.162, 1e-2);
  // Every other trial at the training impact's energy: no distance to
  // share by, the equal shares of the training misfit's shape.
  for (int i = 0; i < 3; ++i) c[i].distance = 0.0;
  EXPECT_NEAR(cross_validated_discrepancy_var(c)[3], 2500.0 + 2500.0 * 183500.0 / 7500.0, 1e-6);
}

TEST(Model6Calibration, OneHugeStatedVarianceDoesNotCancelTheOthers) {
  // A fifth held-out peak whose parameters' SE is 10 kN (a prediction near
  // a switch between two humps) and whose residual is 0: its excess of
  // -1e8 N^2 would cancel the others' in a plain sum (trial 1 left at its
  // 2500 N^2); weighted by its variance it tells almost nothing, and trial
  // 1's variance stays the 37000 N^2 trials 2-4 show (within 0.1 %).
  std::vector<HeldOutCheck> c = four_peaks(2500.0);
  c.push_back({0.0, 1e8, 2500.0, 400.0});
  EXPECT_NEAR(cross_validated_discrepancy_var(c)[0], 37000.0, 37.0);
}

TEST(Model6Calibration, TooFewOtherTrialsLeaveItUnchanged) {
  std::vector<HeldOutCheck> c = four_peaks(2500.0);
  c.resize(2);
  for (double v : cross_validated_discrepancy_var(c)) EXPECT_DOUBLE_EQ(v, 2500.0);
}

TEST(Model6Calibration, DegreesOfFreedomOfTheScaledDiscrepancy) {
  // Four held-out checks: each scaled by the three others; one without a
  // residual leaves two others to the rest (and is itself scaled by three).
  std::vector<HeldOutCheck> c = four_peaks(2500.0);
  for (int d : cross_validated_dof(c)) EXPECT_EQ(d, 3);
  c[1].residual = std::nan("");
  EXPECT_EQ(cross_validated_dof(c), (std::vector<int>{2, 3, 2, 2}));
  c.resize(2);
  EXPECT_EQ(cross_validated_dof(c), (std::vector<int>{0, 0}));
}

TEST(Model6Calibration, WelchSatterthwaiteAndStudentQuantile) {
  // All of the variance estimated from 3 others: 3 degrees of freedom;
  // an equal known part: (1 + 1)^2 / (1 / 3) = 12.
  EXPECT_NEAR(welch_dof(0.0, 1.0, 3.0), 3.0, 1e-12);
  EXPECT_NEAR(welch_dof(1.0, 1.0, 3.0), 12.0, 1e-12);
  EXPECT_TRUE(std::isinf(welch_dof(1.0, 0.0, 3.0)));
  EXPECT_TRUE(std::isinf(welch_dof(1.0, 1.0, 0.0)));
  // Two-sided 95 % points of Student's t (any t table, six decimals).
  EXPECT_NEAR(t_quantile_95(3.0), 3.182446, 1e-6);
  EXPECT_NEAR(t_quantile_95(12.0), 2.178813, 1e-6);
  EXPECT_NEAR(t_quantile_95(std::numeric_limits<double>::infinity()), 1.959964, 1e-6);
}

TEST(Model6Calibration, BirgeRatioOfScatteredOffsets) {
  // Five offsets (ms) of one foam session scattering beyond their SEs:
  // chi2 52.61 about their weighted mean -0.0027 ms on 4 degrees of freedom.
  const std::vector<double> off = {0.034, 0.007, -0.034, 0.035, -0.001};
  const std::vector<double> se = {0.024, 0.003, 0.005, 0.056, 0.004};
  EXPECT_NEAR(birge_ratio(off, se), 3.6268, 1e-4);
  const std::vector<double> out = calibrated_offset_ses(off, se, 0.02);
  ASSERT_EQ(out.size(), 5u);
  EXPECT_NEAR(out[0], 0.08931, 1e-5);
  EXPECT_NEAR(out[1], 0.02277, 1e-5);
  EXPECT_NEAR(out[3], 0.20408, 1e-5);
}

TEST(Model6Calibration, ConsistentOffsetsKeepTheirSes) {
  // Within their SEs (Birge ratio below 1): only the common term is added.
  EXPECT_DOUBLE_EQ(birge_ratio({1.0, 1.1}, {1.0, 1.0}), 1.0);
  const std::vector<double> out = calibrated_offset_ses({1.0, 1.1}, {1.0, 1.0}, 0.75);
  EXPECT_NEAR(out[0], 1.25, 1e-12);
  EXPECT_DOUBLE_EQ(birge_ratio({1.0}, {0.1}), 1.0);
  EXPECT_DOUBLE_EQ(birge_ratio({1.0, 2.0}, {0.1, 0.0}), 1.0);
}

// The common timing discrepancy from a training trial whose fitted force
// matches the record within its noise while the fitted face travel runs
// 0.3 ms behind the video's: the travel's least-squares shift, 0.3 ms; a
// constant 2 mm travel offset (no timing) adds nothing; the travel matched,
// 0.
TEST(Model6Timing, TravelShiftedInTimeIsATimingDiscrepancy) {
  const double period_s = 0.1, h = 1e-4, lag_s = 3e-4;
  const int n = static_cast<int>(period_s / h) + 1;
  const double pi = std::acos(-1.0);
  auto travel = [&](double t) { return 0.1 * std::sin(pi * t / period_s); };
  TrialData td;
  td.id = "trial1";
  td.force_noise_n = 1.5;
  td.marker_noise_m = 2e-4;
  td.t_s.resize(n);
  td.grf_n.resize(n);
  td.impactor_m.resize(n);
  TrialReport rep;
  rep.id = td.id;
  rep.train = true;
  rep.window_end_s = period_s;
  rep.simulation.grf_n.resize(n);
  rep.simulation.impactor_m.resize(n);
  for (int i = 0; i < n; ++i) {
    const double t = i * h;
    td.t_s[i] = t;
    rep.simulation.grf_n[i] = 5000.0 * std::sin(pi * t / period_s);
    td.grf_n[i] = rep.simulation.grf_n[i] + (i % 2 == 0 ? 1.0 : -1.0);  // within the plate's noise
    rep.simulation.impactor_m[i] = travel(t - lag_s);
    td.impactor_m[i] = travel(t);
  }
  Model6FitResult res;
  res.trials = {rep};
  add_model6_prediction_intervals({td}, Model6FitOptions{}, res);
  EXPECT_NEAR(res.timing_discrepancy_s, lag_s, 0.02 * lag_s);
  for (int i = 0; i < n; ++i) res.trials.front().simulation.impactor_m[i] = td.impactor_m[i] - 0.002;
  add_model6_prediction_intervals({td}, Model6FitOptions{}, res);
  EXPECT_NEAR(res.timing_discrepancy_s, 0.0, 1e-3 * lag_s);
  res.trials.front().simulation.impactor_m = td.impactor_m;
  add_model6_prediction_intervals({td}, Model6FitOptions{}, res);
  EXPECT_NEAR(res.timing_discrepancy_s, 0.0, 1e-12);
}

// A fit that ends with the densification strain at its bound, 1 (the
// column is not defined beyond it): every trial still gets its intervals,
// the densification strain's part of the peak's variance from the one
// side the law allows. Its SE against the secant over 1 % on that side:
// within 10 %.
TEST(Model6Intervals, DensificationStrainAtItsBoundStillPropagates) {
  Model6FitOptions o;
  o.model_discrepancy = false;
  Model6Params p;
  p.top.densification_strain = p.base.densification_strain = 1.0;
  const FoamLaw& t = p.top;
  const FoamLaw& b = p.base;
  Eigen::VectorXd u(15);
  u << std::log(t.plateau_pa), std::log(t.modulus_pa), std::log(t.hardening_pa), std::log(t.densification_pa), 0.0,
      std::log(b.plateau_pa), std::log(b.modulus_pa), std::log(b.hardening_pa), std::log(b.densification_pa),
      std::log(p.prony_g1), std::log(p.prony_tau1_s), std::log(p.prony_g2), std::log(p.prony_tau2_s),
      std::log(p.viscosity_pa_s), std::log(o.densification_exponent - 1.0);
  const Model6Params at = model6_params_at(u, o, false);
  TrialData td;
  td.id = "trial1";
  td.impact_velocity_m_s = 6.0;
  td.force_noise_n = 2.0;
  const double h = 1e-4;
  const int n = 1200;
  td.t_s = Eigen::VectorXd::LinSpaced(n, 0.0, (n - 1) * h);
  Impact imp;
  imp.mass_kg = td.impactor_mass_kg;
  imp.gravity_m_s2 = td.gravity_m_s2;
  imp.velocity_m_s = td.impact_velocity_m_s;
  imp.output_dt_s = h;
  imp.duration_s = (n - 1) * h + 0.5 * h;
  const Simulation s = simulate_model6(at, o.geometry, imp);
  td.grf_n = s.grf_n.head(n);
  td.impactor_m = s.impactor_m.head(n);
  Model6FitResult res;
  res.coordinates = u;
  res.params = at;
  res.coordinate_covariance = Eigen::MatrixXd::Zero(15, 15);
  const double sd = 0.01;
  res.coordinate_covariance(4, 4) = sd * sd;
  res.trials = {predict_model6(td, at, o)};
  add_model6_prediction_intervals({td}, o, res);
  EXPECT_TRUE(res.warnings.empty());
  const PredictionInterval& peak = res.trials.front().prediction.peak_force_n;
  ASSERT_TRUE(std::isfinite(peak.value));
  ASSERT_TRUE(std::isfinite(peak.se));
  Eigen::VectorXd below = u;
  below[4] = -sd;
  const Model6Result r0 = simulate_model6_detailed(at, o.geometry, imp);
  const Simulation s1 = simulate_model6(model6_params_at(below, o, false), o.geometry, imp);
  const double secant_n = std::abs(s.grf_n.maxCoeff() - s1.grf_n.maxCoeff());
  EXPECT_GT(r0.max_top_strain, 0.5);  // the impact reaches densification
  EXPECT_GT(secant_n, 10.0 * td.force_noise_n);
  EXPECT_NEAR(peak.se, secant_n, 0.1 * secant_n);
}

}  // namespace
}  // namespace dropfit::fitting
