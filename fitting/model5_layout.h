#pragma once
// Model 5's parameters in the simulation's scalar type and the geometry and
// timing every scalar type shares (the grid of node columns, the face's
// contact weights, the shear stencil, the integration steps), built once
// per simulation by make_layout (fitting/model5.cpp).
#include <Eigen/Core>
#include <vector>

#include "core/error.h"
#include "fitting/model5.h"
#include "fitting/models_impl.h"

namespace dropfit::fitting {

// The parameters Model 5 uses, in the scalar type of the simulation. The
// fitter's free parameters (k1..k3, r1..r3, m1, m2; the effects when fitted)
// are the ones that may carry derivatives.
template <typename T>
struct Model5ParamsT {
  T k1_n_m = T(0.0), k2_n_m = T(0.0), k3_n_m = T(0.0);
  T r1_n_s_m = T(0.0), r2_n_s_m = T(0.0), r3_n_s_m = T(0.0);
  T m1_kg = T(0.0), m2_kg = T(0.0);
  T k1_cubic_n_m3 = T(0.0);
  T r1_unload_n_s_m = T(0.0);
  bool cubic = false;       // k1_cubic in play
  bool hysteresis = false;  // r1_unload replaces r1 while element 1 extends
};

// From MatParams (throws Error for what Model 5 cannot use, as
// simulate_model5 does).
Model5ParamsT<double> model5_params(const MatParams& params);

// From the fitter's templated parameter block (fitting/models_impl.h, laid
// out as Model 4: k[0..2], r[0..2], m1, m2 and the effects), so that Jets
// from the fit's parameter space flow straight in. Throws Error if the
// Maxwell arm is on (Model 5 does not carry it).
template <typename T>
Model5ParamsT<T> model5_params_t(const detail::ParamsT<T>& p) {
  if (p.maxwell) throw Error("model5: the Maxwell arm (maxwell_k_n_m > 0) is not carried by Model 5");
  Model5ParamsT<T> q;
  q.k1_n_m = p.k[0];
  q.k2_n_m = p.k[1];
  q.k3_n_m = p.k[2];
  q.r1_n_s_m = p.r[0];
  q.r2_n_s_m = p.r[1];
  q.r3_n_s_m = p.r[2];
  q.m1_kg = p.m1;
  q.m2_kg = p.m2;
  q.k1_cubic_n_m3 = p.k1_cubic;
  q.cubic = p.cubic;
  q.hysteresis = p.hysteresis;
  q.r1_unload_n_s_m = p.hysteresis ? p.r1_unload : p.r[0];
  return q;
}

namespace model5_detail {

// Geometry and timing shared by every scalar type (doubles only).
struct Layout {
  int nx = 0, ny = 0, n = 0;           // cells, n = nx * ny; flat index j = ix * ny + iy
  double dx = 0.0, dy = 0.0, x0 = 0.0, y0 = 0.0, face_area = 0.0;
  bool framed = false;
  std::vector<double> w, lx, ly;       // contact weight and lever arms per cell
  std::vector<int> face;               // cells the face covers (w > 0)
  // Shear stencil: pairs (a, b) with geometric factor (dy/dx along x, dx/dy
  // along y); frame links (cell, factor) with the factor already doubled.
  std::vector<int> pair_a, pair_b;
  std::vector<double> pair_f;
  std::vector<int> frame_cell;
  std::vector<double> frame_f;
  std::vector<double> frame_w;         // frame factor per cell (0 inside or when free)
  double inertia_x = 0.0, inertia_y = 0.0;  // impactor's tilt inertias
  double shear_gamma = 0.0;  // bound on the shear damping's rate (1/s)
  double zc0 = 0.0, tx0 = 0.0, ty0 = 0.0, wx0 = 0.0, wy0 = 0.0;
  int px = 0, py = 0, px1 = 0, py1 = 0;     // probe under the face centre
  double fxw = 0.0, fyw = 0.0;
  Eigen::VectorXd node_x_m, node_y_m;
  double step_s = 0.0;   // integration step while the face presses (divides output_dt_s)
  int n_sub = 1;         // steps per output step
  // Step while the face is clear of the mat (no creep limit: every column
  // is then stepped exactly, see choose_step); n_sub_free <= n_sub.
  double step_free_s = 0.0;
  int n_sub_free = 1;
  // The creep rate that limits step_s (0 if none does: step_s is then
  // step_free_s) and the bound on the contact force's second difference
  // per output interval, over the largest contact force so far, below which
  // an interval the face presses takes step_free_s (see run).
  double creep_rate_1_s = 0.0;
  double slow_load_bound = 0.0;
  // A slow interval (second difference at most slow_step_bound times the
  // largest mean force) takes n_sub_slow steps of step_slow_s
  // (slow_step_factor x max_step_s; n_sub_slow <= n_sub_free).
  double slow_step_bound = 0.0;
  double step_slow_s = 0.0;
  int n_sub_slow = 1;
  double slow_after_s = 0.0;  // slow steps only in intervals starting at or after this
  bool slow_any_load = false;  // layers lightly damped: slow steps whatever the load's curvature
  int n_first = 0;       // steps to reach first_output_s (0 if it is 0)
  double first_step_s = 0.0;
};

// Validates (throws Error) and builds the layout; the parameters' scalar
// parts choose nothing but are checked.
Layout make_layout(const Model5ParamsT<double>& params, const Model5Geometry& geometry, const Impact& impact);

// Samples a simulation produces for `impact`: t = first_output_s + i * output_dt_s <= duration_s.
int sample_count(const Impact& impact);

// The checks every Model 5 simulation starts with: finite, non-negative
// elements, positive masses, a geometry the grid can be built on, a usable
// output timing (throws Error naming the offending value).
void validate(const MatParams& params, const Model5Geometry& geometry, const Impact& impact);

// Length of the overlap of [a0, a1] and [b0, b1] (0 when disjoint), and its centre.
double overlap(double a0, double a1, double b0, double b1, double* centre);

// Bilinear weights of position p among cell centres c0 + i * d, i = 0..n-1,
// clamped to the outer centres: p lies between centres i0 and i0 + 1 with
// weight (1 - f) and f.
void bracket(double p, double c0, double d, int n, int* i0, double* f);


}  // namespace model5_detail
}  // namespace dropfit::fitting
