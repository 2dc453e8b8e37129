// Model 6's uncertainty calibrations (fitting/model6_calibration.h): the
// cross-validated discrepancy of the prediction intervals and the clock
// offsets' Birge and common-bias widening, on hand-computed values.
#include "fitting/model6_calibration.h"

#include <gtest/gtest.h>

#include <cmath>
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
  // No training misfit in the quantity: the stated variance (100 N^2) is
  // scaled by the others' (r^2 - noise) over theirs, 111000 / 300 for
  // trial 1, the excess carried as its discrepancy.
  const std::vector<double> v = cross_validated_discrepancy_var(four_peaks(0.0));
  EXPECT_NEAR(v[0], (111000.0 / 300.0 - 1.0) * 100.0, 1e-6);
}

TEST(Model6Calibration, TooFewOtherTrialsLeaveItUnchanged) {
  std::vector<HeldOutCheck> c = four_peaks(2500.0);
  c.resize(2);
  for (double v : cross_validated_discrepancy_var(c)) EXPECT_DOUBLE_EQ(v, 2500.0);
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

}  // namespace
}  // namespace dropfit::fitting
