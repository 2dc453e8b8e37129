// The fitter (fitting/fit.h), the key characteristics and the annealer:
// parameters recovered from sessions simulated here with known truth,
// characteristics of hand-computable signals, and the paper's Table 1
// pattern in table mode.
#include <gtest/gtest.h>

#include <atomic>

#include <cmath>
#include <fstream>
#include <random>
#include <sstream>
#include <string>

#include "core/error.h"
#include "fitting/anneal.h"
#include "fitting/characteristics.h"
#include "fitting/fit.h"
#include "fitting/table_fit.h"

namespace dropfit::fitting {
namespace {

const double kVelocities[] = {4.30, 4.80, 5.25, 5.75, 6.50};

// Five trials simulated with `truth`, optionally with Gaussian noise on
// the force and on the marker-derived travel.
std::vector<TrialData> make_trials(ModelKind kind, const MatParams& truth, double force_noise_n = 0.0,
                                   double marker_noise_m = 0.0, unsigned seed = 7, double first_sample_s = 0.0) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> nd(0.0, 1.0);
  std::vector<TrialData> trials;
  for (int i = 0; i < 5; ++i) {
    Impact imp;
    imp.velocity_m_s = kVelocities[i];
    imp.duration_s = 0.15;
    imp.first_output_s = first_sample_s;
    const Simulation s = simulate(kind, truth, imp);
    TrialData t;
    t.id = "trial" + std::to_string(i + 1);
    t.impact_velocity_m_s = kVelocities[i];
    t.t_s = s.t_s;
    t.grf_n = s.grf_n;
    t.impactor_m = s.impactor_m;
    t.surface_m = s.surface_m;
    for (Eigen::Index j = 0; j < t.t_s.size(); ++j) {
      t.grf_n[j] += force_noise_n * nd(rng);
      t.impactor_m[j] += marker_noise_m * nd(rng);
      t.surface_m[j] += marker_noise_m * nd(rng);
    }
    trials.push_back(t);
  }
  return trials;
}

MatParams truth_for(ModelKind kind) {
  MatParams p = paper_table2(kind, 1.5);
  // The paper's Models 1-2 are overdamped and never leave the mat; a
  // lighter damping gives a full contact to fit.
  if (kind == ModelKind::Model1 || kind == ModelKind::Model2) p.r1_n_s_m = 600.0;
  return p;
}

double rel_err(const MatParams& fit, const MatParams& truth, const std::string& name) {
  return std::abs(get_parameter(fit, name) / get_parameter(truth, name) - 1.0);
}

TEST(Fit, RecoversParametersFromNoiseFreeDataWithin1Percent) {
  for (ModelKind kind : {ModelKind::Model1, ModelKind::Model2, ModelKind::Model3, ModelKind::Model4}) {
    const MatParams truth = truth_for(kind);
    FitOptions o;
    o.model = kind;
    o.sensitivity = false;
    const FitResult r = fit(make_trials(kind, truth), o);
    EXPECT_EQ(r.train_ids, std::vector<std::string>{"trial3"});  // median velocity
    for (const auto& name : parameter_names(kind, kind == ModelKind::Model2))
      EXPECT_LT(rel_err(r.params, truth, name), 0.01) << model_name(kind) << " " << name;
    for (const auto& t : r.trials) EXPECT_LT(std::abs(t.comparison.peak_force_pct_diff), 0.1) << t.id;
  }
}

TEST(Fit, RecoversParametersWithRealisticNoiseWithin5Percent) {
  // Force noise 20 N, marker noise 0.5 mm; Models 1-3 from one trial.
  for (ModelKind kind : {ModelKind::Model1, ModelKind::Model2, ModelKind::Model3}) {
    const MatParams truth = truth_for(kind);
    FitOptions o;
    o.model = kind;
    o.sensitivity = false;
    const FitResult r = fit(make_trials(kind, truth, 20.0, 0.0005), o);
    for (const auto& name : parameter_names(kind, kind == ModelKind::Model2))
      EXPECT_LT(rel_err(r.params, truth, name), 0.05) << model_name(kind) << " " << name;
  }
  // Model 4 jointly over the five trials (one trial leaves r2 at ~10 % SE:
  // the GRF hardly depends on it). Every estimate within 5 %, and within
  // 3 standard errors of the truth.
  const MatParams truth = truth_for(ModelKind::Model4);
  FitOptions o;
  o.model = ModelKind::Model4;
  o.sensitivity = false;
  o.train_ids = {"trial1", "trial2", "trial3", "trial4", "trial5"};
  const FitResult r = fit(make_trials(ModelKind::Model4, truth, 20.0, 0.0005), o);
  for (const auto& e : r.estimates) {
    if (!e.free) continue;
    const double truth_v = get_parameter(truth, e.name);
    EXPECT_LT(std::abs(e.value / truth_v - 1.0), 0.05) << e.name;
    EXPECT_LT(std::abs(e.value - truth_v), 3.0 * e.se) << e.name;
    EXPECT_TRUE(e.identifiable) << e.name;
  }
}

TEST(Fit, LayerMassesFreeWithTheirTotalFixed) {
  MatParams truth = truth_for(ModelKind::Model4);
  truth.m1_kg = 2.0;
  truth.m2_kg = 4.1;
  FitOptions o;
  o.model = ModelKind::Model4;
  o.masses_free = true;
  o.m1_kg = 3.0;  // wrong split, right total
  o.m2_kg = 3.1;
  o.sensitivity = false;
  const FitResult r = fit(make_trials(ModelKind::Model4, truth), o);
  EXPECT_NEAR(r.params.m1_kg, 2.0, 0.02);
  EXPECT_NEAR(r.params.m1_kg + r.params.m2_kg, 6.1, 1e-12);
  EXPECT_LT(rel_err(r.params, truth, "k2_n_m"), 0.01);
}

// A mat whose force at depth is mostly its cubic term: the linear k1 lies
// below the series springs' floor (0.3 x peak force / largest travel), and
// the stiffening element meets that floor with its secant, not with k1.
// Before, k1 sat on the floor and the fit ended 7x the truth's cost with
// r2 at 60 % of the truth (an independent-world session, seed 917; its
// training trial then read as hysteresis). Parameters of that session.
TEST(Fit, AStiffeningMatsLinearPartMayLieBelowTheSeriesFloor) {
  MatParams truth = paper_table2(ModelKind::Model4);
  truth.k1_n_m = 21118.0;
  truth.k2_n_m = 1.1508e6;
  truth.k3_n_m = 9.633e5;
  truth.r1_n_s_m = 69.9;
  truth.r2_n_s_m = 297.5;
  truth.r3_n_s_m = 181.9;
  truth.k1_cubic_n_m3 = 7.10e6;
  const std::vector<TrialData> trials = make_trials(ModelKind::Model4, truth, 3.0, 0.0002);
  // The premise: on the training trial (trial3) k1 is under the floor.
  const TrialData& t3 = trials[2];
  const double k_eff = t3.grf_n.maxCoeff() / t3.impactor_m.maxCoeff();
  FitOptions o;
  o.model = ModelKind::Model4;
  o.sensitivity = false;
  o.free_effects = {"k1_cubic_n_m3"};
  o.force_noise_n = 3.0;
  o.marker_noise_m = 0.0002;
  ASSERT_LT(truth.k1_n_m, o.k_eff_lower_ratio * k_eff);
  const FitResult r = fit(trials, o);
  EXPECT_LT(rel_err(r.params, truth, "k1_n_m"), 0.02);
  EXPECT_LT(rel_err(r.params, truth, "k1_cubic_n_m3"), 0.02);
  EXPECT_LT(rel_err(r.params, truth, "k2_n_m"), 0.10);
  for (const auto& c : r.channels) EXPECT_LT(c.rms_sigma, 1.3) << c.name;  // at the noise
  for (const auto& e : r.estimates)
    if (e.name == "k1_n_m") EXPECT_FALSE(e.at_bound);
}

// A parameter the data cannot see is reported: with element 2 far
// stiffer than the rest, any larger k2 fits as well.
TEST(Fit, ReportsParametersTheDataDoNotPinDown) {
  MatParams truth = truth_for(ModelKind::Model4);
  truth.k2_n_m = 3e7;
  FitOptions o;
  o.model = ModelKind::Model4;
  o.sensitivity = false;
  o.k_max_n_m = 1e8;  // bounds up to 1e9
  o.starts = 3;
  const FitResult r = fit(make_trials(ModelKind::Model4, truth, 20.0, 0.0005), o);
  bool k2_flagged = false;
  for (const auto& e : r.estimates)
    if (e.name == "k2_n_m") k2_flagged = !e.identifiable;
  EXPECT_TRUE(k2_flagged) << r.report();
  for (const auto& e : r.estimates) {
    if (e.name == "k1_n_m" || e.name == "k3_n_m") {
      EXPECT_TRUE(e.identifiable) << e.name;
    }
  }
}

// Ceres and Corana annealing minimise the same objective to the same point.
TEST(Fit, CeresAndAnnealingReachTheSameOptimum) {
  const MatParams truth = truth_for(ModelKind::Model1);
  const auto trials = make_trials(ModelKind::Model1, truth, 40.0, 0.001, 11);
  FitOptions o;
  o.model = ModelKind::Model1;
  o.sensitivity = false;
  const FitResult a = fit(trials, o);
  o.optimizer = Optimizer::Annealing;
  o.anneal.nt = 5;
  o.anneal.rt = 0.5;
  o.anneal.eps = 1e-9;
  const FitResult b = fit(trials, o);
  for (const auto& name : parameter_names(ModelKind::Model1, false))
    EXPECT_LT(rel_err(b.params, a.params, name), 0.01) << name;
  EXPECT_NEAR(b.cost, a.cost, 1e-3 * a.cost);
  EXPECT_GT(std::abs(a.params.k1_n_m / truth.k1_n_m - 1.0), 1e-5);  // the noise moved the optimum
}

// A user's model is fitted through a simulate callback with numeric
// differences; a callback wrapping Model 3 must find Model 3's parameters.
TEST(Fit, FitsThroughASimulatorCallback) {
  const MatParams truth = truth_for(ModelKind::Model3);
  FitOptions o;
  o.model = ModelKind::Model3;
  o.sensitivity = false;
  o.starts = 3;
  std::atomic<int> calls = 0;  // the fitter calls the simulator from several threads
  o.simulator = [&calls](const MatParams& p, const Impact& imp) {
    ++calls;
    return simulate(ModelKind::Model3, p, imp);
  };
  const FitResult r = fit(make_trials(ModelKind::Model3, truth), o);
  for (const auto& name : parameter_names(ModelKind::Model3, false))
    EXPECT_LT(rel_err(r.params, truth, name), 0.01) << name;
  EXPECT_GT(calls, 20);

  // A simulator that keeps its own grid (0.1 ms from contact, ignoring
  // first_output_s) is interpolated onto the trial's samples, which here
  // start 0.4 ms after contact.
  o.simulator = [](const MatParams& p, const Impact& imp) {
    Impact own = imp;
    own.first_output_s = 0.0;
    own.output_dt_s = imp.output_dt_s / 10.0;
    return simulate(ModelKind::Model3, p, own);
  };
  const FitResult shifted = fit(make_trials(ModelKind::Model3, truth, 0.0, 0.0, 7, 4e-4), o);
  for (const auto& name : parameter_names(ModelKind::Model3, false))
    EXPECT_LT(rel_err(shifted.params, truth, name), 0.01) << name;
  EXPECT_LT(std::abs(shifted.trials[0].comparison.peak_force_pct_diff), 0.1);
}

TEST(Fit, JointFitPredictionsLeaveOneOutAndSensitivity) {
  const MatParams truth = truth_for(ModelKind::Model3);
  FitOptions o;
  o.model = ModelKind::Model3;
  o.leave_one_out = true;
  o.starts = 2;
  o.train_ids = {"trial1", "trial5"};
  const FitResult r = fit(make_trials(ModelKind::Model3, truth), o);
  ASSERT_EQ(r.trials.size(), 5u);
  EXPECT_TRUE(r.trials[0].train && r.trials[4].train && !r.trials[2].train);
  for (const auto& t : r.trials) {
    EXPECT_LT(std::abs(t.comparison.peak_force_pct_diff), 0.1) << t.id;
    EXPECT_LT(t.comparison.rms_force_pct_peak, 0.1) << t.id;
    EXPECT_LT(std::abs(t.max_deformation_mm_diff), 0.05) << t.id;
  }
  ASSERT_EQ(r.leave_one_out.size(), 5u);
  for (const auto& l : r.leave_one_out) EXPECT_LT(std::abs(l.comparison.peak_force_pct_diff), 0.1) << l.held_out;
  // Stiffer top element: higher peak. The values are those of re-simulating.
  ASSERT_EQ(r.sensitivity.size(), 4u);
  EXPECT_EQ(r.sensitivity[0].name, "k1_n_m");
  EXPECT_GT(r.sensitivity[0].peak_pct_plus10, 1.0);
  EXPECT_LT(r.sensitivity[0].peak_pct_minus10, -1.0);
  Impact imp;
  imp.velocity_m_s = 5.25;
  MatParams hi = r.params;
  hi.k1_n_m *= 1.1;
  const double base = simulate(ModelKind::Model3, r.params, imp).grf_n.maxCoeff();
  EXPECT_NEAR(r.sensitivity[0].peak_pct_plus10,
              100.0 * (simulate(ModelKind::Model3, hi, imp).grf_n.maxCoeff() - base) / base, 0.2);
}

TEST(Fit, BadInputThrows) {
  const auto trials = make_trials(ModelKind::Model1, truth_for(ModelKind::Model1));
  FitOptions o;
  o.model = ModelKind::Model1;
  o.train_ids = {"trial9"};
  EXPECT_THROW(fit(trials, o), Error);
  std::vector<TrialData> none = trials;
  for (auto& t : none) t.accepted = false;
  o.train_ids.clear();
  EXPECT_THROW(fit(none, o), Error);
  std::vector<TrialData> ragged = trials;
  ragged[2].grf_n.conservativeResize(10);
  EXPECT_THROW(fit(ragged, o), Error);
}

// ---------------------------------------------------------------------------
// Key characteristics on signals whose answers are known by hand.

TEST(Characteristics, TwoPeakPiecewiseLinearSignal) {
  // 0 -> 3000 N at 10 ms, down to 2000 N at 15 ms, up to 5000 N at 30 ms,
  // down to 0 at 60 ms; 1 kHz.
  const int n = 61;
  Eigen::VectorXd t(n), f(n);
  for (int i = 0; i < n; ++i) {
    t[i] = 1e-3 * i;
    if (i <= 10) f[i] = 300.0 * i;
    else if (i <= 15) f[i] = 3000.0 - 200.0 * (i - 10);
    else if (i <= 30) f[i] = 2000.0 + 200.0 * (i - 15);
    else f[i] = 5000.0 - (5000.0 / 30.0) * (i - 30);
  }
  const Characteristics c = characteristics(t, f);
  EXPECT_EQ(c.n_peaks, 2);
  EXPECT_DOUBLE_EQ(c.peak_force_n, 5000.0);
  EXPECT_DOUBLE_EQ(c.time_to_peak_s, 0.030);
  EXPECT_DOUBLE_EQ(c.first_peak_n, 3000.0);
  EXPECT_DOUBLE_EQ(c.first_peak_s, 0.010);
  EXPECT_DOUBLE_EQ(c.second_peak_n, 5000.0);
  EXPECT_DOUBLE_EQ(c.second_peak_s, 0.030);
  EXPECT_DOUBLE_EQ(c.min_between_n, 2000.0);
  EXPECT_DOUBLE_EQ(c.min_between_s, 0.015);
  EXPECT_NEAR(c.max_loading_rate_n_s, 300000.0, 1e-6);
  EXPECT_GE(c.max_loading_rate_s, 0.0);  // any sample of the first ramp
  EXPECT_LT(c.max_loading_rate_s, 0.010);
}

TEST(Characteristics, HalfSineHasOnePeakAndItsLoadingRate) {
  const double A = 7000.0, T = 0.08, dt = 1e-3;
  const int n = 81;
  Eigen::VectorXd t(n), f(n);
  for (int i = 0; i < n; ++i) {
    t[i] = i * dt;
    f[i] = A * std::sin(M_PI * t[i] / T);
  }
  const Characteristics c = characteristics(t, f);
  EXPECT_EQ(c.n_peaks, 1);
  EXPECT_NEAR(c.peak_force_n, A, 1e-9);
  EXPECT_NEAR(c.time_to_peak_s, 0.040, 1e-12);
  EXPECT_NEAR(c.first_peak_n, A, 1e-9);
  EXPECT_TRUE(std::isnan(c.second_peak_n));
  EXPECT_TRUE(std::isnan(c.min_between_n));
  // Steepest at the start: the one-sided difference A sin(pi dt / T) / dt.
  EXPECT_NEAR(c.max_loading_rate_n_s, A * std::sin(M_PI * dt / T) / dt, 1e-6);
  EXPECT_DOUBLE_EQ(c.max_loading_rate_s, 0.0);

  // A simulation 10 % high everywhere: RMS = 0.1 * RMS(f), peak +10 %.
  const ForceComparison cmp = compare_forces(t, f, Eigen::VectorXd(1.1 * f));
  const double rms_f = std::sqrt(f.squaredNorm() / n);
  EXPECT_NEAR(cmp.rms_force_pct_peak, 100.0 * 0.1 * rms_f / A, 1e-9);
  EXPECT_NEAR(cmp.peak_force_pct_diff, 10.0, 1e-9);
  EXPECT_NEAR(cmp.time_to_peak_ms_diff, 0.0, 1e-9);
  // Shifted 3 samples later: time to peak +3 ms.
  Eigen::VectorXd late(n);
  for (int i = 0; i < n; ++i) late[i] = A * std::sin(M_PI * std::max(t[i] - 0.003, 0.0) / T);
  EXPECT_NEAR(compare_forces(t, f, late).time_to_peak_ms_diff, 3.0, 1e-9);
}

TEST(Characteristics, SmallWigglesAreNotPeaks) {
  // A ramp with a 1 % dip: below the 3 % prominence, one peak only.
  Eigen::VectorXd t(5), f(5);
  t << 0, 1, 2, 3, 4;
  f << 0, 1000, 990, 1000.5, 0;
  EXPECT_EQ(characteristics(t, f).n_peaks, 1);
  f << 0, 1000, 900, 1001, 0;  // 10 % dip: two
  const Characteristics c = characteristics(t, f);
  EXPECT_EQ(c.n_peaks, 2);
  EXPECT_DOUBLE_EQ(c.min_between_n, 900.0);
  // A peak on the first sample (a damper's jump at contact) counts.
  f << 5000, 4000, 3000, 1000, 0;
  const Characteristics d = characteristics(t, f);
  EXPECT_EQ(d.n_peaks, 1);
  EXPECT_DOUBLE_EQ(d.first_peak_n, 5000.0);
  EXPECT_DOUBLE_EQ(d.first_peak_s, 0.0);
  EXPECT_THROW(characteristics(t.head(2), f.head(2)), Error);
}

// ---------------------------------------------------------------------------
// Annealing alone, on a function with known minimum.
TEST(Anneal, FindsTheGlobalMinimumOfAMultimodalFunction) {
  // Rastrigin-like in 2-D, minimum 0 at (1, -2), many local minima.
  auto f = [](const Eigen::VectorXd& x) {
    const double a = x[0] - 1.0, b = x[1] + 2.0;
    return a * a + b * b + 3.0 * (2.0 - std::cos(2 * M_PI * a) - std::cos(2 * M_PI * b));
  };
  Eigen::VectorXd lo(2), hi(2), x0(2);
  lo << -5, -5;
  hi << 5, 5;
  x0 << 4, 4;
  AnnealOptions o;
  o.nt = 20;
  const AnnealResult r = anneal(f, x0, lo, hi, o);
  EXPECT_TRUE(r.converged);
  EXPECT_NEAR(r.x[0], 1.0, 1e-3);
  EXPECT_NEAR(r.x[1], -2.0, 1e-3);
  EXPECT_THROW(anneal(f, x0, hi, lo, o), Error);
}

// ---------------------------------------------------------------------------
// The paper's Table 1 in table mode: a linear model fitted to trial 3's
// peak force and deformation over-predicts the slow trial and
// under-predicts the fast one (the paper: +4.0 % and -9.6 % with Model 4).

std::vector<TableTrial> read_table1() {
  std::ifstream in(DROPFIT_SOURCE_DIR "/samples/paper/table1.csv");
  EXPECT_TRUE(in.good()) << "samples/paper/table1.csv";
  std::vector<TableTrial> out;
  std::string line;
  std::getline(in, line);
  EXPECT_EQ(line, "trial,impact_velocity_m_s,max_deformation_m,peak_force_n");
  while (std::getline(in, line)) {
    if (line.empty()) continue;
    std::stringstream ss(line);
    std::string cell[4];
    for (auto& c : cell) std::getline(ss, c, ',');
    TableTrial t;
    t.id = "trial" + cell[0];
    t.impact_velocity_m_s = std::stod(cell[1]);
    t.max_deformation_m = std::stod(cell[2]);
    t.peak_force_n = std::stod(cell[3]);
    out.push_back(t);
  }
  return out;
}

TEST(TableMode, LinearModelOnTrial3OverPredictsTrial1AndUnderPredictsTrial5) {
  const auto table = read_table1();
  ASSERT_EQ(table.size(), 5u);
  TableFitOptions o;
  o.model = ModelKind::Model1;
  o.base.k1_n_m = 80000.0;
  o.base.r1_n_s_m = 500.0;
  const TableFitResult r = fit_table(table, o);
  ASSERT_EQ(r.trials.size(), 5u);
  EXPECT_TRUE(r.trials[2].train);
  // Trial 3 itself is matched: both of its numbers, two parameters.
  EXPECT_NEAR(r.trials[2].simulated_peak_force_n, 7054.0, 1.0);
  EXPECT_NEAR(r.trials[2].simulated_max_deformation_m, 0.100, 1e-4);
  EXPECT_GT(r.trials[0].peak_force_pct_diff, 1.0);
  EXPECT_LT(r.trials[4].peak_force_pct_diff, -5.0);
  // Any other optimum that fits as well is a mat too (the gate) and
  // predicts the same pattern.
  EXPECT_TRUE(r.refused.empty()) << r.refused;
  for (const MatParams& p : r.alternatives) {
    EXPECT_EQ(table_degenerate(o, p, 5.25), "");
    Impact imp;
    imp.output_dt_s = 5e-4;
    imp.velocity_m_s = 4.30;
    EXPECT_GT(simulate(ModelKind::Model1, p, imp).grf_n.maxCoeff(), 5593.0 * 1.01);
    imp.velocity_m_s = 6.50;
    EXPECT_LT(simulate(ModelKind::Model1, p, imp).grf_n.maxCoeff(), 9597.0 * 0.95);
  }
  // Without gravity a linear model's peak force is proportional to the
  // impact velocity; the measured peaks grow faster (5593 -> 9597 N for
  // 4.30 -> 6.50 m/s), hence the pattern.
  o.gravity_m_s2 = 0.0;
  const TableFitResult r0 = fit_table(table, o);
  EXPECT_NEAR(r0.trials[4].simulated_peak_force_n / r0.trials[0].simulated_peak_force_n, 6.50 / 4.30, 2e-3);
  EXPECT_GT(9597.0 / 5593.0, 1.1 * 6.50 / 4.30);
}

// Model 1 on Table 1 as `dropfit table` fits it (the paper's Table 2 as a
// start: r1 5700 N s/m, far above critical). Two numbers and two
// parameters also admit a soft spring under a strong damper (k1 2.2 kN/m,
// r1 1344 N s/m) whose force peaks at contact (r1 v0 = 7054 N) and whose
// impactor never leaves the mat; the bounds from the data and the gate
// must give the spring instead.
TEST(TableMode, Model1OnTable1IsTheSpringThatStoresTheImpactNotADamper) {
  const auto table = read_table1();
  ASSERT_EQ(table.size(), 5u);
  const TableFitOptions o = table_options(ModelKind::Model1, 24.0, 2.44, 3.66);
  const TableFitResult r = fit_table(table, o);
  ASSERT_TRUE(r.refused.empty()) << r.refused;
  EXPECT_TRUE(r.trials[2].train);
  // Physics: trial 3 (M 24 kg, v 5.25 m/s, x 0.100 m, F 7054 N) stores its
  // impact almost without loss at maximum compression: 1/2 F x = 352.7 J
  // against 1/2 M v^2 + M g x = 354.3 J (0.5 % apart). A linear spring that
  // reaches that force at that travel has k1 = F / x = 70.5 kN/m and little
  // damping. 3 %: the fit also carries gravity and a small damping (each
  // moves k1 by well under 1 % here), far inside the 97 % gap to the
  // damper-dominated optimum.
  const double k_spring = 7054.0 / 0.100;
  EXPECT_NEAR(r.params.k1_n_m, k_spring, 0.03 * k_spring);
  EXPECT_LT(r.params.r1_n_s_m, 0.1 * 2.0 * std::sqrt(k_spring * 24.0)) << "well under critical damping";
  EXPECT_NEAR(r.trials[2].simulated_peak_force_n, 7054.0, 0.01 * 7054.0);
  EXPECT_EQ(table_degenerate(o, r.params, 5.25), "");

  // The gate names what is wrong with the damper-dominated mat.
  MatParams damper = o.base;
  damper.k1_n_m = 2202.0;
  damper.r1_n_s_m = 1344.0;
  EXPECT_NE(table_degenerate(o, damper, 5.25).find("comes at contact"), std::string::npos)
      << table_degenerate(o, damper, 5.25);
  // The second reason: the fitted mat holds the impactor for about 58 ms
  // (half a period, pi sqrt(M / k1)); asked to release it within 20 ms, the
  // gate says it never leaves.
  TableFitOptions short_horizon = o;
  short_horizon.rebound_horizon_s = 0.02;
  EXPECT_NE(table_degenerate(short_horizon, r.params, 5.25).find("never leaves"), std::string::npos)
      << table_degenerate(short_horizon, r.params, 5.25);
}

// With no optimum that passes the gate, fit_table refuses instead of
// returning one: here the gate asks for a peak 10 s after contact, which no
// optimum (simulated for 1 s) can give.
TEST(TableMode, NoOptimumThatPassesTheGateIsARefusalWithTheReason) {
  const auto table = read_table1();
  TableFitOptions o = table_options(ModelKind::Model1, 24.0, 2.44, 3.66);
  o.contact_peak_s = 10.0;
  const TableFitResult r = fit_table(table, o);
  EXPECT_NE(r.refused.find("comes at contact"), std::string::npos) << r.refused;
  ASSERT_FALSE(r.warnings.empty());
  EXPECT_NE(r.warnings.front().find("no optimum is a physical mat"), std::string::npos) << r.warnings.front();
}

}  // namespace
}  // namespace dropfit::fitting
