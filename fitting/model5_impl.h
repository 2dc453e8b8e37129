#pragma once
// Model 5 (fitting/model5.h) templated on the scalar type, so that
// ceres::Jet flows through it (exact derivatives for the fitter), and the
// integrator that keeps it stable and fast at any stiffness and damping.
// Its parts: fitting/model5_layout.h (the parameters in the scalar type,
// the grid and the steps), fitting/model5_dual.h (the dual numbers a Jet
// runs on), fitting/model5_integrator.h (the integrator); here, the
// stepping over the output samples and the entry point simulate_model5_t.
//
// Integration (see model5.h, "Integration", for the reasoning): the forces
// split in two parts.
//   A (stiff, implicit): the three vertical elements of every node column
//     (k1, r1 contact with the face while it presses; k2, r2; k3, r3), the
//     impactor's inertia and gravity. Node by node they are local; all
//     columns under the face share the impactor, an arrow-shaped linear
//     system solved exactly per stage by eliminating the columns (2 x 2
//     each) onto the impactor's three coordinates (a 3 x 3 Schur
//     complement). Integrated by the three-stage, L-stable, stiffly
//     accurate SDIRK of order 3 (Alexander 1977, SIAM J. Numer. Anal.
//     14:1006; see implicit_step): stiff damping is damped, not amplified,
//     and the step does not depend on k or r.
//   B (explicit): the layers' shear coupling (fixed geometry, not fitted)
//     and element 1's cubic term, as half kicks before and after each A
//     step (Strang splitting; each half kick by the explicit midpoint rule,
//     so shear damping keeps second order). The step is bounded by B's
//     stability (shear rigidity over node masses), not by k or r.
// Within a step the contact set (which columns the face presses) and
// element 1's loading/unloading damping are those found at the step's
// start, as in the explicit scheme. The linear algebra depends on them
// only, so it is rebuilt only when they change.
//
// For a Jet, branches (contact, unloading) follow the scalar parts, so the
// derivative is that of the scheme's discrete solution with the contact
// pattern held: exact for the discrete model between pattern changes.
#include <ceres/jet.h>

#include <algorithm>
#include <type_traits>
#include <vector>

#include "fitting/model5_integrator.h"
#include "fitting/model5_layout.h"

namespace dropfit::fitting {

namespace model5_detail {

constexpr int kStartRefine = 8;

// Runs an integrator over the samples t_i = first_output_s + i output_dt_s:
// record.after_step(integrator, contact_force, t) after every step (and at
// t = 0), record(i, integrator, contact_force) at each sample.
template <typename T, typename Record>
void run(Integrator<T>& it, const Layout& L, const Impact& imp, int n_samples, Record& record) {
  if (n_samples <= 0) return;
  T f = it.contact();
  record.after_step(it, f, 0.0);
  // The first output interval (and the way to first_output_s) in steps
  // kStartRefine times shorter: the face lands with its full speed on
  // light cells, a transient as fast as m / r1 that a full step would
  // smear into the first samples.
  const int nf = L.n_first * kStartRefine;
  for (int s = 0; s < nf; ++s) {
    it.step(L.first_step_s / kStartRefine);
    if (s + 1 == nf) it.sync();
    f = it.contact();
    record.after_step(it, f, (s + 1) * L.first_step_s / kStartRefine);
  }
  // The impactor's heave velocity at the last four interval starts and the
  // largest mean contact force over an interval so far (scalar parts: the
  // step pattern is the same for a Jet).
  double v0 = 0.0, v1 = 0.0, v2 = 0.0, v3 = 0.0, f_max = 0.0;
  int pressed0 = -1, pressed1 = -1;
  const double dt_out = imp.output_dt_s, mass = imp.mass_kg, gravity = imp.gravity_m_s2;
  for (int i = 0; i < n_samples; ++i) {
    if (i > 0) {
      const double t0 = imp.first_output_s + (i - 1) * imp.output_dt_s;
      const int refine = i == 1 ? kStartRefine : 1;
      // The creep limit on the step matters only while the face presses
      // (pressed columns take the implicit stages; free ones are exact): an
      // interval the face is sure to spend clear of the mat takes the free
      // step (after the rebound: most of the 0.3 s at the stiff, damped
      // corner).
      const bool limited = i > 1 && L.n_sub_free < L.n_sub;
      const bool clear = limited && it.clear_of_contact(imp.output_dt_s);
      // While the face presses and the load is slow, neither the creep
      // limit nor the full accuracy cap is needed: the stages' error on a
      // stiff, slow mode follows the curvature of its quasi-static path
      // (order reduction; Prothero & Robinson 1974), and so do the
      // splitting errors of the shear against stiff damping, i.e. the
      // curvature of the contact force. The measure: the second difference
      // of the mean contact force over the last three intervals (from the
      // impactor's momentum: smooth, where the force at an instant carries
      // unresolved transients), over its largest mean so far, with the same
      // cells pressed at the last three interval starts. At most
      // slow_load_bound (creep-limited runs): the free step; at most
      // slow_step_bound too: the slow step (slow_step_factor x the free
      // one). Long contacts of a soft mat run on the slow step; a hard
      // impact's rise and fall keep the full one.
      v0 = v1, v1 = v2, v2 = v3, v3 = detail::scalar_of(it.vc());
      if (i > 1) f_max = std::max(f_max, std::abs(mass * (gravity - (v3 - v2) / dt_out)));
      const int pressed = it.pressed_count();
      const bool steady = !clear && i > 4 && pressed > 0 && pressed == pressed1 && pressed == pressed0;
      const double d2 = mass * std::abs(v3 - 3.0 * v2 + 3.0 * v1 - v0);
      const bool slow_load = steady && d2 <= L.slow_load_bound * f_max * dt_out;
      const bool slow = L.n_sub_slow < L.n_sub_free && t0 >= L.slow_after_s &&
                        ((L.slow_any_load && pressed > 0) ||
                         (steady && d2 <= L.slow_step_bound * f_max * dt_out && (!limited || slow_load)));
      const bool unlimited = clear || (limited && slow_load);
      pressed0 = pressed1, pressed1 = pressed;
      const int n = slow ? L.n_sub_slow : (unlimited ? L.n_sub_free : L.n_sub * refine);
      const double h = slow ? L.step_slow_s : (unlimited ? L.step_free_s : L.step_s / refine);
      for (int s = 0; s < n; ++s) {
        it.step(h);
        if (s + 1 == n) it.sync();
        f = it.contact();
        record.after_step(it, f, t0 + (s + 1) * h);
      }
    }
    record(i, it, f);
  }
}

}  // namespace model5_detail

namespace model5_detail {

template <typename T>
struct IsJet : std::false_type {};
template <int N>
struct IsJet<ceres::Jet<double, N>> : std::true_type {};

template <typename T>
void simulate_plain(const Model5ParamsT<T>& params, const Model5Geometry& geometry, const Impact& impact,
                    int n_samples, std::vector<T>* grf, std::vector<T>* impactor, std::vector<T>* surface) {
  Model5ParamsT<double> scalar;
  scalar.k1_n_m = detail::scalar_of(params.k1_n_m);
  scalar.k2_n_m = detail::scalar_of(params.k2_n_m);
  scalar.k3_n_m = detail::scalar_of(params.k3_n_m);
  scalar.r1_n_s_m = detail::scalar_of(params.r1_n_s_m);
  scalar.r2_n_s_m = detail::scalar_of(params.r2_n_s_m);
  scalar.r3_n_s_m = detail::scalar_of(params.r3_n_s_m);
  scalar.m1_kg = detail::scalar_of(params.m1_kg);
  scalar.m2_kg = detail::scalar_of(params.m2_kg);
  scalar.k1_cubic_n_m3 = detail::scalar_of(params.k1_cubic_n_m3);
  scalar.r1_unload_n_s_m = detail::scalar_of(params.r1_unload_n_s_m);
  scalar.cubic = params.cubic;
  scalar.hysteresis = params.hysteresis;
  const Layout L = make_layout(scalar, geometry, impact);
  for (std::vector<T>* v : {grf, impactor, surface})
    if (v) v->assign(std::max(n_samples, 0), T(0.0));
  Integrator<T> it(params, geometry, impact, L);
  struct Rec {
    std::vector<T>*grf, *impactor, *surface;
    void operator()(int i, const Integrator<T>& s, const T&) const {
      if (grf) (*grf)[i] = s.grf();
      if (impactor) (*impactor)[i] = s.zc();
      if (surface) (*surface)[i] = s.surface();
    }
    void after_step(const Integrator<T>&, const T&, double) const {}
  } rec{grf, impactor, surface};
  run(it, L, impact, n_samples, rec);
}

// A ceres::Jet runs on Dual (see there) and is copied back.
template <int N>
void simulate_jet(const Model5ParamsT<ceres::Jet<double, N>>& params, const Model5Geometry& geometry,
                  const Impact& impact, int n_samples, std::vector<ceres::Jet<double, N>>* grf,
                  std::vector<ceres::Jet<double, N>>* impactor, std::vector<ceres::Jet<double, N>>* surface) {
  using J = ceres::Jet<double, N>;
  using D = Dual<N>;
  auto to_dual = [](const J& j) {
    D d(j.a);
    for (int i = 0; i < N; ++i) d.v[i] = j.v[i];
    return d;
  };
  Model5ParamsT<D> p;
  p.k1_n_m = to_dual(params.k1_n_m);
  p.k2_n_m = to_dual(params.k2_n_m);
  p.k3_n_m = to_dual(params.k3_n_m);
  p.r1_n_s_m = to_dual(params.r1_n_s_m);
  p.r2_n_s_m = to_dual(params.r2_n_s_m);
  p.r3_n_s_m = to_dual(params.r3_n_s_m);
  p.m1_kg = to_dual(params.m1_kg);
  p.m2_kg = to_dual(params.m2_kg);
  p.k1_cubic_n_m3 = to_dual(params.k1_cubic_n_m3);
  p.r1_unload_n_s_m = to_dual(params.r1_unload_n_s_m);
  p.cubic = params.cubic;
  p.hysteresis = params.hysteresis;
  std::vector<D> g, z, s;
  simulate_plain<D>(p, geometry, impact, n_samples, grf ? &g : nullptr, impactor ? &z : nullptr,
                    surface ? &s : nullptr);
  auto back = [](const std::vector<D>& in, std::vector<J>* out) {
    if (!out) return;
    out->resize(in.size());
    for (std::size_t k = 0; k < in.size(); ++k) {
      (*out)[k].a = in[k].a;
      for (int i = 0; i < N; ++i) (*out)[k].v[i] = in[k].v[i];
    }
  };
  back(g, grf);
  back(z, impactor);
  back(s, surface);
}

}  // namespace model5_detail

// Model 5 for the fitter: the samples t_i = first_output_s + i output_dt_s,
// i < n_samples, of the ground reaction force, the impactor face centre's
// travel and element 1's top under the face centre (as simulate_model5's
// Simulation::grf_n, impactor_m, surface_m). Any null output is skipped.
// T: double, or ceres::Jet<double, N> (the derivatives of the discrete
// solution with the contact pattern held; see the header comment). Throws
// Error for what simulate_model5 rejects.
template <typename T>
void simulate_model5_t(const Model5ParamsT<T>& params, const Model5Geometry& geometry, const Impact& impact,
                       int n_samples, std::vector<T>* grf, std::vector<T>* impactor, std::vector<T>* surface) {
  if constexpr (model5_detail::IsJet<T>::value) {
    model5_detail::simulate_jet(params, geometry, impact, n_samples, grf, impactor, surface);
  } else {
    model5_detail::simulate_plain(params, geometry, impact, n_samples, grf, impactor, surface);
  }
}

}  // namespace dropfit::fitting
