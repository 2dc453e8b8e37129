// The generator's own physics (samples/generator/physics.h): its integrator
// against closed forms, energy and momentum, the effects' force laws, and a
// cross-check against the fitter's independent implementation.
#include <gtest/gtest.h>

#include <cmath>

#include "core/error.h"
#include "fitting/models.h"
#include "samples/generator/physics.h"
#include "samples/generator/synth.h"

namespace dropfit::synth {
namespace {

constexpr double kG = 9.81;

// Underdamped y'' = -w^2 y - 2 z w y', y(0) = 0, y'(0) = v:
// y = v / wd exp(-z w t) sin(wd t).
TEST(GeneratorIntegrator, DampedOscillatorMatchesTheClosedForm) {
  const double w = 60.0, z = 0.1, v = 5.0, wd = w * std::sqrt(1 - z * z);
  OdeOptions opt;
  opt.rtol = 1e-11;
  opt.atol = 1e-14;
  DormandPrince ode(
      [&](double, const OdeState& y) {
        OdeState d = OdeState::Zero();
        d(0) = y(1);
        d(1) = -w * w * y(0) - 2 * z * w * y(1);
        return d;
      },
      0.0, (OdeState() << 0.0, v, 0, 0, 0, 0, 0, 0).finished(), opt);
  double worst = 0.0, worst_dense = 0.0;
  while (ode.t() < 0.5) {
    const OdeStep s = ode.step(0.5);
    const double exact = v / wd * std::exp(-z * w * s.t1) * std::sin(wd * s.t1);
    worst = std::max(worst, std::abs(s.y1(0) - exact));
    const double tm = 0.5 * (s.t0 + s.t1);  // dense output between the steps
    worst_dense = std::max(worst_dense, std::abs(s.at(tm)(0) - v / wd * std::exp(-z * w * tm) * std::sin(wd * tm)));
  }
  // Amplitude 83 mm; the bar is 1e-6 (step ends) and the Hermite
  // dense output of steps <= 0.2 ms stays within it too.
  EXPECT_LT(worst, 1e-8);
  EXPECT_LT(worst_dense, 1e-6);
}

// Model 1: M x'' = M g - (k x + r x') while k x + r x' > 0. Closed form
// about the static deflection x_s = M g / k, and the separation instant.
TEST(GeneratorPhysics, Model1MatchesTheClosedFormUpToSeparation) {
  MatParams p;
  p.k1_n_m = 84183.0;
  p.r1_n_s_m = 300.0;
  const double M = 24.0, v = 5.25;
  ChainImpact im;
  im.mass_kg = M;
  im.velocity_m_s = v;
  im.duration_s = 0.6;
  im.output_dt_s = 1e-5;
  im.catch_at_apex = true;
  const ChainSimulation s = simulate_chain(ModelKind::Model1, p, im);
  const double w = std::sqrt(p.k1_n_m / M), z = p.r1_n_s_m / (2 * std::sqrt(p.k1_n_m * M));
  const double wd = w * std::sqrt(1 - z * z), xs = M * kG / p.k1_n_m;
  // x = xs + e^{-z w t} (A cos wd t + B sin wd t), x(0) = 0, x'(0) = v.
  const double A = -xs, B = (v + z * w * A) / wd;
  auto x = [&](double t) { return xs + std::exp(-z * w * t) * (A * std::cos(wd * t) + B * std::sin(wd * t)); };
  auto xd = [&](double t) {
    const double e = std::exp(-z * w * t);
    return e * ((-z * w * A + wd * B) * std::cos(wd * t) + (-z * w * B - wd * A) * std::sin(wd * t));
  };
  auto force = [&](double t) { return p.k1_n_m * x(t) + p.r1_n_s_m * xd(t); };
  double lo = 0.01, hi = 0.2;  // the force's zero after its peak
  ASSERT_GT(force(lo), 0.0);
  ASSERT_LT(force(hi - 0.1), 0.0);
  hi = hi - 0.1;
  for (int i = 0; i < 200; ++i) ((force(0.5 * (lo + hi)) > 0.0) ? lo : hi) = 0.5 * (lo + hi);
  const double t_sep = 0.5 * (lo + hi);
  EXPECT_NEAR(s.separation_s, t_sep, 1e-9);  // event location to the Illinois tolerance
  double worst_x = 0.0, worst_f = 0.0;
  for (Eigen::Index i = 0; i < s.t_s.size() && s.t_s(i) < t_sep; ++i) {
    worst_x = std::max(worst_x, std::abs(s.impactor_m(i) - x(s.t_s(i))));
    worst_f = std::max(worst_f, std::abs(s.grf_n(i) - force(s.t_s(i))));
  }
  EXPECT_LT(worst_x, 1e-6);   // the bar: 1e-6 of a ~0.1 m travel
  EXPECT_LT(worst_f, 1e-1);   // 1e-6 m times k1 (0.08 N)
  // After separation: free flight, then caught at the apex (v = 0, held).
  EXPECT_TRUE(std::isfinite(s.caught_s));
  const double v_sep = xd(t_sep);
  EXPECT_NEAR(s.caught_s - t_sep, -v_sep / kG, 1e-8);
  EXPECT_EQ(s.impactor_v_m_s(s.t_s.size() - 1), 0.0);
}

// Undamped Model 4 in contact conserves the impactor's kinetic and potential
// energy plus the mat's (gravity acts on the impactor only).
TEST(GeneratorPhysics, UndampedModel4ConservesEnergyInContact) {
  MatParams p = default_mat_params(ModelKind::Model4, {{"c", 0.005, 0.0}, {"s", 0.05, 2.44}, {"f", 0.15, 3.66}});
  p.r1_n_s_m = p.r2_n_s_m = p.r3_n_s_m = 0.0;
  p.k1_cubic_n_m3 = 4e6;  // a conservative nonlinearity too
  const double M = 24.0, v = 5.0;
  ChainImpact im;
  im.mass_kg = M;
  im.velocity_m_s = v;
  im.duration_s = 0.1;
  im.ode.rtol = 1e-11;
  im.ode.atol = 1e-14;
  const ChainSimulation s = simulate_chain(ModelKind::Model4, p, im);
  const double e0 = 0.5 * M * v * v;
  double worst = 0.0;
  for (Eigen::Index i = 0; i < s.t_s.size() && s.t_s(i) < s.separation_s; ++i) {
    const double d = s.impactor_m(i) - s.layer1_m(i);
    const double e = 0.5 * M * s.impactor_v_m_s(i) * s.impactor_v_m_s(i) +
                     0.5 * p.m1_kg * s.layer1_v_m_s(i) * s.layer1_v_m_s(i) +
                     0.5 * p.m2_kg * s.layer2_v_m_s(i) * s.layer2_v_m_s(i) + 0.5 * p.k1_n_m * d * d +
                     0.25 * p.k1_cubic_n_m3 * d * d * d * d +
                     0.5 * p.k2_n_m * std::pow(s.layer1_m(i) - s.layer2_m(i), 2) +
                     0.5 * p.k3_n_m * s.layer2_m(i) * s.layer2_m(i) - M * kG * s.impactor_m(i);
    worst = std::max(worst, std::abs(e - e0) / e0);
  }
  EXPECT_LT(worst, 1e-7);  // relative; the integrator's tolerance is 1e-11
}

// Momentum: M v0 + m1 v1 + m2 v2 - M v = M g t - integral of the GRF (the
// mat's weight is carried statically), through separation and re-landing.
TEST(GeneratorPhysics, MomentumChangeEqualsTheImpulse) {
  const MatParams p = default_mat_params(ModelKind::Model4, {{"c", 0.005, 0.0}, {"s", 0.05, 2.44}, {"f", 0.15, 3.66}});
  const double M = 24.0, v = 6.0;
  ChainImpact im;
  im.mass_kg = M;
  im.velocity_m_s = v;
  im.duration_s = 1.2;  // the impactor lands again (no catcher)
  const ChainSimulation s = simulate_chain(ModelKind::Model4, p, im);
  EXPECT_GE(s.n_contacts, 2);
  double impulse = 0.0;
  double worst = 0.0;
  for (Eigen::Index i = 1; i < s.t_s.size(); ++i) {
    impulse += 0.5 * (s.grf_n(i) + s.grf_n(i - 1)) * (s.t_s(i) - s.t_s(i - 1));
    if (i % 1000) continue;
    const double momentum = M * s.impactor_v_m_s(i) + p.m1_kg * s.layer1_v_m_s(i) + p.m2_kg * s.layer2_v_m_s(i);
    worst = std::max(worst, std::abs(momentum - M * v - (M * kG * s.t_s(i) - impulse)));
  }
  // Trapezoid error of a 10 us grid across the kinks at separation and
  // landing: well under 1e-3 of the ~250 N s exchanged.
  EXPECT_LT(worst, 0.05);
}

// Models 2 and 3: a plastic collision with the top mass at first contact.
TEST(GeneratorPhysics, RigidModelsStartWithAPlasticCollision) {
  MatParams p;
  p.k1_n_m = 84183.0;
  p.r1_n_s_m = 500.0;
  p.m_eff_kg = 2.0;
  ChainImpact im;
  im.velocity_m_s = 5.0;
  im.duration_s = 0.01;
  const ChainSimulation s2 = simulate_chain(ModelKind::Model2, p, im);
  EXPECT_NEAR(s2.impactor_v_m_s(0), 24.0 * 5.0 / 26.0, 1e-12);
  EXPECT_NEAR(s2.layer1_v_m_s(0), 24.0 * 5.0 / 26.0, 1e-12);
  EXPECT_NEAR(s2.impactor_m(500), s2.layer1_m(500), 1e-12);  // together in contact
}

// Element 1's force law: each effect with its stated size.
TEST(GeneratorPhysics, ElementOneForceLawCarriesEachEffect) {
  MatParams p;
  p.k1_n_m = 5e4;
  p.r1_n_s_m = 100.0;
  EXPECT_DOUBLE_EQ(element1_force_n(p, 0.1, 1.0, 0.0), 5e3 + 100.0);
  p.k1_cubic_n_m3 = 4e6;  // + c d^3 = 4000 N at 0.1 m
  EXPECT_DOUBLE_EQ(element1_force_n(p, 0.1, 0.0, 0.0), 5e3 + 4e3);
  p.k1_hysteresis = 0.2;  // elastic force 20 % lower while unloading, full while loading
  EXPECT_NEAR(element1_force_n(p, 0.1, -1.0, 0.0), 0.8 * 9e3 - 100.0, 1e-6 * 9e3);
  EXPECT_NEAR(element1_force_n(p, 0.1, 1.0, 0.0), 9e3 + 100.0, 1e-6 * 9e3);
  EXPECT_NEAR(element1_force_n(p, 0.1, 0.0, 0.0), 0.9 * 9e3, 1e-9);  // half-way at rest
  p.r1_unload_n_s_m = 300.0;  // damping asymmetry, the older "hysteresis"
  EXPECT_NEAR(element1_force_n(p, 0.1, -1.0, 0.0), 0.8 * 9e3 - 300.0, 1e-6 * 9e3);
  EXPECT_DOUBLE_EQ(element1_force_n(p, 0.0, 0.0, 250.0), 250.0);  // the Maxwell arm adds its force
}

// The Maxwell arm's force is the convolution of its spring with the
// relaxation kernel: Fm(t) = k_m integral exp(-(t - s)/tau) d'(s) ds.
TEST(GeneratorPhysics, MaxwellArmRelaxesWithItsTimeConstant) {
  MatParams p = default_mat_params(ModelKind::Model4, {{"c", 0.005, 0.0}, {"s", 0.05, 2.44}, {"f", 0.15, 3.66}});
  p.maxwell_k_n_m = 28000.0;
  p.maxwell_tau_s = 0.025;
  ChainImpact im;
  im.velocity_m_s = 5.0;
  im.duration_s = 0.1;
  const ChainSimulation s = simulate_chain(ModelKind::Model4, p, im);
  double fm = 0.0, worst = 0.0, largest = 0.0;
  const double dt = im.output_dt_s, decay = std::exp(-dt / p.maxwell_tau_s);
  for (Eigen::Index i = 1; i < s.t_s.size() && s.t_s(i) < s.separation_s; ++i) {
    const double dd = (s.impactor_m(i) - s.layer1_m(i)) - (s.impactor_m(i - 1) - s.layer1_m(i - 1));
    fm = fm * decay + p.maxwell_k_n_m * dd * (1.0 + decay) / 2.0;  // trapezoid of the kernel
    worst = std::max(worst, std::abs(fm - s.maxwell_n(i)));
    largest = std::max(largest, std::abs(s.maxwell_n(i)));
  }
  EXPECT_GT(largest, 500.0);              // a weak arm, but present: ~28 kN/m x ~0.05 m
  EXPECT_LT(worst, 1e-3 * largest);       // discrete convolution on a 10 us grid
}

// The fitter's Model 4 (fitting::simulate, exact matrix exponential) and the
// generator's (Dormand-Prince) agree: two implementations of one model.
TEST(GeneratorPhysics, AgreesWithTheFittersIndependentImplementation) {
  const MatParams p = default_mat_params(ModelKind::Model4, {{"c", 0.005, 0.0}, {"s", 0.05, 2.44}, {"f", 0.15, 3.66}});
  ChainImpact im;
  im.velocity_m_s = 5.25;
  im.duration_s = 0.1;
  im.output_dt_s = 1e-4;
  const ChainSimulation g = simulate_chain(ModelKind::Model4, p, im);
  fitting::Impact fi;
  fi.velocity_m_s = 5.25;
  fi.duration_s = 0.1;
  fi.output_dt_s = 1e-4;
  const fitting::Simulation f = fitting::simulate(fitting::ModelKind::Model4, p, fi);
  ASSERT_EQ(f.grf_n.size(), g.grf_n.size());
  EXPECT_LT((f.grf_n - g.grf_n).cwiseAbs().maxCoeff(), 1e-4 * f.grf_n.maxCoeff());
  EXPECT_LT((f.impactor_m - g.impactor_m).cwiseAbs().maxCoeff(), 1e-6);
  EXPECT_NEAR(f.separation_s, g.separation_s, 1e-6);
}

TEST(GeneratorPhysics, RefusesImpossibleParameters) {
  MatParams p = default_mat_params(ModelKind::Model4, {{"c", 0.005, 0.0}, {"s", 0.05, 2.44}, {"f", 0.15, 3.66}});
  ChainImpact im;
  MatParams bad = p;
  bad.k1_hysteresis = 1.0;
  EXPECT_THROW(simulate_chain(ModelKind::Model4, bad, im), Error);
  bad = p;
  bad.m2_kg = 0.0;
  EXPECT_THROW(simulate_chain(ModelKind::Model4, bad, im), Error);
  bad = p;
  bad.k2_n_m = -1.0;
  EXPECT_THROW(simulate_chain(ModelKind::Model4, bad, im), Error);
  EXPECT_THROW(simulate_chain(ModelKind::Model5, p, im), Error);
}

}  // namespace
}  // namespace dropfit::synth
