// The residual-analysis toolkit on residuals whose structure the test builds:
// white noise must read as unstructured, a cubic residual must be traced to
// x^3, a sinusoid must give its frequency, and the statistics must match
// their textbook values.
#include "diagnosis/structure.h"

#include "core/error.h"

#include <gtest/gtest.h>

#include <cmath>
#include <vector>
#include <cstdio>
#include <numbers>
#include <random>

namespace dropfit::diagnosis {
namespace {

Eigen::VectorXd gaussian(int n, double sd, unsigned seed) {
  std::mt19937 rng(seed);
  std::normal_distribution<double> g(0.0, sd);
  Eigen::VectorXd v(n);
  for (int i = 0; i < n; ++i) v(i) = g(rng);
  return v;
}

// A mat-like impact: deformation rises and falls as a half sine of
// amplitude 0.1 m over 0.2 s (1 kHz), as the paper's trials do.
struct Impact {
  Eigen::VectorXd t, x, v;
};
Impact half_sine(int n = 200, double amplitude_m = 0.1, double duration_s = 0.2) {
  Impact s;
  s.t.resize(n);
  s.x.resize(n);
  s.v.resize(n);
  const double w = std::numbers::pi / duration_s;
  for (int i = 0; i < n; ++i) {
    s.t(i) = i * duration_s / n;
    s.x(i) = amplitude_m * std::sin(w * s.t(i));
    s.v(i) = amplitude_m * w * std::cos(w * s.t(i));
  }
  return s;
}

TEST(ChiSquare, MatchesTabulatedQuantiles) {
  // 95th percentiles from any chi-square table; dof 2 is exactly exp(-q/2).
  EXPECT_NEAR(chi_square_sf(3.841459, 1), 0.05, 1e-6);
  EXPECT_NEAR(chi_square_sf(18.307038, 10), 0.05, 1e-6);
  EXPECT_NEAR(chi_square_sf(31.410433, 20), 0.05, 1e-6);
  EXPECT_NEAR(chi_square_sf(2.0, 2), std::exp(-1.0), 1e-12);
  EXPECT_NEAR(chi_square_sf(40.0, 2), std::exp(-20.0), 1e-18);
  EXPECT_DOUBLE_EQ(chi_square_sf(0.0, 3), 1.0);
}

TEST(LinearFit, RecoversExactCoefficientsAndIntercept) {
  const Impact s = half_sine();
  Eigen::MatrixXd cols(s.x.size(), 2);
  cols << s.x, s.v;
  const Eigen::VectorXd y = (3.0 + 5000.0 * s.x.array() - 20.0 * s.v.array()).matrix();
  const LinearFit fit = linear_fit(cols, y);
  EXPECT_NEAR(fit.coefficients(0), 5000.0, 1e-6);
  EXPECT_NEAR(fit.coefficients(1), -20.0, 1e-9);
  EXPECT_NEAR(fit.intercept, 3.0, 1e-8);
  EXPECT_NEAR(fit.r2, 1.0, 1e-12);
}

TEST(LinearFit, RidgeShrinksTowardZero) {
  const Impact s = half_sine();
  Eigen::MatrixXd cols(s.x.size(), 1);
  cols << s.x;
  const Eigen::VectorXd y = 100.0 * s.x;
  // On unit-RMS columns the ridge solution is beta / (1 + ridge).
  EXPECT_NEAR(linear_fit(cols, y, 1.0).coefficients(0), 50.0, 1e-9);
}

TEST(Structure, WhiteNoiseReadsAsUnstructured) {
  const Impact s = half_sine(1000, 0.1, 1.0);
  const Eigen::VectorXd e = gaussian(1000, 50.0, 7);
  StructureOptions opt;
  opt.dt_s = 1e-3;
  const StructureReport rep = analyse_residual(e, state_candidates(s.t, s.x, s.v), opt);
  EXPECT_TRUE(rep.whiteness.white) << rep.summary();
  EXPECT_GT(rep.whiteness.p_value, 0.01);
  EXPECT_LT(std::abs(rep.whiteness.rho1()), 0.1);
  EXPECT_FALSE(rep.peak.significant);
  EXPECT_EQ(rep.best(), nullptr) << rep.summary();
  EXPECT_TRUE(rep.sparse.support.empty()) << rep.summary();
  EXPECT_FALSE(rep.structured) << rep.summary();
}

TEST(Structure, CubicResidualNamesXCubed) {
  // Five impacts (the five trials) with different amplitudes; the residual is
  // what a linear spring misses of F = k3 x^3, plus plate noise.
  std::vector<Eigen::VectorXd> parts;
  Eigen::VectorXd t(0), x(0), v(0);
  const double k3 = 4.0e6;  // N/m^3: 4000 N at 0.1 m
  int seed = 11;
  for (double a : {0.088, 0.099, 0.100, 0.113, 0.118}) {
    const Impact s = half_sine(200, a, 0.2);
    const Eigen::VectorXd e = (k3 * s.x.array().cube()).matrix() + gaussian(200, 20.0, seed++);
    parts.push_back(e);
    const Eigen::Index n0 = t.size();
    t.conservativeResize(n0 + 200);
    x.conservativeResize(n0 + 200);
    v.conservativeResize(n0 + 200);
    t.tail(200) = s.t;
    x.tail(200) = s.x;
    v.tail(200) = s.v;
  }
  StructureOptions opt;
  opt.dt_s = 1e-3;
  const StructureReport rep = analyse_residual(parts, state_candidates(t, x, v), opt);
  ASSERT_NE(rep.best(), nullptr);
  EXPECT_EQ(rep.best()->name, "x^3") << rep.summary();
  EXPECT_GT(rep.best()->share_alone, 0.9);
  EXPECT_GT(rep.explained_share, 0.9);
  EXPECT_TRUE(rep.structured);
  EXPECT_FALSE(rep.whiteness.white);
  const TermScore* cube = rep.find("x^3");
  ASSERT_NE(cube, nullptr);
  EXPECT_TRUE(cube->kept);
  EXPECT_EQ(rep.sparse.support.size(), 1u) << rep.summary();
  EXPECT_NEAR(cube->coefficient, k3, 0.03 * k3);
}

TEST(Structure, NuisanceColumnsAreProjectedOut) {
  // A linear model refitted to stiffening data absorbs part of x^3 into its
  // own k x; what is left must still be traced to x^3, not to x.
  const Impact s = half_sine(400, 0.1, 0.2);
  const Eigen::VectorXd cube = (4.0e6 * s.x.array().cube()).matrix();
  Eigen::MatrixXd nuisance(s.x.size(), 2);
  nuisance << s.x, s.v;
  const Eigen::VectorXd residual = project_out(nuisance, cube) + gaussian(400, 5.0, 3);
  const StructureReport rep = analyse_residual(residual, state_candidates(s.t, s.x, s.v), {}, nuisance);
  ASSERT_NE(rep.best(), nullptr);
  EXPECT_NE(rep.best()->name, "x");
  EXPECT_NE(rep.best()->name, "xdot");
  EXPECT_NEAR(rep.find("x")->share_alone, 0.0, 1e-9);
  EXPECT_GT(rep.find("x^3")->share_alone, 0.9) << rep.summary();
}

TEST(Structure, CentringSegmentsIsProjectingOutPerSegmentIntercepts) {
  // Six segments (trials) with their own offsets and a drift along a column
  // that also differs in level between segments: centring each segment
  // must give what the dense one-hot intercept columns give.
  std::vector<Eigen::VectorXd> segments;
  std::vector<int> lengths = {150, 90, 200, 120, 60, 180};
  int n = 0;
  for (int len : lengths) n += len;
  Eigen::VectorXd t(n), noise = gaussian(n, 1.0, 17);
  Eigen::MatrixXd one_hot = Eigen::MatrixXd::Zero(n, static_cast<Eigen::Index>(lengths.size()));
  int at = 0;
  for (std::size_t k = 0; k < lengths.size(); ++k) {
    Eigen::VectorXd seg(lengths[k]);
    for (int j = 0; j < lengths[k]; ++j) {
      t(at + j) = 0.3 * static_cast<double>(k) + 0.001 * j;
      one_hot(at + j, static_cast<Eigen::Index>(k)) = 1.0;
      seg(j) = 20.0 * static_cast<double>(k) - 7.0 + 40.0 * t(at + j) + noise(at + j);
    }
    segments.push_back(seg);
    at += lengths[k];
  }
  const std::vector<Candidate> candidates = {{"t", "time", t}, {"t2", "time squared", t.array().square().matrix()}};
  StructureOptions centred;
  centred.centre_segments = true;
  const StructureReport a = analyse_residual(segments, candidates, {}, one_hot);
  const StructureReport b = analyse_residual(segments, candidates, centred);
  for (const char* name : {"t", "t2"}) {
    EXPECT_NEAR(a.find(name)->r, b.find(name)->r, 1e-9) << name;
    EXPECT_NEAR(a.find(name)->coefficient, b.find(name)->coefficient, 1e-6 * std::abs(a.find(name)->coefficient));
  }
  EXPECT_GT(b.find("t")->share_alone, 0.1);  // the drift is seen within the segments
  EXPECT_NEAR(a.whiteness.q, b.whiteness.q, 1e-6 * a.whiteness.q);
  EXPECT_THROW(analyse_residual(segments, candidates, centred, one_hot), Error);
}

TEST(Structure, SparseFitFindsTwoTermsAmongNine) {
  // Coulomb-like friction plus a spring: 2000 x - 30 sign(xdot). (sign(xdot)
  // is the loading/unloading indicator up to the intercept.)
  const Impact s = half_sine(600, 0.1, 0.3);
  const Eigen::VectorXd y = (2000.0 * s.x.array()).matrix() - 30.0 * state_candidates(s.t, s.x, s.v)[2].values +
                            gaussian(600, 2.0, 5);
  const auto cands = state_candidates(s.t, s.x, s.v);
  Eigen::MatrixXd cols(600, static_cast<Eigen::Index>(cands.size()));
  for (std::size_t j = 0; j < cands.size(); ++j) cols.col(static_cast<Eigen::Index>(j)) = cands[j].values;
  const SparseFit fit = stlsq(cols, y);
  ASSERT_EQ(fit.support.size(), 2u);
  EXPECT_EQ(fit.support[0], 0);  // x
  EXPECT_EQ(fit.support[1], 2);  // sign(xdot)
  EXPECT_EQ(state_candidates(s.t, s.x, s.v)[2].name, "sign(xdot)");
  EXPECT_NEAR(fit.coefficients(0), 2000.0, 0.05 * 2000.0);
  EXPECT_NEAR(fit.coefficients(2), -30.0, 0.05 * 30.0);
  EXPECT_GT(fit.r2, 0.95);
}

TEST(Structure, SinusoidGivesItsFrequencyAndAmplitude) {
  // A force-plate frame ringing at 23.7 Hz (between Fourier bins) under noise.
  const int n = 1500;
  const double dt = 1e-3, f = 23.7, amp = 40.0;
  Eigen::VectorXd e = gaussian(n, 20.0, 9);
  for (int i = 0; i < n; ++i) e(i) += amp * std::sin(2.0 * std::numbers::pi * f * i * dt + 0.4);
  const PeriodicPeak peak = periodogram_peak(e, dt);
  EXPECT_TRUE(peak.significant);
  EXPECT_LT(peak.p_value, 1e-6);
  EXPECT_NEAR(peak.frequency_hz, f, 0.05);
  EXPECT_NEAR(peak.amplitude, amp, 0.05 * amp);
  // Variance share of the sinusoid: (amp^2 / 2) / (amp^2 / 2 + sd^2) = 2/3.
  EXPECT_NEAR(peak.share, 2.0 / 3.0, 0.03);
}

TEST(Structure, PeriodogramIgnoresTrendsAndFrequenciesBelowTheFloor) {
  const int n = 1000;
  const Eigen::VectorXd noise = gaussian(n, 1.0, 21);
  Eigen::VectorXd trend = noise, bowl = noise;
  for (int i = 0; i < n; ++i) {
    trend(i) += 0.05 * i;                              // a drift, not a period
    bowl(i) += 4.0 * std::pow((i - 500.0) / 500.0, 2);  // a slow bow
  }
  EXPECT_FALSE(periodogram_peak(trend, 1e-3).significant);
  EXPECT_TRUE(periodogram_peak(bowl, 1e-3).significant);
  EXPECT_LT(periodogram_peak(bowl, 1e-3).frequency_hz, 3.0);
  EXPECT_FALSE(periodogram_peak(bowl, 1e-3, 0.01, 20.0).significant);
}

// Four held-out trials' force residuals over their contacts (55-65 samples
// at 1 kHz): the plate rings at 152.5 Hz after each impact (rising over
// 3 ms, decaying over 30 ms, its phase differing from trial to trial), each
// trial also carries a misfit of its own at 30-80 Hz, about as strong as the
// ringing, and 3 N of noise. One short segment's bins are 16-18 Hz apart and
// its strongest bin may be the misfit's; the sum over the trials finds the
// ringing within 1 %.
TEST(Structure, ACommonPeriodStandsOutOfShortSegments) {
  const double dt = 1e-3, f = 152.5;
  std::vector<Eigen::VectorXd> segs;
  const int lengths[] = {55, 61, 65, 58};
  const double misfit_hz[] = {32.0, 63.0, 47.0, 78.0};
  for (int s = 0; s < 4; ++s) {
    Eigen::VectorXd e = gaussian(lengths[s], 3.0, 100 + s);
    for (int i = 0; i < e.size(); ++i) {
      const double t = i * dt;
      const double env = (1.0 - std::exp(-t / 0.003)) * std::exp(-t / 0.030);
      e(i) += 25.0 * env * std::sin(2.0 * std::numbers::pi * f * t + 0.9 * s);
      e(i) += 12.0 * std::sin(2.0 * std::numbers::pi * misfit_hz[s] * t + 1.7 * s);
    }
    segs.push_back(e);
  }
  const PeriodicPeak common = common_periodic_peak(segs, dt, 0.01, 5.0);
  EXPECT_TRUE(common.significant);
  EXPECT_LT(common.p_value, 1e-6);
  EXPECT_NEAR(common.frequency_hz, f, 0.01 * f);
  EXPECT_GT(common.share, 0.2);
  EXPECT_LT(common.share, 0.8);
}

// White segments of those lengths: at alpha = 0.01 the common peak is
// called significant in at most 2 % of 400 draws (Bonferroni over the
// oversampled grid keeps it near or below alpha).
TEST(Structure, WhiteSegmentsRarelyShowACommonPeriod) {
  int significant = 0;
  for (unsigned draw = 0; draw < 400; ++draw) {
    std::vector<Eigen::VectorXd> segs;
    for (int s = 0; s < 4; ++s) segs.push_back(gaussian(55 + 3 * s, 3.0, 1000 + 7 * draw + s));
    significant += common_periodic_peak(segs, 1e-3, 0.01, 5.0).significant;
  }
  std::printf("white segments: %d of 400 draws significant at alpha = 0.01\n", significant);
  EXPECT_LE(significant, 8);
}

TEST(Whiteness, Ar1ResidualIsStructuredWithItsRho) {
  const int n = 3000;
  const double phi = 0.8;
  const Eigen::VectorXd w = gaussian(n, 1.0, 13);
  Eigen::VectorXd e(n);
  e(0) = w(0);
  for (int i = 1; i < n; ++i) e(i) = phi * e(i - 1) + w(i);
  const Whiteness wt = ljung_box(e, 20);
  EXPECT_FALSE(wt.white);
  EXPECT_LT(wt.p_value, 1e-10);
  EXPECT_NEAR(wt.rho1(), phi, 0.04);
  EXPECT_NEAR(wt.acf(1), phi * phi, 0.05);
  // N (1 - rho) / (1 + rho) = 3000 * 0.2 / 1.8.
  EXPECT_NEAR(effective_sample_size(n, 0.8), 333.33, 0.01);
  EXPECT_DOUBLE_EQ(effective_sample_size(n, -0.3), n);
}

TEST(Whiteness, SegmentsArePooledWithoutStraddling) {
  // Two white segments at different levels: concatenated as one series they
  // look like a step (strongly autocorrelated) about the overall mean, but
  // pooled per segment about each segment's deviation the lag products do
  // not cross the boundary. The pooled statistic matches the hand sum.
  const Eigen::VectorXd a = gaussian(500, 1.0, 17), b = gaussian(500, 1.0, 19);
  const Eigen::VectorXd acf = autocorrelation(std::vector<Eigen::VectorXd>{a, b}, 1);
  Eigen::VectorXd all(1000);
  all << a, b;
  const double m = all.mean();
  double c0 = (all.array() - m).square().sum();
  double c1 = ((a.head(499).array() - m) * (a.tail(499).array() - m)).sum() +
              ((b.head(499).array() - m) * (b.tail(499).array() - m)).sum();
  EXPECT_NEAR(acf(0), c1 / c0, 1e-12);
}

TEST(InformationCriteria, FormulasByHand) {
  const InformationCriteria ic = information_criteria(50.0, 100.0, 3);
  const double ll = 100.0 * std::log(0.5);
  EXPECT_NEAR(ic.aic, ll + 6.0, 1e-12);
  EXPECT_NEAR(ic.aicc, ll + 6.0 + 24.0 / 96.0, 1e-12);
  EXPECT_NEAR(ic.bic, ll + 3.0 * std::log(100.0), 1e-12);
  EXPECT_TRUE(std::isinf(information_criteria(1.0, 4.0, 3).aicc));
}

TEST(InformationCriteria, CompareModelsSupportsARealTermOnly) {
  const Impact s = half_sine(500, 0.1, 0.25);
  const Eigen::VectorXd noise = gaussian(500, 10.0, 23);
  const Eigen::VectorXd y = (5.0e6 * s.x.array().cube()).matrix() + noise;
  Eigen::MatrixXd one(500, 1), two(500, 2);
  one << s.x;
  two << s.x, s.x.array().cube().matrix();
  const LinearFit small = linear_fit(one, y), large = linear_fit(two, y);
  const Eigen::VectorXd large_res = y - two * large.coefficients - Eigen::VectorXd::Constant(500, large.intercept);
  const ModelComparison real =
      compare_models(small.rss, 2, large.rss, 3, 500, autocorrelation(large_res, 1)(0), Criterion::AICc);
  EXPECT_TRUE(real.larger_supported);
  EXPECT_LT(real.delta, -10.0);

  // A column of pure noise adds a parameter and (almost) nothing else.
  Eigen::MatrixXd junk(500, 3);
  junk << two, gaussian(500, 1.0, 29);
  const LinearFit larger = linear_fit(junk, y);
  const ModelComparison none = compare_models(large.rss, 3, larger.rss, 4, 500, 0.0, Criterion::BIC);
  EXPECT_FALSE(none.larger_supported);
  EXPECT_GT(none.delta, 0.0);
}

TEST(PairedImprovement, NeedsAConsistentDrop) {
  Eigen::VectorXd before(5), after(5), mixed(5);
  before << 4.0, 2.0, 1.0, 3.0, 9.6;
  after << 1.0, 0.9, 0.8, 1.1, 1.5;
  mixed << 4.5, 1.0, 1.4, 2.0, 9.9;
  const PairedImprovement good = paired_improvement(before, after);
  EXPECT_TRUE(good.significant);
  EXPECT_NEAR(good.mean_drop, (19.6 - 5.3) / 5.0, 1e-12);
  EXPECT_FALSE(paired_improvement(before, mixed).significant);
  EXPECT_FALSE(paired_improvement(before, after, 2.0, 0.1, 5.0).significant);  // below the noise floor
}

// Three held-out trials whose errors each fall by a factor of 33-44, one
// of them carrying most of the error: the differences' t is 1.32 (below
// 2), the logarithms' 43.6 (ratios 40, 33.3 and 44.4: logs 3.689, 3.507,
// 3.794, mean 3.663, SD 0.145). A pair with a zero error is left out, and
// fewer than three pairs give NaN.
TEST(PairedImprovement, OnTheLogarithmsSeesALikeFactor) {
  const std::vector<double> before{20.0, 60.0, 400.0}, after{0.5, 1.8, 9.0};
  const PairedImprovement raw = paired_improvement(Eigen::Map<const Eigen::VectorXd>(before.data(), 3),
                                                   Eigen::Map<const Eigen::VectorXd>(after.data(), 3));
  EXPECT_NEAR(raw.t, 1.32, 0.01);
  EXPECT_FALSE(raw.significant);
  EXPECT_NEAR(log_paired_t(before, after), 43.6, 0.1);
  EXPECT_TRUE(std::isnan(log_paired_t({20.0, 60.0, 0.0}, {0.5, 1.8, 9.0})));
  EXPECT_TRUE(std::isnan(log_paired_t({20.0, 60.0}, {0.5, 1.8})));
}

}  // namespace
}  // namespace dropfit::diagnosis
