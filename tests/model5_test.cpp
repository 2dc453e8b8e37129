// Model 5 (fitting/model5.h): the geometric, area-elastic mat. Each test
// builds its own truth: Model 4 (which Model 5 must become when the mat moves
// as a whole), Newton's second law for the whole system (impulse balance),
// symmetry (no tilt), and the time step (convergence).
#include "fitting/model5.h"

#include <ceres/jet.h>
#include <gtest/gtest.h>

#include <cmath>
#include <cstdio>
#include <vector>

#include "bench/model5_leapfrog.h"
#include "fitting/model5_impl.h"

#include "core/error.h"
#include "fitting/models.h"

namespace dropfit::fitting {
namespace {

using bench::simulate_model5_leapfrog;

// The paper's Table 2 Model 5 parameters (k1 70880, k2 787200, k3 617120,
// r1 260, r2 280, r3 850; m1 2.44 kg, m2 3.66 kg) and its trial 3 impact.
MatParams table2() { return paper_table2(ModelKind::Model5); }

Impact trial3() {
  Impact im;
  im.mass_kg = 24.0;
  im.velocity_m_s = 5.25;
  im.duration_s = 0.3;
  im.output_dt_s = 1e-3;
  return im;
}

double max_abs_diff(const Eigen::VectorXd& a, const Eigen::VectorXd& b) { return (a - b).cwiseAbs().maxCoeff(); }

// Trapezoid rule over uniformly spaced samples.
double integral(const Eigen::VectorXd& y, double h) {
  return h * (y.sum() - 0.5 * (y(0) + y(y.size() - 1)));
}

// Index of the cell centre nearest to v.
Eigen::Index nearest(const Eigen::VectorXd& centres, double v) {
  Eigen::Index i = 0;
  (centres.array() - v).abs().minCoeff(&i);
  return i;
}

TEST(Model5, OneCellPerLayerIsModel4) {
  // With one cell per layer every element's share is the whole element:
  // Model 4 exactly, whatever the shear.
  Model5Geometry geo;
  geo.nodes_x = 1;
  geo.nodes_y = 1;
  const Simulation m4 = simulate(ModelKind::Model4, table2(), trial3());
  const Simulation m5 = simulate_model5(table2(), geo, trial3());
  const double peak = m4.grf_n.maxCoeff();
  ASSERT_GT(peak, 1000.0);
  ASSERT_EQ(m5.grf_n.size(), m4.grf_n.size());
  EXPECT_LT(max_abs_diff(m5.grf_n, m4.grf_n), 0.001 * peak);       // 0.1 % of peak (1 % required)
  EXPECT_LT(max_abs_diff(m5.impactor_m, m4.impactor_m), 2e-4);     // 0.2 mm
  EXPECT_LT(max_abs_diff(m5.surface_m, m4.surface_m), 2e-4);
  EXPECT_LT(max_abs_diff(m5.layer1_m, m4.layer1_m), 2e-4);
  EXPECT_NEAR(m5.separation_s, m4.separation_s, 2e-4);
}

TEST(Model5, FaceCoveringTheMatIsModel4) {
  // A face as large as the mat presses every cell alike: no neighbour
  // differs, so shear does nothing and the grid moves as Model 4's masses.
  Model5Geometry geo;  // 9 x 6 cells, shear on
  geo.footprint_length_m = geo.mat_length_m;
  geo.footprint_width_m = geo.mat_width_m;
  const Simulation m4 = simulate(ModelKind::Model4, table2(), trial3());
  const Model5Result m5 = simulate_model5_detailed(table2(), geo, trial3());
  const double peak = m4.grf_n.maxCoeff();
  EXPECT_LT(max_abs_diff(m5.sim.grf_n, m4.grf_n), 0.001 * peak);
  EXPECT_LT(max_abs_diff(m5.sim.surface_m, m4.surface_m), 2e-4);
  // Uniform: the field at peak is flat to rounding.
  const Eigen::MatrixXd& f = m5.surface_at_peak_m;
  EXPECT_LT(f.maxCoeff() - f.minCoeff(), 1e-12);
}

TEST(Model5, StiffShearApproachesModel4) {
  // The real 0.25 m face: as the layers' shear rigidity grows they move as
  // flat plates and Model 4 returns; the error shrinks with stiffness.
  const Simulation m4 = simulate(ModelKind::Model4, table2(), trial3());
  const double peak = m4.grf_n.maxCoeff();
  double previous = std::numeric_limits<double>::infinity();
  for (double shear : {1e4, 1e5, 1e6, 1e7}) {
    Model5Geometry geo;
    geo.shear1_n_m = geo.shear2_n_m = shear;
    const Simulation m5 = simulate_model5(table2(), geo, trial3());
    const double err = max_abs_diff(m5.grf_n, m4.grf_n) / peak;
    EXPECT_LT(err, previous) << "shear " << shear;
    previous = err;
  }
  EXPECT_LT(previous, 0.01);  // within 1 % of peak at S = 1e7 N/m
}

// Newton for the whole system, downward positive, GRF zeroed at rest (the
// mat's weight is what the zeroing removed): over [0, T]
//   integral(GRF) = M (v0 - v(T)) + M g T - p_mat(T),
// i.e. the plate's impulse is the impactor's momentum change plus gravity's
// impulse on it, less what the mat still carries. A raw plate would add the
// mat's weight times T on both sides.
void expect_impulse_balance(const Model5Geometry& geo) {
  Impact im = trial3();
  im.output_dt_s = 5e-5;  // fine samples: the trapezoid's own error stays far below 1e-3
  const Model5Result r = simulate_model5_detailed(table2(), geo, im);
  const Eigen::Index last = r.sim.t_s.size() - 1;
  const double T = r.sim.t_s(last);
  const double plate = integral(r.sim.grf_n, im.output_dt_s);
  const double newton = im.mass_kg * (im.velocity_m_s - r.impactor_velocity_m_s(last)) +
                        im.mass_kg * im.gravity_m_s2 * T - r.mat_momentum_n_s(last);
  ASSERT_GT(plate, 100.0);
  EXPECT_NEAR(plate, newton, 1e-3 * plate);  // 0.1 % (1 % required)
  // The impactor has left and the mat has nearly settled by 0.3 s: the plate
  // has returned the impactor's momentum plus the rebound.
  EXPECT_TRUE(std::isfinite(r.sim.separation_s));
  EXPECT_LT(std::abs(r.mat_momentum_n_s(last)), 1e-2 * plate);
}

TEST(Model5, ImpulseBalancesMomentumCentred) { expect_impulse_balance(Model5Geometry{}); }

TEST(Model5, ImpulseBalancesMomentumFramedOffCentreTilted) {
  // Every path at once: frame reactions, off-centre contact, tilt.
  Model5Geometry geo;
  geo.edge = MatEdge::Framed;
  geo.impact_x_m = 0.17;
  geo.impact_y_m = -0.08;
  geo.tilt_x0_rad = 0.03;
  geo.tilt_rate_y0_rad_s = -0.5;
  expect_impulse_balance(geo);
}

TEST(Model5, CentredImpactDoesNotTilt) {
  for (MatEdge edge : {MatEdge::Free, MatEdge::Framed}) {
    Model5Geometry geo;
    geo.edge = edge;
    const Model5Result r = simulate_model5_detailed(table2(), geo, trial3());
    EXPECT_LT(r.tilt_x_rad.cwiseAbs().maxCoeff(), 1e-9);
    EXPECT_LT(r.tilt_y_rad.cwiseAbs().maxCoeff(), 1e-9);
  }
}

// Off-centre towards +x and +y (face at (0.20, 0.10) m on the 0.90 x 0.60 m
// mat). With free edges the cells between the face and the near edges have
// fewer neighbours beyond them to share the load through shear, so the near
// side is softer and sinks further: the face tilts with its +x, +y sides
// down (tilt > 0). Held by the frame, the near edges are the stiff side: the
// far side sinks, tilt < 0. Without shear every column stands alone and the
// face's contact is symmetric about its centre: no tilt at all.
TEST(Model5, OffCentreImpactTiltsTowardsTheSofterSide) {
  Model5Geometry geo;
  geo.impact_x_m = 0.20;
  geo.impact_y_m = 0.10;
  auto peak_tilt = [&](const Model5Result& r, const Eigen::VectorXd& tilt) {
    Eigen::Index i = 0;
    r.sim.grf_n.maxCoeff(&i);
    return tilt(i);
  };

  geo.edge = MatEdge::Free;
  const Model5Result free_edges = simulate_model5_detailed(table2(), geo, trial3());
  EXPECT_GT(peak_tilt(free_edges, free_edges.tilt_x_rad), 1e-4);
  EXPECT_GT(peak_tilt(free_edges, free_edges.tilt_y_rad), 1e-4);

  geo.edge = MatEdge::Framed;
  const Model5Result framed = simulate_model5_detailed(table2(), geo, trial3());
  EXPECT_LT(peak_tilt(framed, framed.tilt_x_rad), -1e-4);
  EXPECT_LT(peak_tilt(framed, framed.tilt_y_rad), -1e-4);

  geo.edge = MatEdge::Free;
  geo.shear1_n_m = geo.shear2_n_m = 0.0;
  geo.shear_damping1_n_s_m = geo.shear_damping2_n_s_m = 0.0;
  const Model5Result no_shear = simulate_model5_detailed(table2(), geo, trial3());
  EXPECT_LT(no_shear.tilt_x_rad.cwiseAbs().maxCoeff(), 1e-9);
  EXPECT_LT(no_shear.tilt_y_rad.cwiseAbs().maxCoeff(), 1e-9);
}

TEST(Model5, InitialTiltLevelsOut) {
  // A face landing tilted (+x side low) touches first with that side, which
  // the mat pushes up: the tilt must fall during contact.
  Model5Geometry geo;
  geo.tilt_x0_rad = 0.05;
  const Model5Result r = simulate_model5_detailed(table2(), geo, trial3());
  Eigen::Index i = 0;
  r.sim.grf_n.maxCoeff(&i);
  EXPECT_NEAR(r.tilt_x_rad(0), 0.05, 1e-12);
  EXPECT_LT(r.tilt_x_rad(i), 0.05);
  // At t = 0 the low corner is at the mat top: the centre is above it.
  EXPECT_NEAR(r.sim.impactor_m(0), -0.05 * 0.125, 1e-12);
}

TEST(Model5, EachTiltHasItsOwnInertia) {
  // Landing tilted about both axes, with a huge moment of inertia against
  // tilt_x only: tilt_x must keep its initial value while tilt_y levels out.
  Model5Geometry geo;
  geo.tilt_x0_rad = 0.02;
  geo.tilt_y0_rad = 0.02;
  geo.inertia_tilt_x_kg_m2 = 1e6;
  const Model5Result r = simulate_model5_detailed(table2(), geo, trial3());
  Eigen::Index i = 0;
  r.sim.grf_n.maxCoeff(&i);
  EXPECT_NEAR(r.tilt_x_rad(i), 0.02, 1e-5);
  EXPECT_LT(r.tilt_y_rad(i), 0.01);
}

TEST(Model5, HalvingTheStepChangesPeakByLessThanHalfAPercent) {
  Model5Geometry geo;
  const Model5Result base = simulate_model5_detailed(table2(), geo, trial3());
  geo.max_step_s = 0.5 * base.step_s;
  const Model5Result half = simulate_model5_detailed(table2(), geo, trial3());
  geo.max_step_s = 0.1 * base.step_s;
  const Model5Result tenth = simulate_model5_detailed(table2(), geo, trial3());
  ASSERT_NEAR(half.step_s, 0.5 * base.step_s, 1e-12);
  EXPECT_LT(std::abs(half.peak_grf_n / base.peak_grf_n - 1.0), 0.005);
  EXPECT_LT(std::abs(tenth.peak_grf_n / base.peak_grf_n - 1.0), 0.005);
  const double peak = tenth.peak_grf_n;
  EXPECT_LT(max_abs_diff(base.sim.grf_n, tenth.sim.grf_n), 0.005 * peak);
}

TEST(Model5, ShearSpreadsTheDentBeyondTheFace) {
  // At peak force, the top layer under a cell outside the 0.25 m face (centre
  // (0.30, 0.05) m: the face ends at x = 0.125 m) moves only through shear.
  Model5Geometry geo;
  const Model5Result with_shear = simulate_model5_detailed(table2(), geo, trial3());
  const Eigen::Index ix = nearest(with_shear.node_x_m, 0.30), iy = nearest(with_shear.node_y_m, 0.05);
  ASSERT_NEAR(with_shear.node_x_m(ix), 0.30, 1e-12);
  const double centre = with_shear.sim.layer1_m.maxCoeff();
  EXPECT_GT(with_shear.surface_at_peak_m(iy, ix), 0.1 * centre);
  EXPECT_GT(with_shear.layer_dent_area_at_peak_m2, 3.0 * 0.25 * 0.25);

  geo.shear1_n_m = geo.shear2_n_m = 0.0;
  geo.shear_damping1_n_s_m = geo.shear_damping2_n_s_m = 0.0;
  const Model5Result point_elastic = simulate_model5_detailed(table2(), geo, trial3());
  EXPECT_EQ(point_elastic.surface_at_peak_m(iy, ix), 0.0);
  EXPECT_EQ(point_elastic.surface_at_peak_m.row(0).cwiseAbs().maxCoeff(), 0.0);  // y = -0.25 m row
}

TEST(Model5, ShearRigidityMeansTheSameOnAFinerGrid) {
  // S is a continuum parameter (pair stiffness S dy/dx): doubling the grid
  // must change the answer only by discretisation, not by a factor.
  Model5Geometry coarse;
  Model5Geometry fine = coarse;
  fine.nodes_x = 18;
  fine.nodes_y = 12;
  const Model5Result a = simulate_model5_detailed(table2(), coarse, trial3());
  const Model5Result b = simulate_model5_detailed(table2(), fine, trial3());
  EXPECT_NEAR(b.peak_grf_n, a.peak_grf_n, 0.03 * a.peak_grf_n);
  EXPECT_NEAR(b.layer_dent_area_at_peak_m2, a.layer_dent_area_at_peak_m2, 0.15 * a.layer_dent_area_at_peak_m2);
}

TEST(Model5, RejectsImpossibleInput) {
  const Model5Geometry geo;
  MatParams p = table2();
  p.m1_kg = 0.0;
  EXPECT_THROW(simulate_model5(p, geo, trial3()), Error);
  p = table2();
  p.k2_n_m = -1.0;
  EXPECT_THROW(simulate_model5(p, geo, trial3()), Error);
  p = table2();
  p.maxwell_k_n_m = 1000.0;
  p.maxwell_tau_s = 0.01;
  EXPECT_THROW(simulate_model5(p, geo, trial3()), Error);
  Model5Geometry off = geo;
  off.impact_x_m = 1.0;  // face [0.875, 1.125] m, mat ends at 0.45 m
  EXPECT_THROW(simulate_model5(table2(), off, trial3()), Error);
  Model5Geometry no_cells = geo;
  no_cells.nodes_y = 0;
  EXPECT_THROW(simulate_model5(table2(), no_cells, trial3()), Error);
}


// ---------------------------------------------------------------------------
// Accuracy against a reference: the former explicit leapfrog (every force
// explicit; second order, stable at its step) at max_step_s = 1e-6 s, 100
// times below the default step and 9 times below the fastest time scale in
// these cases (m1 / (r1 w) = 9 us at r1 = 3e4 N s/m): its own error is below
// 0.01 % of peak (halving its step changes it by less). Cases: the paper's
// Table 2 parameters and the corners of the fitter's bounds (fitting/fit.h:
// stiffness 2e3..3e7 N/m, damping 3..3e4 N s/m).
struct Case {
  const char* name;
  double k, r;  // all three elements; k = 0: Table 2; k < 0: see case_params
  double rms_limit;
  double peak_limit = 0.005;
  // Each element on its own (k1, k2, k3, r1, r2, r3) when k1 > 0; k and r ignored.
  double each[6] = {0.0, 0.0, 0.0, 0.0, 0.0, 0.0};
};

MatParams case_params(const Case& c) {
  MatParams p = table2();
  if (c.each[0] > 0.0) {
    p.k1_n_m = c.each[0], p.k2_n_m = c.each[1], p.k3_n_m = c.each[2];
    p.r1_n_s_m = c.each[3], p.r2_n_s_m = c.each[4], p.r3_n_s_m = c.each[5];
  } else if (c.k < 0.0) {  // element 1 at its stiff, damped corner, the others Table 2's
    p.k1_n_m = 3e7;
    p.r1_n_s_m = 3e4;
  } else if (c.k > 0.0) {
    p.k1_n_m = p.k2_n_m = p.k3_n_m = c.k;
    p.r1_n_s_m = p.r2_n_s_m = p.r3_n_s_m = c.r;
  }
  return p;
}

class Model5Accuracy : public ::testing::TestWithParam<Case> {};

TEST_P(Model5Accuracy, MatchesTheFineStepReference) {
  const Case c = GetParam();
  const MatParams p = case_params(c);
  Model5Geometry fine;
  fine.max_step_s = 1e-6;
  const Model5Result ref = simulate_model5_leapfrog(p, fine, trial3());
  const Model5Result r = simulate_model5_detailed(p, Model5Geometry{}, trial3());
  ASSERT_EQ(r.sim.grf_n.size(), ref.sim.grf_n.size());
  const double peak = ref.sim.grf_n.maxCoeff();
  ASSERT_GT(peak, 500.0);
  // Peak within 0.5 % (the target); the whole force curve within
  // rms_limit of the peak (RMS over the 0.3 s).
  EXPECT_NEAR(r.sim.grf_n.maxCoeff(), peak, c.peak_limit * peak) << c.name;
  const double rms = std::sqrt((r.sim.grf_n - ref.sim.grf_n).squaredNorm() / static_cast<double>(ref.sim.grf_n.size()));
  EXPECT_LT(rms, c.rms_limit * peak) << c.name;
  // The impactor's travel within 0.5 mm RMS (a marker's noise).
  const double rms_z =
      std::sqrt((r.sim.impactor_m - ref.sim.impactor_m).squaredNorm() / static_cast<double>(ref.sim.grf_n.size()));
  EXPECT_LT(rms_z, 5e-4) << c.name;
}

// Limits: peak 0.5 %, RMS 1 % of peak (the targets; measured at most 0.23 %
// and 0.41 %, docs/models.md). Includes the stiff, nearly undamped corner
// where the light mat cells ring at up to 11 000 rad/s (the free columns are
// stepped exactly; the former explicit scheme at its own step: 4.6 % RMS).
INSTANTIATE_TEST_SUITE_P(TypicalAndBounds, Model5Accuracy,
                         ::testing::Values(Case{"table2", 0.0, 0.0, 0.01}, Case{"k_min_r_min", 2e3, 3.0, 0.01},
                                           Case{"k_min_r_max", 2e3, 3e4, 0.01}, Case{"k_max_r_min", 3e7, 3.0, 0.01},
                                           Case{"k_max_r_max", 3e7, 3e4, 0.01},
                                           Case{"k1_max_r1_max", -1.0, 0.0, 0.01},
                                           // Inside the bounds: near critical damping on element
                                           // 1's cells (a creep of 8 000 1/s, left to the stiff
                                           // limit: measured 0.05 %), and the heavily damped
                                           // interior where the explicit shear's splitting error
                                           // peaks (measured 1.43 % of peak, 0.66 % RMS; second
                                           // order in the step: docs/models.md).
                                           Case{"near_critical", 3e7, 6000.0, 0.01},
                                           Case{"damped_interior", 1e6, 3e4, 0.01, 0.015},
                                           // Long contacts whose creep limited the step while
                                           // the face pressed (4 960, 8 102, 7 310 steps), now
                                           // on the slow-load steps (docs/models.md, Step).
                                           Case{"creep_long_contact", 0.0, 0.0, 0.01, 0.005,
                                                {2.8e7, 8.9e4, 3.8e4, 1.5e4, 280.0, 850.0}},
                                           Case{"creep_element2_soft_top", 0.0, 0.0, 0.01, 0.005,
                                                {3.47e3, 2.89e7, 4.88e5, 4.15, 1.84e4, 162.0}},
                                           Case{"creep_stiff_top_soft_base", 0.0, 0.0, 0.01, 0.005,
                                                {2.43e7, 2.79e7, 2.58e3, 1.42e4, 283.0, 94.2}}),
                         [](const auto& info) { return std::string(info.param.name); });

TEST(Model5, StepIsSetByAccuracyNotStability) {
  // The vertical elements are implicit: stiff, undamped elements keep
  // max_step_s; stiff, overdamped ones creep at 2 k / (r + sqrt(r^2 - 4 k m))
  // (1150 1/s for element 3 at k = 3e7, r = 3e4, m = 3.66 / 54 kg) and get
  // 0.07 / that: 1/17 of the 1 ms output step. The explicit scheme fell to
  // 3.3 us there.
  const Model5Result typical = simulate_model5_detailed(table2(), Model5Geometry{}, trial3());
  EXPECT_NEAR(typical.step_s, 1e-4, 1e-12);
  const Model5Result undamped = simulate_model5_detailed(case_params({"", 3e7, 3.0, 0.0}), Model5Geometry{}, trial3());
  EXPECT_NEAR(undamped.step_s, 1e-4, 1e-12);
  const Model5Result damped = simulate_model5_detailed(case_params({"", 3e7, 3e4, 0.0}), Model5Geometry{}, trial3());
  EXPECT_NEAR(damped.step_s, 1e-3 / 17, 1e-12);
  // Near critical damping the slow root is fast (8 000 1/s on element 1's
  // cells at r = 6000 N s/m): it settles within the step and the stiffly
  // accurate stages give its quasi-static limit; the step stays max_step_s
  // (it was 8.4 us, 35 600 steps, when every creep was resolved).
  const Model5Result critical = simulate_model5_detailed(case_params({"", 3e7, 6000.0, 0.0}), Model5Geometry{}, trial3());
  EXPECT_NEAR(critical.step_s, 1e-4, 1e-12);
  const Model5Result old = simulate_model5_leapfrog(case_params({"", 3e7, 3e4, 0.0}), Model5Geometry{}, trial3());
  EXPECT_LT(old.step_s, 1e-5);
}

// The slow-load rules (model5.h, Integration): a long contact whose load
// changes slowly steps without the creep limit and, after 0.1 s, at twice
// max_step_s; counted in steps (not timed). Table 2 (contact over by 0.1 s,
// not creep-limited) is stepped exactly as before.
TEST(Model5, SlowLoadTakesLongerSteps) {
  Model5Geometry off;
  off.creep_slow_load = 0.0;
  off.slow_step_load = 0.0;
  off.slow_step_factor = 1.0;
  const Model5Geometry on;
  const Model5Result t2_off = simulate_model5_detailed(table2(), off, trial3());
  const Model5Result t2_on = simulate_model5_detailed(table2(), on, trial3());
  EXPECT_EQ(t2_off.steps, 3070);
  EXPECT_LE(t2_on.steps, t2_off.steps);
  EXPECT_LT(max_abs_diff(t2_on.sim.grf_n, t2_off.sim.grf_n), 1e-4 * t2_off.peak_grf_n);
  struct Long {
    MatParams p;
    long steps_off, steps_max;
  };
  MatParams soft = table2();
  soft.k1_n_m = soft.k2_n_m = soft.k3_n_m = 2e3;
  soft.r1_n_s_m = soft.r2_n_s_m = soft.r3_n_s_m = 3.0;
  const Long cases[] = {
      {soft, 3070, 2100},  // measured 2 070
      {case_params(Case{"", 0.0, 0.0, 0.0, 0.0, {2.8e7, 8.9e4, 3.8e4, 1.5e4, 280.0, 850.0}}), 4960, 3500},  // 3 448
      {case_params(Case{"", 0.0, 0.0, 0.0, 0.0, {3.47e3, 2.89e7, 4.88e5, 4.15, 1.84e4, 162.0}}), 8102, 2400},  // 2 334
      {case_params(Case{"", 0.0, 0.0, 0.0, 0.0, {2.43e7, 2.79e7, 2.58e3, 1.42e4, 283.0, 94.2}}), 7310, 2800},  // 2 720
  };
  for (const Long& c : cases) {
    EXPECT_EQ(simulate_model5_detailed(c.p, off, trial3()).steps, c.steps_off);
    EXPECT_LE(simulate_model5_detailed(c.p, on, trial3()).steps, c.steps_max);
  }
}

TEST(Model5, FirstOutputOffsetSamplesBetweenTheSteps) {
  // first_output_s shifts the samples: the series at 0.4 ms must lie
  // between its neighbours on a 0.1 ms grid (linear interpolation of the
  // unshifted fine series, within 0.2 % of peak: the curve's curvature over
  // 0.1 ms).
  Impact fine = trial3();
  fine.output_dt_s = 1e-4;
  const Simulation a = simulate_model5(table2(), Model5Geometry{}, fine);
  Impact shifted = trial3();
  shifted.first_output_s = 4e-4;
  const Simulation b = simulate_model5(table2(), Model5Geometry{}, shifted);
  ASSERT_NEAR(b.t_s(0), 4e-4, 1e-15);
  const double peak = a.grf_n.maxCoeff();
  for (int i = 0; i + 1 < b.t_s.size(); ++i) {
    const int k = 4 + 10 * i;  // same time on the fine grid
    ASSERT_NEAR(a.t_s(k), b.t_s(i), 1e-12);
    EXPECT_NEAR(b.grf_n(i), a.grf_n(k), 0.002 * peak) << "t " << b.t_s(i);
  }
}

// ---------------------------------------------------------------------------
// Exact derivatives: the Jet version against central differences of the
// double version, per parameter, over the three fitted series.
TEST(Model5, FitterParameterBlockMapsOntoModel5) {
  // The fitter's Model 4 block (detail::ParamsT) carries the same values
  // into Model 5, and the same simulation follows.
  MatParams p = table2();
  p.r1_unload_n_s_m = 120.0;
  const Model5ParamsT<double> a = model5_params(p);
  const Model5ParamsT<double> b = model5_params_t(detail::to_params_t<double>(ModelKind::Model4, p));
  EXPECT_EQ(a.k1_n_m, b.k1_n_m);
  EXPECT_EQ(a.k3_n_m, b.k3_n_m);
  EXPECT_EQ(a.r2_n_s_m, b.r2_n_s_m);
  EXPECT_EQ(a.m2_kg, b.m2_kg);
  EXPECT_EQ(a.r1_unload_n_s_m, 120.0);
  EXPECT_EQ(b.r1_unload_n_s_m, 120.0);
  EXPECT_TRUE(b.hysteresis);
  std::vector<double> ga, gb;
  simulate_model5_t<double>(a, Model5Geometry{}, trial3(), 301, &ga, nullptr, nullptr);
  simulate_model5_t<double>(b, Model5Geometry{}, trial3(), 301, &gb, nullptr, nullptr);
  EXPECT_EQ(ga, gb);
  // And simulate_model5 (the Simulation path) gives the same force: to
  // rounding, since it may run the AVX2/FMA copy (core/cpu_dispatch.h)
  // where this test's own instantiation runs the baseline one.
  const Simulation s = simulate_model5(p, Model5Geometry{}, trial3());
  const double peak_n = s.grf_n.maxCoeff();
  double worst_n = 0.0;
  for (int k = 0; k < 301; ++k) worst_n = std::max(worst_n, std::abs(s.grf_n(k) - ga[k]));
  EXPECT_LE(worst_n, 1e-12 * peak_n);  // measured 1.5e-14 of the peak
  p.maxwell_k_n_m = 1000.0;
  p.maxwell_tau_s = 0.01;
  EXPECT_THROW(model5_params_t(detail::to_params_t<double>(ModelKind::Model4, p)), Error);
}

void expect_jet_matches_central_differences(const MatParams& params) {
  using J = ceres::Jet<double, 8>;
  const Model5Geometry geo;
  Impact im = trial3();
  im.duration_s = 0.1;  // the contact and the rebound
  const int n = 101;
  const Model5ParamsT<double> base = model5_params(params);
  auto field = [](auto& p, int i) -> auto& {
    switch (i) {
      case 0: return p.k1_n_m;
      case 1: return p.k2_n_m;
      case 2: return p.k3_n_m;
      case 3: return p.r1_n_s_m;
      case 4: return p.r2_n_s_m;
      case 5: return p.r3_n_s_m;
      case 6: return p.m1_kg;
      default: return p.m2_kg;
    }
  };
  Model5ParamsT<J> pj;
  for (int i = 0; i < 8; ++i) field(pj, i) = J(field(base, i), i);
  pj.r1_unload_n_s_m = J(base.r1_unload_n_s_m);
  std::vector<J> gj, zj, sj;
  simulate_model5_t<J>(pj, geo, im, n, &gj, &zj, &sj);
  std::vector<double> g0, z0, s0;
  simulate_model5_t<double>(base, geo, im, n, &g0, &z0, &s0);
  for (int k = 0; k < n; ++k) {
    // The Jet's values are the double run's (to rounding: the operations are grouped differently).
    ASSERT_NEAR(gj[k].a, g0[k], 1e-9 * (1.0 + std::abs(g0[k])));
    ASSERT_NEAR(zj[k].a, z0[k], 1e-12);
  }
  for (int i = 0; i < 8; ++i) {
    // Relative step 1e-5: truncation (h^2) and rounding (1e-16 / h) both
    // near 1e-10 relative, far below the 1e-4 asked.
    const double h = 1e-5 * field(base, i);
    Model5ParamsT<double> lo = base, hi = base;
    field(lo, i) -= h;
    field(hi, i) += h;
    std::vector<double> gl, zl, sl, gh, zh, sh;
    simulate_model5_t<double>(lo, geo, im, n, &gl, &zl, &sl);
    simulate_model5_t<double>(hi, geo, im, n, &gh, &zh, &sh);
    double num = 0.0, den = 0.0, num_z = 0.0, den_z = 0.0, num_s = 0.0, den_s = 0.0;
    for (int k = 0; k < n; ++k) {
      const double cd = (gh[k] - gl[k]) / (2 * h), cz = (zh[k] - zl[k]) / (2 * h), cs = (sh[k] - sl[k]) / (2 * h);
      num += std::pow(gj[k].v[i] - cd, 2);
      den += cd * cd;
      num_z += std::pow(zj[k].v[i] - cz, 2);
      den_z += cz * cz;
      num_s += std::pow(sj[k].v[i] - cs, 2);
      den_s += cs * cs;
    }
    ASSERT_GT(den, 0.0) << "parameter " << i;
    std::printf("  parameter %d: relative error grf %.2e impactor %.2e surface %.2e\n", i, std::sqrt(num / den),
                std::sqrt(num_z / den_z), std::sqrt(num_s / den_s));
    EXPECT_LT(std::sqrt(num / den), 1e-4) << "grf, parameter " << i;
    EXPECT_LT(std::sqrt(num_z / den_z), 1e-4) << "impactor, parameter " << i;
    EXPECT_LT(std::sqrt(num_s / den_s), 1e-4) << "surface, parameter " << i;
  }
}

TEST(Model5, JetDerivativesMatchCentralDifferences) { expect_jet_matches_central_differences(table2()); }

TEST(Model5, JetDerivativesMatchCentralDifferencesStiffDamped) {
  expect_jet_matches_central_differences(case_params({"", 3e7, 3e4, 0.0}));
}

TEST(Model5, JetDerivativesMatchCentralDifferencesSoftDamped) {
  expect_jet_matches_central_differences(case_params({"", 2e3, 3e4, 0.0}));
}

}  // namespace
}  // namespace dropfit::fitting
