// Model 6 (fitting/model6.h): the foam column against closed forms and
// against itself at finer resolution, and its exact derivatives.
#include <gtest/gtest.h>

#include <cmath>

#include "core/error.h"
#include "fitting/model6.h"
#include "fitting/model6_impl.h"

namespace dropfit::fitting {
namespace {

Model6Params foam() {
  // A soft top foam over a stiff base: peaks of 6-11 kN and 90-120 mm
  // of travel at 4.3-6.5 m/s, as landing mats show.
  Model6Params p;
  p.top = {3.5e3, 7.0e4, 5.0e4, 600.0, 0.88, 2.2};
  p.base = {5.5e4, 1.1e6, 1.3e5, 8.0e3, 0.8, 2.2};
  p.prony_g1 = 0.5;
  p.prony_tau1_s = 2e-3;
  p.prony_g2 = 0.3;
  p.prony_tau2_s = 0.04;
  p.viscosity_pa_s = 300.0;
  p.top_mass_kg = 2.4;
  p.base_mass_kg = 3.6;
  return p;
}

Impact impact(double v) {
  Impact im;
  im.velocity_m_s = v;
  im.duration_s = 0.1;
  im.output_dt_s = 1e-4;
  return im;
}

TEST(Model6, LinearColumnIsTheSpringMassClosedForm) {
  // A linear foam (plateau far above the stresses, no hardening or
  // densification), no memory, a nearly massless column: the impactor on a
  // spring k = E A / h. Peak force M g + sqrt((M g)^2 + k M v0^2). A trace
  // of viscosity damps the light column's own modes (0.1 % of critical for
  // the impactor's).
  Model6Params p;
  p.top = {1e9, 2.0e5, 0.0, 0.0, 0.9, 2.0};
  p.base = p.top;
  p.prony_g1 = p.prony_g2 = 0.0;
  p.viscosity_pa_s = 8.0;
  p.top_mass_kg = 1e-3;
  p.base_mass_kg = 1e-3;
  Model6Geometry g;
  g.top_thickness_m = 0.1;
  g.base_thickness_m = 0.1;
  g.n_top = 3;
  g.n_base = 3;
  g.max_step_s = 1e-5;
  const double k = 2.0e5 * g.area_m2 / 0.2, M = 24.0, v0 = 4.0, w = 9.81 * M;
  const Simulation s = simulate_model6(p, g, impact(v0));
  const double expected = w + std::sqrt(w * w + k * M * v0 * v0);
  EXPECT_NEAR(s.grf_n.maxCoeff(), expected, 0.002 * expected);
  EXPECT_NEAR(s.impactor_m.maxCoeff(), expected / k, 0.002 * expected / k);
  // It leaves the spring after half a period of sqrt(k / M) (gravity shifts it a little).
  EXPECT_NEAR(s.separation_s, M_PI * std::sqrt(M / k) + 2.0 * std::atan(w / (std::sqrt(k * M) * v0)) * std::sqrt(M / k),
              2e-4);
}

TEST(Model6, TenElementsConvergeToAFineColumn) {
  // 6 + 4 elements at 0.1 ms steps (the fitter's) against 24 + 16 at 10 us.
  Model6Geometry coarse, fine;
  fine.n_top = 24;
  fine.n_base = 16;
  fine.max_step_s = 1e-5;
  for (double v : {4.3, 6.5}) {
    const Simulation a = simulate_model6(foam(), coarse, impact(v));
    const Simulation b = simulate_model6(foam(), fine, impact(v));
    const double peak = b.grf_n.maxCoeff();
    EXPECT_NEAR(a.grf_n.maxCoeff(), peak, 0.005 * peak) << v;
    EXPECT_NEAR(a.impactor_m.maxCoeff(), b.impactor_m.maxCoeff(), 3e-4) << v;
    EXPECT_GT(peak, 5e3);
    EXPECT_LT(peak, 1.2e4);
    EXPECT_GT(b.impactor_m.maxCoeff(), 0.08);
    EXPECT_LT(b.impactor_m.maxCoeff(), 0.13);
    EXPECT_LT((a.grf_n - b.grf_n).norm() / std::sqrt(double(a.grf_n.size())), 0.015 * peak) << v;
  }
}

TEST(Model6, ThePlateFeelsTheImpactAfterTheStressCrossesTheColumn) {
  // The face moves before the plate reads anything: the loading front
  // must cross the column first (2.4-2.5 ms here at 4 and 6.5 m/s).
  Model6Geometry g;
  g.n_top = 24;
  g.n_base = 16;
  g.max_step_s = 1e-5;
  auto onset = [&](double v, double* face_m) {
    const Simulation s = simulate_model6(foam(), g, impact(v));
    for (Eigen::Index i = 0; i < s.grf_n.size(); ++i)
      if (s.grf_n[i] > 0.05 * s.grf_n.maxCoeff()) {
        *face_m = s.impactor_m[i];
        return s.t_s[i];
      }
    return -1.0;
  };
  double face_slow = 0.0, face_fast = 0.0;
  const double slow = onset(4.0, &face_slow), fast = onset(6.5, &face_fast);
  EXPECT_GT(fast, 1.5e-3);  // a lumped layered mat: 0.4-0.55 ms
  EXPECT_GT(slow, 1.5e-3);
  EXPECT_GT(face_slow, 0.008);  // the face is centimetres in by then
  EXPECT_GT(face_fast, 0.008);
}

TEST(Model6, ImpulseBalancesMomentum) {
  // dP/dt = M g - GRF (deviation coordinates): with the impactor in free
  // flight after the contact, the plate's impulse is M (v0 + v_up) + M g T
  // less the mat's momentum (small by then: checked to 1 %).
  const Model6Params p = foam();
  Impact im = impact(5.0);
  im.duration_s = 0.09;
  const Simulation s = simulate_model6(p, Model6Geometry{}, im);
  ASSERT_TRUE(std::isfinite(s.separation_s));
  const Eigen::Index n = s.grf_n.size();
  double impulse = 0.0;
  for (Eigen::Index i = 1; i < n; ++i) impulse += 0.5 * (s.grf_n[i] + s.grf_n[i - 1]) * im.output_dt_s;
  const double T = s.t_s[n - 1];
  const double v_end = (s.impactor_m[n - 1] - s.impactor_m[n - 3]) / (2.0 * im.output_dt_s);  // downwards
  const double expected = im.mass_kg * (im.velocity_m_s - v_end) + im.mass_kg * im.gravity_m_s2 * T;
  EXPECT_NEAR(impulse, expected, 0.01 * expected);
}

TEST(Model6, JetDerivativesMatchCentralDifferences) {
  using J = ceres::Jet<double, 2>;
  const Model6Params p = foam();
  Model6ParamsT<J> pj = model6_params_t<J>(p);
  pj.top.plateau_pa.v[0] = 1.0;
  pj.prony_tau1_s.v[1] = 1.0;
  const Impact im = impact(5.0);
  const int n = 600;
  std::vector<J> gj, zj;
  simulate_model6_t<J>(pj, Model6Geometry{}, im, n, &gj, &zj);
  auto peak_at = [&](const Model6Params& q, int i) {
    std::vector<double> g;
    simulate_model6_t<double>(model6_params_t<double>(q), Model6Geometry{}, im, n, &g, nullptr);
    return g[i];
  };
  for (int i : {50, 150, 300}) {
    Model6Params a = p, b = p;
    const double h = 1e-4 * p.top.plateau_pa;
    a.top.plateau_pa += h;
    b.top.plateau_pa -= h;
    EXPECT_NEAR(gj[i].v[0], (peak_at(a, i) - peak_at(b, i)) / (2 * h), 1e-3 * std::abs(gj[i].v[0]) + 1e-6) << i;
    a = b = p;
    const double ht = 1e-4 * p.prony_tau1_s;
    a.prony_tau1_s += ht;
    b.prony_tau1_s -= ht;
    EXPECT_NEAR(gj[i].v[1], (peak_at(a, i) - peak_at(b, i)) / (2 * ht), 1e-3 * std::abs(gj[i].v[1]) + 1e-3) << i;
  }
}

TEST(Model6, RejectsImpossibleFoams) {
  Model6Params p = foam();
  p.top.modulus_pa = -1.0;
  EXPECT_THROW(simulate_model6(p, Model6Geometry{}, impact(5.0)), Error);
  p = foam();
  p.base.densification_strain = 1.2;
  EXPECT_THROW(simulate_model6(p, Model6Geometry{}, impact(5.0)), Error);
  Model6Geometry g;
  g.n_top = 0;
  EXPECT_THROW(simulate_model6(foam(), g, impact(5.0)), Error);
}

}  // namespace
}  // namespace dropfit::fitting
