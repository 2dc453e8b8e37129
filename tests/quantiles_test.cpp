// The distribution functions the stages use come from Boost.Math
// (diagnosis::chi_square_sf, trial::student_t_quantile); these pin them to
// tabulated values. Tolerance 1e-6: the tables give six decimals (rounding
// error at most 5e-7), and Boost is accurate to a few ulp.
#include <gtest/gtest.h>

#include <boost/math/distributions/chi_squared.hpp>
#include <boost/math/distributions/students_t.hpp>
#include <cmath>

#include "diagnosis/structure.h"
#include "trial/trial.h"

namespace {

constexpr double kTable = 1e-6;

TEST(Quantiles, ChiSquareFromBoostMatchesTables) {
  // 95th percentiles (any chi-square table, e.g. NIST/SEMATECH e-Handbook 1.3.6.7.4).
  const auto q95 = [](double dof) { return boost::math::quantile(boost::math::chi_squared(dof), 0.95); };
  EXPECT_NEAR(q95(1), 3.841459, kTable);
  EXPECT_NEAR(q95(2), 5.991465, kTable);
  EXPECT_NEAR(q95(10), 18.307038, kTable);
  EXPECT_NEAR(q95(20), 31.410433, kTable);
  // The diagnosis stage's upper tail at those points is 0.05.
  for (double dof : {1.0, 2.0, 10.0, 20.0})
    EXPECT_NEAR(dropfit::diagnosis::chi_square_sf(q95(dof), dof), 0.05, 1e-12) << "dof " << dof;
  EXPECT_NEAR(dropfit::diagnosis::chi_square_sf(3.841459, 1), 0.05, kTable);
}

TEST(Quantiles, StudentTMatchesTables) {
  namespace tr = dropfit::trial;
  EXPECT_NEAR(tr::student_t_quantile(0.975, 10), 2.228139, kTable);
  EXPECT_NEAR(tr::student_t_quantile(0.975, 1), 12.706205, kTable);
  EXPECT_NEAR(tr::student_t_quantile(0.95, 5), 2.015048, kTable);
  EXPECT_NEAR(tr::student_t_quantile(0.995, 30), 2.749996, kTable);
  EXPECT_NEAR(tr::student_t_quantile(0.025, 10), -2.228139, kTable);
  // Outside (0, 1) or dof <= 0: NaN, not a Boost exception.
  EXPECT_TRUE(std::isnan(tr::student_t_quantile(1.0, 10)));
  EXPECT_TRUE(std::isnan(tr::student_t_quantile(0.5, 0)));
}

TEST(Quantiles, ChiSquareEdges) {
  namespace dg = dropfit::diagnosis;
  EXPECT_DOUBLE_EQ(dg::chi_square_sf(0.0, 3), 1.0);
  EXPECT_DOUBLE_EQ(dg::chi_square_sf(INFINITY, 3), 0.0);
  EXPECT_TRUE(std::isnan(dg::chi_square_sf(1.0, 0.0)));
  // dof 2: exactly exp(-q/2); far in the tail the relative error stays small.
  EXPECT_NEAR(dg::chi_square_sf(40.0, 2) / std::exp(-20.0), 1.0, 1e-12);
}

}  // namespace
