// Co-simulation API (fitting/cosim.h) against fitting::simulate: the same
// impact, once with the impactor motion prescribed step by step (open loop)
// and once with a point mass integrated here under the mat's force (closed
// loop), must give the simulated ground reaction force.
#include <gtest/gtest.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "core/error.h"
#include "fitting/cosim.h"
#include "fitting/models.h"

namespace dropfit::fitting {
namespace {

constexpr double kFineDt = 1e-5;

Simulation fine_run(ModelKind kind, const MatParams& p, double v0, double duration) {
  Impact imp;
  imp.mass_kg = 24.0;
  imp.velocity_m_s = v0;
  imp.duration_s = duration;
  imp.output_dt_s = kFineDt;
  return simulate(kind, p, imp);
}

double peak(const Eigen::VectorXd& v) { return v.maxCoeff(); }

struct OpenLoop {
  double max_err_n = 0.0;
  double peak_n = 0.0;
  double separation_s = NAN;  // the run's, to show the window covers it
};

// Drives MatContact with the simulated impactor travel and velocity (central
// differences of the fine run) every `every` fine samples; compares GRFs.
OpenLoop open_loop(ModelKind kind, const MatParams& p, int every, double v_start) {
  const Simulation s = fine_run(kind, p, 5.0, 0.2);
  const Eigen::VectorXd& y = s.impactor_m;
  const Eigen::Index n = y.size();
  auto vel = [&](Eigen::Index j) { return j == 0 ? v_start : (y[j + 1] - y[j - 1]) / (2.0 * kFineDt); };
  MatContact mat(kind, p);
  mat.reset(y[0], vel(0));
  OpenLoop out;
  out.peak_n = peak(s.grf_n);
  out.separation_s = s.separation_s;
  const double dt = every * kFineDt;
  for (Eigen::Index j = every; j + 1 < n; j += every) {
    const ContactForces f = mat.step(y[j], vel(j), dt);
    out.max_err_n = std::max(out.max_err_n, std::abs(f.grf_n - s.grf_n[j]));
  }
  return out;
}

TEST(Cosim, PrescribedImpactorMotionReproducesTheGrfOfModels124At1ms) {
  const double M = 24.0, v0 = 5.0, m_eff = 3.0;
  struct Case {
    ModelKind kind;
    MatParams p;
    double v_start;
    bool separates;  // within the window: exercises the unilateral contact
  };
  // The paper's Models 1 and 2 are overdamped (r1 = 5700 N s/m: the
  // impactor never leaves); lightly damped variants separate.
  MatParams light1 = paper_table2(ModelKind::Model1), light2 = paper_table2(ModelKind::Model2, m_eff);
  light1.r1_n_s_m = 400.0;
  light2.r1_n_s_m = 400.0;
  const Case cases[] = {
      {ModelKind::Model1, paper_table2(ModelKind::Model1), v0, false},
      {ModelKind::Model1, light1, v0, true},
      {ModelKind::Model2, paper_table2(ModelKind::Model2, m_eff), M * v0 / (M + m_eff), false},
      {ModelKind::Model2, light2, M * v0 / (M + m_eff), true},
      {ModelKind::Model4, paper_table2(ModelKind::Model4), v0, true},
  };
  for (const Case& c : cases) {
    const OpenLoop r = open_loop(c.kind, c.p, 100, c.v_start);  // dt = 1 ms
    EXPECT_GT(r.peak_n, 1000.0) << model_name(c.kind);
    if (c.separates) {
      EXPECT_LT(r.separation_s, 0.15) << model_name(c.kind) << ": the comparison must cover the separation";
    }
    EXPECT_LT(r.max_err_n, 0.01 * r.peak_n) << model_name(c.kind) << ": max |GRF error| " << r.max_err_n
                                            << " N, peak " << r.peak_n << " N";
    RecordProperty(model_name(c.kind) + (c.separates ? "_separating" : "") + "_max_err_pct_of_peak", std::to_string(100.0 * r.max_err_n / r.peak_n));
  }
}

// Model 3's top mass rides on the prescribed foot: GRF from m2's forced
// motion, which the exact forced discrete form reproduces too.
TEST(Cosim, PrescribedImpactorMotionReproducesModel3WhileInContact) {
  const MatParams p = paper_table2(ModelKind::Model3);
  const double v_start = 24.0 * 5.0 / (24.0 + p.m1_kg);
  const OpenLoop r = open_loop(ModelKind::Model3, p, 100, v_start);
  EXPECT_LT(r.max_err_n, 0.02 * r.peak_n) << "max |GRF error| " << r.max_err_n << " N, peak " << r.peak_n;
  RecordProperty("model3_max_err_pct_of_peak", std::to_string(100.0 * r.max_err_n / r.peak_n));
}

struct ClosedLoop {
  double peak_grf_n = 0.0, peak_foot_n = 0.0;
};

// A 24 kg point mass landing at v0 (semi-implicit Euler; the mat's force
// from MatContact at the new position).
ClosedLoop closed_loop(ModelKind kind, const MatParams& p, double v0, double dt, double duration) {
  const double M = 24.0, g = 9.81;
  MatContact mat(kind, p);
  double y = 0.0, v = v0;
  mat.reset(y, v);
  ClosedLoop out;
  double force = 0.0;
  for (int n = 0; n * dt < duration; ++n) {
    v += (g - force / M) * dt;
    y += v * dt;
    const ContactForces f = mat.step(y, v, dt);
    force = f.foot_n;
    out.peak_grf_n = std::max(out.peak_grf_n, f.grf_n);
    out.peak_foot_n = std::max(out.peak_foot_n, f.foot_n);
  }
  return out;
}

TEST(Cosim, ClosedLoopLandingReproducesThePeakForceOfModel4) {
  const MatParams p = paper_table2(ModelKind::Model4);
  const Simulation s = fine_run(ModelKind::Model4, p, 5.0, 0.1);
  const double truth = peak(s.grf_n);
  // Element 1's force on the impactor: k1 (y - y1) + r1 (y' - y1'), from the
  // fine run's travel (central differences).
  double truth_foot = 0.0;
  for (Eigen::Index j = 1; j + 1 < s.t_s.size(); ++j) {
    const double dy = s.impactor_m[j] - s.layer1_m[j];
    const double ddy = (s.impactor_m[j + 1] - s.layer1_m[j + 1] - s.impactor_m[j - 1] + s.layer1_m[j - 1]) /
                       (2.0 * kFineDt);
    truth_foot = std::max(truth_foot, p.k1_n_m * dy + p.r1_n_s_m * ddy);
  }
  const ClosedLoop c = closed_loop(ModelKind::Model4, p, 5.0, 1e-4, 0.1);
  EXPECT_NEAR(c.peak_grf_n, truth, 0.01 * truth);
  EXPECT_NEAR(c.peak_foot_n, truth_foot, 0.01 * truth_foot);
  // At 1 ms the loop stays stable and close (the point mass's own Euler
  // step dominates the error).
  const ClosedLoop coarse = closed_loop(ModelKind::Model4, p, 5.0, 1e-3, 0.1);
  EXPECT_NEAR(coarse.peak_grf_n, truth, 0.05 * truth);
  RecordProperty("peak_err_pct_dt_0.1ms", std::to_string(100.0 * (c.peak_grf_n - truth) / truth));
  RecordProperty("peak_err_pct_dt_1ms", std::to_string(100.0 * (coarse.peak_grf_n - truth) / truth));
}

TEST(Cosim, NoForceWhileTheFootIsAboveTheMat) {
  const ModelKind kinds[] = {ModelKind::Model1, ModelKind::Model2, ModelKind::Model3, ModelKind::Model4};
  for (ModelKind kind : kinds) {
    MatContact mat(kind, paper_table2(kind, 3.0));
    mat.reset(-0.05, 2.0);
    double y = -0.05;
    for (int n = 0; n < 20; ++n) {  // approaching, still 1 cm above at the end
      y += 0.002;
      const ContactForces f = mat.step(y, 2.0, 1e-3);
      EXPECT_EQ(f.foot_n, 0.0) << model_name(kind);
      EXPECT_EQ(f.grf_n, 0.0) << model_name(kind);
      EXPECT_FALSE(f.contact);
    }
    // Pressing 5 mm in, then lifted well clear: the mat pushes, then lets go
    // (no pull) and the foot feels nothing.
    const ContactForces in = mat.step(-0.005, 2.0, 5e-3);
    EXPECT_EQ(in.foot_n, 0.0) << model_name(kind);
    const ContactForces press = mat.step(0.005, 2.0, 5e-3);
    EXPECT_GT(press.foot_n, 0.0) << model_name(kind);
    const ContactForces lifted = mat.step(-0.05, -5.0, 5e-3);
    EXPECT_EQ(lifted.foot_n, 0.0) << model_name(kind);
    EXPECT_FALSE(lifted.contact) << model_name(kind);
  }
}

TEST(Cosim, RejectsWhatItCannotSimulate) {
  EXPECT_THROW(MatContact(ModelKind::Model5, paper_table2(ModelKind::Model5)), Error);
  MatParams cubic = paper_table2(ModelKind::Model4);
  cubic.k1_cubic_n_m3 = 1e7;
  EXPECT_THROW(MatContact(ModelKind::Model4, cubic), Error);
  MatParams no_mass = paper_table2(ModelKind::Model4);
  no_mass.m2_kg = 0.0;
  EXPECT_THROW(MatContact(ModelKind::Model4, no_mass), Error);
  MatContact ok(ModelKind::Model4, paper_table2(ModelKind::Model4));
  EXPECT_THROW(ok.step(0.0, 1.0, 0.0), Error);
  EXPECT_THROW(ok.step(NAN, 1.0, 1e-3), Error);
}

}  // namespace
}  // namespace dropfit::fitting
