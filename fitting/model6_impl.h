#pragma once
// Model 6 (fitting/model6.h) templated on the scalar type, so that
// ceres::Jet flows through it: the fitter's exact derivatives. For a Jet
// every branch (contact, Newton's stopping, the densification's tangent
// continuation) follows the scalar parts, so the derivative is that of the
// discrete solution with those decisions held.
#include <ceres/jet.h>

#include <algorithm>
#include <cmath>
#include <type_traits>
#include <vector>

#include "core/error.h"
#include "fitting/model6.h"

namespace dropfit::fitting {

template <typename T>
struct FoamLawT {
  T plateau_pa, modulus_pa, hardening_pa, densification_pa, densification_strain, densification_exponent;
};

// Model 6's parameters in the simulation's scalar type.
template <typename T>
struct Model6ParamsT {
  FoamLawT<T> top, base;
  T prony_g1, prony_tau1_s, prony_g2, prony_tau2_s;
  T viscosity_pa_s;
  T top_mass_kg, base_mass_kg;
};

template <typename T>
FoamLawT<T> foam_law_t(const FoamLaw& l) {
  return {T(l.plateau_pa),       T(l.modulus_pa),           T(l.hardening_pa),
          T(l.densification_pa), T(l.densification_strain), T(l.densification_exponent)};
}

template <typename T>
Model6ParamsT<T> model6_params_t(const Model6Params& p) {
  return {foam_law_t<T>(p.top), foam_law_t<T>(p.base), T(p.prony_g1), T(p.prony_tau1_s), T(p.prony_g2), T(p.prony_tau2_s),
          T(p.viscosity_pa_s), T(p.top_mass_kg), T(p.base_mass_kg)};
}

// What a simulation may return beside the plate force and the face travel.
struct Model6Extras {
  std::vector<double> surface_m, interface_m, top_strain, base_strain;
  double separation_s = std::numeric_limits<double>::quiet_NaN();
  long steps = 0;
  double step_s = 0.0;
};

namespace model6_detail {

inline double val(double x) { return x; }
template <typename S, int N>
double val(const ceres::Jet<S, N>& x) {
  return x.a;
}

// r^n; a constant exponent (the fitter's) through the scalar power, and
// n = 2 as a product.
inline double power(double r, double n) { return n == 2.0 ? r * r : std::pow(r, n); }
template <typename S, int N>
ceres::Jet<S, N> power(const ceres::Jet<S, N>& r, const ceres::Jet<S, N>& n) {
  if (!n.v.isZero()) return pow(r, n);
  return n.a == 2.0 ? r * r : pow(r, n.a);
}

// Elastic stress s and tangent ds of a law at strain e (model6.h).
template <typename T>
void elastic(const FoamLawT<T>& L, const T& e, T* s, T* ds) {
  using std::tanh;
  const T th = tanh(L.modulus_pa * e / L.plateau_pa);
  *s = L.plateau_pa * th + L.hardening_pa * e;
  *ds = L.modulus_pa * (T(1.0) - th * th) + L.hardening_pa;
  if (!(val(e) > 0.0)) return;
  const T& ed = L.densification_strain;
  const T& n = L.densification_exponent;
  const T ec = T(0.97) * ed;
  const bool beyond = val(e) > val(ec);
  const T x = beyond ? ec : e;
  const T r = x / (ed - x);
  const T rn = power(r, n);
  const T slope = L.densification_pa * n * rn / r * ed / ((ed - x) * (ed - x));
  *s += L.densification_pa * rn + (beyond ? slope * (e - ec) : T(0.0));
  *ds += slope;
}

inline void require(bool ok, const char* what) {
  if (!ok) throw Error(what);
}

inline void check(const Model6Geometry& g, const Impact& imp) {
  require(g.area_m2 > 0.0 && g.top_thickness_m > 0.0 && g.base_thickness_m >= 0.0,
          "model6: the column needs a positive area and top thickness");
  require(g.n_top >= 1 && (g.n_base >= 1 || g.base_thickness_m == 0.0), "model6: each layer needs an element");
  require(g.max_step_s > 0.0, "model6: max_step_s must be positive");
  require(imp.output_dt_s > 0.0 && imp.duration_s > 0.0 && imp.mass_kg > 0.0,
          "model6: the impact needs a positive mass, output step and duration");
  require(imp.first_output_s >= 0.0 && imp.first_output_s < imp.output_dt_s,
          "model6: first_output_s must lie in [0, output_dt_s)");
}

template <typename T>
bool law_ok(const FoamLawT<T>& l) {
  return val(l.plateau_pa) > 0.0 && val(l.modulus_pa) > 0.0 && val(l.hardening_pa) >= 0.0 &&
         val(l.densification_pa) >= 0.0 && val(l.densification_strain) > 0.0 && val(l.densification_strain) <= 1.0 &&
         val(l.densification_exponent) >= 1.0;
}

template <typename T>
void check(const Model6ParamsT<T>& p) {
  const bool ok = law_ok(p.top) && law_ok(p.base) && val(p.prony_g1) >= 0.0 && val(p.prony_g2) >= 0.0 &&
                  val(p.prony_tau1_s) > 0.0 && val(p.prony_tau2_s) > 0.0 && val(p.viscosity_pa_s) >= 0.0 &&
                  val(p.top_mass_kg) > 0.0 && val(p.base_mass_kg) >= 0.0;
  require(ok, "model6: a foam law needs positive moduli, plateau and masses, e_d in (0, 1], n >= 1, g >= 0, tau > 0");
}

// A step's start state in scalar S (the column's own, or its values in
// doubles): what the stresses and the Newton iteration read.
template <typename S>
struct StepView {
  int n = 0;
  double area = 0.0;
  const FoamLawT<S>* law = nullptr;
  const double* h = nullptr;
  const S *mass = nullptr, *es = nullptr, *ss = nullptr;  // node masses; static strain and stress
  const S *u = nullptr, *v = nullptr, *a = nullptr, *q1 = nullptr, *q2 = nullptr, *se = nullptr;
  S m0, eta, e1, e2, b1, b2;  // node 0's moving mass; viscosity; the Prony recursion's coefficients
  S top_load;                 // the impactor's weight on node 0 while in contact (0 otherwise)
  bool driven = false;        // node 0's travel is prescribed (co-simulation): its equation is u_0 = given
  S top_velocity;             // and its velocity at the step's end
};

// The step's work arrays: node travels un and velocities vn at the step's
// end, element stresses (elastic sen with its tangent dsn in strain, total
// sign, the total's tangent kn x A / h), the Newton system (res: the last
// iteration's correction once solved).
template <typename S>
struct StepWork {
  std::vector<S> un, vn, sen, dsn, sign, kn, res, diag, off;
  void resize(int n) {
    for (auto* x : {&un, &vn, &sen, &dsn, &sign, &kn, &res, &diag, &off}) x->assign(n, S(0.0));
  }
};

// Stresses of every element at the step's end (w.un, w.vn): elastic, total
// (the Prony terms advanced over dt) and the tangent of the total stress in
// the element's strain times A / h.
template <typename S>
void step_stresses(const StepView<S>& c, double dt, StepWork<S>& w) {
  for (int j = 0; j < c.n; ++j) {
    const S ub = j + 1 < c.n ? w.un[j + 1] : S(0.0), vb = j + 1 < c.n ? w.vn[j + 1] : S(0.0);
    const S e = c.es[j] + (w.un[j] - ub) / c.h[j];
    const S edot = (w.vn[j] - vb) / c.h[j];
    S s, ds;
    elastic(c.law[j], e, &s, &ds);
    w.sen[j] = s;
    w.dsn[j] = ds;
    const S dse = s - c.se[j];
    w.sign[j] = s + c.e1 * c.q1[j] + c.b1 * dse + c.e2 * c.q2[j] + c.b2 * dse + c.eta * edot;
    w.kn[j] = S(c.area) * (ds * (S(1.0) + c.b1 + c.b2) + c.eta * S(2.0 / dt)) / c.h[j];
  }
}

// One Newton iteration on the trapezoidal step's equations of motion at
// the node travels w.un (updated in place; Thomas algorithm on the
// symmetric tridiagonal Jacobian). Returns whether w.un already met the
// relative residual 1e-10 (scale: the largest force term seen).
template <typename S>
bool newton_iteration(const StepView<S>& c, double dt, StepWork<S>& w, double& scale) {
  const double c4 = 4.0 / (dt * dt), c2 = 2.0 / dt;
  const S A(c.area);
  const int n = c.n;
  for (int j = 0; j < n; ++j) w.vn[j] = S(c2) * (w.un[j] - c.u[j]) - c.v[j];
  if (c.driven) w.vn[0] = c.top_velocity;
  step_stresses(c, dt, w);
  double rmax = 0.0;
  for (int j = 0; j < n; ++j) {
    if (j == 0 && c.driven) {  // no correction to a prescribed travel
      w.res[0] = S(0.0), w.diag[0] = S(1.0), w.off[0] = S(0.0);
      continue;
    }
    const S mj = j == 0 ? c.m0 : c.mass[j];
    const S acc = S(c4) * (w.un[j] - c.u[j] - S(dt) * c.v[j]) - c.a[j];
    S f = -A * (w.sign[j] - c.ss[j]);
    if (j > 0) f += A * (w.sign[j - 1] - c.ss[j - 1]);
    if (j == 0) f += c.top_load;
    w.res[j] = mj * acc - f;
    w.diag[j] = mj * S(c4) + w.kn[j] + (j > 0 ? w.kn[j - 1] : S(0.0));
    w.off[j] = -w.kn[j];  // between j and j + 1
    rmax = std::max(rmax, std::abs(val(w.res[j])));
    scale = std::max(scale, std::abs(val(mj * acc)) + std::abs(val(f)));
  }
  const bool converged = rmax <= 1e-10 * std::max(scale, 1e-6);
  for (int j = 1; j < n; ++j) {
    const S q = w.off[j - 1] / w.diag[j - 1];
    w.diag[j] -= q * w.off[j - 1];
    w.res[j] -= q * w.res[j - 1];
  }
  w.res[n - 1] /= w.diag[n - 1];
  for (int j = n - 2; j >= 0; --j) w.res[j] = (w.res[j] - w.off[j] * w.res[j + 1]) / w.diag[j];
  for (int j = 0; j < n; ++j) w.un[j] -= w.res[j];
  return converged;
}

// The column's state and the implicit step.
template <typename T>
class Column {
 public:
  Column(const Model6ParamsT<T>& p, const Model6Geometry& g, const Impact& imp) : imp_(imp), area_(g.area_m2) {
    build(p, g);
    // The plastic collision of the impactor with node 0.
    const T M(imp.mass_kg);
    v_[0] = M * T(imp.velocity_m_s) / (M + mass_[0]);
    a_[0] = M * T(imp.gravity_m_s2) / (M + mass_[0]);
    contact_ = true;
  }
  // The column at rest with no impactor (co-simulation, model6_cosim.h):
  // node 0 is driven by drive() or free.
  Column(const Model6ParamsT<T>& p, const Model6Geometry& g, double gravity_m_s2) : area_(g.area_m2) {
    imp_.mass_kg = 0.0;
    imp_.velocity_m_s = 0.0;
    imp_.gravity_m_s2 = gravity_m_s2;
    build(p, g);
    contact_ = false;
  }

  int nodes() const { return n_; }
  int interface_node() const { return n_top_; }
  bool contact() const { return contact_; }
  const T& u(int j) const { return u_[j]; }
  const T& v(int j) const { return v_[j]; }
  const T& node_mass(int j) const { return mass_[j]; }
  T impactor() const { return contact_ ? u_[0] : z_; }
  T plate_force() const { return area_ * (sigma_[n_ - 1] - ss_[n_ - 1]); }
  T strain(int j) const { return es_[j] + (u_[j] - (j + 1 < n_ ? u_[j + 1] : T(0.0))) / h_[j]; }

  // One trapezoidal step of length dt; returns false on a contact change (at its end).
  bool step(double dt);
  // Co-simulation: one step with node 0 driven to `top_travel` at its end
  // with velocity `top_velocity` (null: node 0 free, as the column with
  // nothing on it). Returns the force the driver exerts on node 0
  // (downwards), m_0 a_0 + A (s_0 - s_0,static): the mat's push on whatever
  // drives it. A driven node's velocity is the driver's and its acceleration
  // the velocity's change over the step (the trapezoidal rule's own, from a
  // prescribed travel, rings from step to step).
  T drive(double dt, const double* top_travel, double top_velocity = 0.0);
  // Node 0 takes the velocity v (a plastic landing on it).
  void set_top_velocity(const T& v) { v_[0] = v; }

 private:
  void build(const Model6ParamsT<T>& p, const Model6Geometry& g) {
    const int nt = g.n_top, nb = g.base_thickness_m > 0.0 ? g.n_base : 0;
    n_ = nt + nb;
    n_top_ = nt;
    law_.resize(n_);
    h_.resize(n_);
    for (int j = 0; j < n_; ++j) {
      law_[j] = j < nt ? p.top : p.base;
      h_[j] = j < nt ? g.top_thickness_m / nt : g.base_thickness_m / nb;
    }
    // Node masses: each element's half on each of its nodes (node n_ on the plate).
    mass_.assign(n_, T(0.0));
    for (int j = 0; j < n_; ++j) {
      const T me = j < nt ? p.top_mass_kg / double(nt) : p.base_mass_kg / double(nb);
      mass_[j] += T(0.5) * me;
      if (j + 1 < n_) mass_[j + 1] += T(0.5) * me;
    }
    g1_ = p.prony_g1, g2_ = p.prony_g2, tau1_ = p.prony_tau1_s, tau2_ = p.prony_tau2_s, eta_ = p.viscosity_pa_s;
    static_state();
    u_.assign(n_, T(0.0));
    v_.assign(n_, T(0.0));
    a_.assign(n_, T(0.0));
    q1_.assign(n_, T(0.0));
    q2_.assign(n_, T(0.0));
  }
  void newton(double dt);            // the step's node travels w_.un (from their start there)
  void finish_step(double dt);       // the state at the step's end from w_.un
  bool advance_contact(double dt);   // the contact's change; false when it changed
  void static_state();
  // The Prony recursion's coefficients over a step dt (kept for the last dt):
  // q_i <- e_i q_i + b_i (change of the elastic stress).
  void prony(double dt) const {
    if (dt == prony_dt_) return;
    using std::exp;
    e1_ = exp(-T(dt) / tau1_), e2_ = exp(-T(dt) / tau2_);
    b1_ = g1_ * (T(1.0) - e1_) * tau1_ / T(dt), b2_ = g2_ * (T(1.0) - e2_) * tau2_ / T(dt);
    prony_dt_ = dt;
  }
  StepView<T> view() const;
  void linearised_stresses();        // finish_step's stresses after a single correcting iteration

  Impact imp_;
  double area_;
  int n_ = 0, n_top_ = 0;
  std::vector<FoamLawT<T>> law_;
  std::vector<double> h_;
  std::vector<T> mass_, es_, ss_;   // node masses; static strain and stress per element
  std::vector<T> u_, v_, a_, q1_, q2_, se_, sigma_;
  T g1_, g2_, tau1_, tau2_, eta_;
  bool contact_ = true;
  T z_ = T(0.0), vz_ = T(0.0);  // the impactor in flight
  bool driven_ = false;         // within drive() with node 0 prescribed
  T top_velocity_ = T(0.0);     // its velocity at the step's end
  // Work arrays (no allocation in the time loop).
  StepWork<T> w_;
  mutable double prony_dt_ = -1.0;
  mutable T e1_, e2_, b1_, b2_;
  // The step's last Newton iteration started converged (in doubles; for a
  // Jet, the one in T after the doubles converged): its correction is at
  // the round-off level in value (for a Jet, the derivatives' whole
  // change), so the step's end stresses follow from the iteration's own by
  // their tangent instead of a second pass through the foam law.
  bool linearised_ = false;
  // For a Jet column, the step solved first in doubles (the values), then
  // one Newton iteration in T carries the derivatives: at the converged
  // values the residual is zero, so that iteration's change of the
  // derivatives is the implicit function's, -J^-1 dres/dparameters. A step
  // the doubles do not converge runs its iterations in T.
  std::vector<FoamLawT<double>> law_d_;
  std::vector<double> mass_d_, es_d_, ss_d_, u_d_, v_d_, a_d_, q1_d_, q2_d_, se_d_;
  StepWork<double> w_d_;
};

template <typename T>
void Column<T>::static_state() {
  // Element j carries the weight of the nodes above its bottom: nodes 0..j.
  es_.assign(n_, T(0.0));
  ss_.assign(n_, T(0.0));
  se_.assign(n_, T(0.0));
  sigma_.assign(n_, T(0.0));
  T load(0.0);
  for (int j = 0; j < n_; ++j) {
    load += mass_[j] * T(imp_.gravity_m_s2);
    const T target = load / T(area_);
    // Bisection in doubles (the law is increasing), then Newton in T for the derivatives.
    double lo = 0.0, hi = 0.97 * val(law_[j].densification_strain);
    T s, ds;
    for (int it = 0; it < 60; ++it) {
      const double mid = 0.5 * (lo + hi);
      elastic(law_[j], T(mid), &s, &ds);
      (val(s) < val(target) ? lo : hi) = mid;
    }
    T e(0.5 * (lo + hi));
    for (int it = 0; it < 2; ++it) {
      elastic(law_[j], e, &s, &ds);
      e -= (s - target) / ds;
    }
    es_[j] = e;
    elastic(law_[j], e, &s, &ds);
    ss_[j] = s;
    se_[j] = s;
    sigma_[j] = s;
  }
  w_.resize(n_);
  if constexpr (!std::is_same_v<T, double>) {
    law_d_.resize(n_);
    for (int j = 0; j < n_; ++j) {
      const FoamLawT<T>& l = law_[j];
      law_d_[j] = {val(l.plateau_pa),       val(l.modulus_pa),           val(l.hardening_pa),
                   val(l.densification_pa), val(l.densification_strain), val(l.densification_exponent)};
    }
    mass_d_.resize(n_), es_d_.resize(n_), ss_d_.resize(n_);
    for (int j = 0; j < n_; ++j) mass_d_[j] = val(mass_[j]), es_d_[j] = val(es_[j]), ss_d_[j] = val(ss_[j]);
    for (auto* x : {&u_d_, &v_d_, &a_d_, &q1_d_, &q2_d_, &se_d_}) x->assign(n_, 0.0);
    w_d_.resize(n_);
  }
}

template <typename T>
StepView<T> Column<T>::view() const {
  StepView<T> c;
  c.n = n_;
  c.area = area_;
  c.law = law_.data();
  c.h = h_.data();
  c.mass = mass_.data(), c.es = es_.data(), c.ss = ss_.data();
  c.u = u_.data(), c.v = v_.data(), c.a = a_.data(), c.q1 = q1_.data(), c.q2 = q2_.data(), c.se = se_.data();
  const T M(imp_.mass_kg);
  c.m0 = contact_ ? mass_[0] + M : mass_[0];
  c.top_load = contact_ ? M * T(imp_.gravity_m_s2) : T(0.0);
  c.eta = eta_, c.e1 = e1_, c.e2 = e2_, c.b1 = b1_, c.b2 = b2_;
  c.driven = driven_;
  c.top_velocity = top_velocity_;
  return c;
}

template <typename T>
T Column<T>::drive(double dt, const double* top_travel, double top_velocity) {
  for (int j = 0; j < n_; ++j) w_.un[j] = u_[j] + T(dt) * v_[j] + T(0.25 * dt * dt) * a_[j];
  driven_ = top_travel != nullptr;
  const T v_before = v_[0];
  if (driven_) w_.un[0] = T(*top_travel), top_velocity_ = T(top_velocity);
  newton(dt);
  finish_step(dt);
  if (driven_) a_[0] = (v_[0] - v_before) / T(dt);
  driven_ = false;
  return mass_[0] * a_[0] + T(area_) * (sigma_[0] - ss_[0]);
}

template <typename T>
bool Column<T>::step(double dt) {
  // Newton on the node travels at the step's end; start: constant acceleration.
  for (int j = 0; j < n_; ++j) w_.un[j] = u_[j] + T(dt) * v_[j] + T(0.25 * dt * dt) * a_[j];
  newton(dt);
  finish_step(dt);
  return advance_contact(dt);
}

template <typename T>
void Column<T>::newton(double dt) {
  prony(dt);
  const StepView<T> c = view();
  double scale = 0.0;
  if constexpr (std::is_same_v<T, double>) {
    for (int it = 0; it < 30 && !linearised_; ++it) linearised_ = newton_iteration(c, dt, w_, scale);
  } else {
    StepView<double> d;
    d.n = n_, d.area = area_, d.law = law_d_.data(), d.h = h_.data();
    d.mass = mass_d_.data(), d.es = es_d_.data(), d.ss = ss_d_.data();
    for (int j = 0; j < n_; ++j) {
      u_d_[j] = val(u_[j]), v_d_[j] = val(v_[j]), a_d_[j] = val(a_[j]);
      q1_d_[j] = val(q1_[j]), q2_d_[j] = val(q2_[j]), se_d_[j] = val(se_[j]);
      w_d_.un[j] = val(w_.un[j]);
    }
    d.u = u_d_.data(), d.v = v_d_.data(), d.a = a_d_.data(), d.q1 = q1_d_.data(), d.q2 = q2_d_.data();
    d.se = se_d_.data();
    d.m0 = val(c.m0), d.top_load = val(c.top_load);
    d.eta = val(eta_), d.e1 = val(e1_), d.e2 = val(e2_), d.b1 = val(b1_), d.b2 = val(b2_);
    d.driven = c.driven;
    d.top_velocity = val(c.top_velocity);
    bool converged = false;
    for (int it = 0; it < 30 && !converged; ++it) converged = newton_iteration(d, dt, w_d_, scale);
    if (converged) {
      for (int j = 0; j < n_; ++j) w_.un[j] = T(w_d_.un[j]);
      newton_iteration(c, dt, w_, scale);
      linearised_ = true;
      return;
    }
    // Not converged in doubles: the values are those of the last iterate
    // (as in the doubles' simulation), and so must the derivatives be, so
    // the iterations run again in T.
    scale = 0.0;
    for (int it = 0; it < 30; ++it)
      if (newton_iteration(c, dt, w_, scale)) break;
  }
}

// The element strains move by de = (du_j - du_{j+1}) / h_j with the
// correction du = -res, their rates by de x 2 / dt (the trapezoidal rule),
// so the elastic stress by ds x de and the total by kn x h / A x de; the
// second-order remainder is of the correction's value squared.
template <typename T>
void Column<T>::linearised_stresses() {
  for (int j = 0; j < n_; ++j) {
    const T de = ((j + 1 < n_ ? w_.res[j + 1] : T(0.0)) - w_.res[j]) / h_[j];
    w_.sen[j] += w_.dsn[j] * de;
    w_.sign[j] += w_.kn[j] * (h_[j] / area_) * de;
  }
}

template <typename T>
void Column<T>::finish_step(double dt) {
  const double c4 = 4.0 / (dt * dt), c2 = 2.0 / dt;
  for (int j = 0; j < n_; ++j) w_.vn[j] = T(c2) * (w_.un[j] - u_[j]) - v_[j];
  if (driven_) w_.vn[0] = top_velocity_;
  if (linearised_) {
    linearised_stresses();
    linearised_ = false;
  } else {
    step_stresses(view(), dt, w_);
  }
  for (int j = 0; j < n_; ++j) {
    q1_[j] = e1_ * q1_[j] + b1_ * (w_.sen[j] - se_[j]);
    q2_[j] = e2_ * q2_[j] + b2_ * (w_.sen[j] - se_[j]);
  }
  for (int j = 0; j < n_; ++j) {
    a_[j] = T(c4) * (w_.un[j] - u_[j] - T(dt) * v_[j]) - a_[j];
    u_[j] = w_.un[j];
    v_[j] = w_.vn[j];
    se_[j] = w_.sen[j];
    sigma_[j] = w_.sign[j];
  }
}

template <typename T>
bool Column<T>::advance_contact(double dt) {
  const T M(imp_.mass_kg), g(imp_.gravity_m_s2), A(area_);
  const T f0 = -A * (sigma_[0] - ss_[0]);  // element 0's force on node 0 (downwards)
  if (contact_) {
    // The contact force on the impactor, upwards: M (g - a_0). It cannot pull.
    if (val(M * (g - a_[0])) < 0.0) {
      contact_ = false;
      z_ = u_[0];
      vz_ = v_[0];
      a_[0] = f0 / mass_[0];
      return false;
    }
  } else {
    z_ += T(dt) * vz_ + T(0.5 * dt * dt) * g;
    vz_ += T(dt) * g;
    if (val(z_) >= val(u_[0])) {  // lands again: a plastic collision with node 0
      v_[0] = (M * vz_ + mass_[0] * v_[0]) / (M + mass_[0]);
      a_[0] = (M * g + f0) / (M + mass_[0]);
      contact_ = true;
      return false;
    }
  }
  return true;
}

}  // namespace model6_detail

// Samples at impact.first_output_s + i * output_dt_s, i < n_samples: the
// plate force and the face's travel (and, when `extras`, the rest; doubles).
template <typename T>
void simulate_model6_t(const Model6ParamsT<T>& params, const Model6Geometry& geometry, const Impact& impact,
                       int n_samples, std::vector<T>* grf, std::vector<T>* impactor, Model6Extras* extras = nullptr) {
  using model6_detail::val;
  model6_detail::check(geometry, impact);
  model6_detail::check(params);
  model6_detail::Column<T> col(params, geometry, impact);
  const int sub = std::max(1, static_cast<int>(std::ceil(impact.output_dt_s / geometry.max_step_s - 1e-9)));
  const double dt = impact.output_dt_s / sub;
  if (grf) grf->assign(n_samples, T(0.0));
  if (impactor) impactor->assign(n_samples, T(0.0));
  if (extras) {
    *extras = Model6Extras{};
    extras->step_s = dt;
    for (auto* v : {&extras->surface_m, &extras->interface_m, &extras->top_strain, &extras->base_strain})
      v->assign(n_samples, 0.0);
  }
  double t = 0.0;
  long steps = 0;
  auto advance = [&](double to, double h_max) {
    const int n = std::max(1, static_cast<int>(std::ceil((to - t) / h_max - 1e-9)));
    const double h = (to - t) / n;
    for (int k = 0; k < n; ++k) {
      const bool was = col.contact();
      col.step(h);
      ++steps;
      if (extras && was && !col.contact() && !std::isfinite(extras->separation_s)) extras->separation_s = t + (k + 1) * h;
    }
    t = to;
  };
  for (int i = 0; i < n_samples; ++i) {
    const double ti = impact.first_output_s + i * impact.output_dt_s;
    if (ti > t) advance(ti, dt);
    if (grf) (*grf)[i] = col.plate_force();
    if (impactor) (*impactor)[i] = col.impactor();
    if (extras) {
      extras->surface_m[i] = val(col.u(0));
      extras->interface_m[i] = col.interface_node() < col.nodes() ? val(col.u(col.interface_node())) : 0.0;
      extras->top_strain[i] = val(col.strain(0));
      extras->base_strain[i] = val(col.strain(col.nodes() - 1));
    }
  }
  if (extras) extras->steps = steps;
}

}  // namespace dropfit::fitting
