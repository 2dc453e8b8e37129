// Co-simulation of Model 6 (fitting/model6_cosim.h) against
// fitting::simulate_model6: the same impact, once with the impactor's motion
// prescribed step by step (open loop) and once with a point mass integrated
// here under the column's push (closed loop), must give the simulated plate
// force and the force between impactor and mat.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>

#include "core/error.h"
#include "fitting/model6.h"
#include "fitting/model6_cosim.h"

namespace dropfit::fitting {
namespace {

constexpr double kFineDt = 1e-5;
constexpr double kMass = 24.0, kG = 9.81;

Simulation fine_run(const Model6Params& p, double v0, double duration) {
  Model6Geometry g;
  g.max_step_s = kFineDt;
  Impact imp;
  imp.mass_kg = kMass;
  imp.velocity_m_s = v0;
  imp.gravity_m_s2 = kG;
  imp.duration_s = duration;
  imp.output_dt_s = kFineDt;
  return simulate_model6(p, g, imp);
}

// Driven with the fine run's travel every 10 fine samples (0.1 ms, the
// fitter's step): the plate force within 1 % of its peak at every step, and
// the push on the foot within 1.5 % of the impactor's own M (g - a) at its
// peak.
TEST(Model6Cosim, PrescribedImpactorMotionReproducesThePlateForceAndThePush) {
  const Model6Params p;
  const Simulation s = fine_run(p, 5.0, 0.12);
  const Eigen::VectorXd& y = s.impactor_m;
  const Eigen::Index n = y.size();
  ASSERT_TRUE(std::isfinite(s.separation_s));
  const Eigen::Index end = static_cast<Eigen::Index>(s.separation_s / kFineDt) - 20;  // in contact throughout
  auto vel = [&](Eigen::Index j) { return j == 0 ? 5.0 : (y[j + 1] - y[j - 1]) / (2.0 * kFineDt); };
  ColumnContact mat(p, Model6Geometry{}, kG);
  mat.reset(y[0], 5.0);
  const double peak_grf = s.grf_n.maxCoeff();
  double max_err = 0.0, peak_foot = 0.0, true_push = 0.0;
  for (Eigen::Index j = 1; j + 1 < n; ++j)
    if (j < end) true_push = std::max(true_push, kMass * (kG - (y[j + 1] - 2 * y[j] + y[j - 1]) / (kFineDt * kFineDt)));
  for (Eigen::Index j = 10; j < end; j += 10) {
    const ContactForces f = mat.step(y[j], vel(j), 10 * kFineDt);
    EXPECT_TRUE(f.contact) << "t = " << s.t_s[j];
    max_err = std::max(max_err, std::abs(f.grf_n - s.grf_n[j]));
    // The first step holds the landing's impulse (the top node taking 5 m/s),
    // which the simulation spends before its first sample.
    if (j > 10) peak_foot = std::max(peak_foot, f.foot_n);
  }
  EXPECT_LT(max_err, 0.01 * peak_grf);
  EXPECT_NEAR(peak_foot, true_push, 0.015 * true_push);
  RecordProperty("grf_max_err_pct_peak", std::to_string(100.0 * max_err / peak_grf));
  RecordProperty("push_peak_err_pct", std::to_string(100.0 * (peak_foot - true_push) / true_push));
}

struct ClosedLoop {
  double peak_grf_n = 0.0, max_travel_m = 0.0;
  bool left = false;  // the foot left the mat
};

ClosedLoop closed_loop(const Model6Params& p, double v0, double dt, double duration) {
  ColumnContact mat(p, Model6Geometry{}, kG);
  double y = 0.0, v = v0;
  mat.reset(y, v);
  ClosedLoop out;
  for (double t = 0.0; t < duration; t += dt) {
    y += v * dt;
    const ContactForces f = mat.step(y, v, dt);
    v += (kG - f.foot_n / kMass) * dt;
    out.peak_grf_n = std::max(out.peak_grf_n, f.grf_n);
    out.max_travel_m = std::max(out.max_travel_m, y);
    out.left = out.left || (y < mat.surface_m() - 1e-3 && !f.contact);
  }
  return out;
}

// A 24 kg point mass landing at 5 m/s, stepped at 0.1 ms: peak plate force
// within 1 % and deepest travel within 0.5 mm of the fine simulation; it
// leaves the mat. At 1 ms (a MuJoCo step) within 5 % and 2 mm.
TEST(Model6Cosim, ClosedLoopLandingReproducesThePeakAndTheTravel) {
  const Model6Params p;
  const Simulation s = fine_run(p, 5.0, 0.12);
  const double peak = s.grf_n.maxCoeff(), travel = s.impactor_m.maxCoeff();
  const ClosedLoop fine = closed_loop(p, 5.0, 1e-4, 0.15);
  EXPECT_NEAR(fine.peak_grf_n, peak, 0.01 * peak);
  EXPECT_NEAR(fine.max_travel_m, travel, 0.5e-3);
  EXPECT_TRUE(fine.left);
  const ClosedLoop coarse = closed_loop(p, 5.0, 1e-3, 0.15);
  EXPECT_NEAR(coarse.peak_grf_n, peak, 0.05 * peak);
  EXPECT_NEAR(coarse.max_travel_m, travel, 2e-3);
  RecordProperty("peak_err_pct_dt_0.1ms", std::to_string(100.0 * (fine.peak_grf_n - peak) / peak));
  RecordProperty("peak_err_pct_dt_1ms", std::to_string(100.0 * (coarse.peak_grf_n - peak) / peak));
}

// Above the mat nothing touches it: no force, the column at rest.
TEST(Model6Cosim, NoForceWhileTheFootIsAboveTheMat) {
  ColumnContact mat(Model6Params{}, Model6Geometry{}, kG);
  mat.reset(-0.0205, 1.0);
  for (int k = 1; k <= 20; ++k) {
    const ContactForces f = mat.step(-0.0205 + 1e-3 * k, 1.0, 1e-3);  // 1 m/s
    EXPECT_EQ(f.foot_n, 0.0);
    EXPECT_NEAR(f.grf_n, 0.0, 1e-9);
    EXPECT_FALSE(f.contact);
  }
  // Lands within this step: the top node's mass (0.2 kg) takes the foot's
  // 1 m/s, an impulse of 0.2 N s, 200 N over the 1 ms step, beside the push.
  const ContactForces f = mat.step(0.0005, 1.0, 1e-3);
  EXPECT_TRUE(f.contact);
  EXPECT_GT(f.foot_n, 200.0);
}

TEST(Model6Cosim, RejectsWhatItCannotSimulate) {
  ColumnContact mat(Model6Params{}, Model6Geometry{}, kG);
  EXPECT_THROW(mat.step(0.0, 1.0, 0.0), Error);
  EXPECT_THROW(mat.step(std::nan(""), 1.0, 1e-3), Error);
  Model6Params bad;
  bad.top.modulus_pa = -1.0;
  EXPECT_THROW(ColumnContact(bad, Model6Geometry{}, kG), Error);
  Model6Geometry flat;
  flat.area_m2 = 0.0;
  EXPECT_THROW(ColumnContact(Model6Params{}, flat, kG), Error);
}

}  // namespace
}  // namespace dropfit::fitting
