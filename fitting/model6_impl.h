#pragma once
// Model 6 (fitting/model6.h) templated on the scalar type, so that
// ceres::Jet flows through it: the fitter's exact derivatives. For a Jet
// every branch (contact, Newton's stopping, the densification's tangent
// continuation) follows the scalar parts, so the derivative is that of the
// discrete solution with those decisions held.
#include <ceres/jet.h>

#include <algorithm>
#include <cmath>
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

// The column's state and the implicit step.
template <typename T>
class Column {
 public:
  Column(const Model6ParamsT<T>& p, const Model6Geometry& g, const Impact& imp)
      : imp_(imp), area_(g.area_m2) {
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
    // The plastic collision of the impactor with node 0.
    const T M(imp.mass_kg);
    v_[0] = M * T(imp.velocity_m_s) / (M + mass_[0]);
    a_[0] = M * T(imp.gravity_m_s2) / (M + mass_[0]);
    contact_ = true;
  }

  int nodes() const { return n_; }
  int interface_node() const { return n_top_; }
  bool contact() const { return contact_; }
  const T& u(int j) const { return u_[j]; }
  T impactor() const { return contact_ ? u_[0] : z_; }
  T plate_force() const { return area_ * (sigma_[n_ - 1] - ss_[n_ - 1]); }
  T strain(int j) const { return es_[j] + (u_[j] - (j + 1 < n_ ? u_[j + 1] : T(0.0))) / h_[j]; }

  // One trapezoidal step of length dt; returns false on a contact change (at its end).
  bool step(double dt);

 private:
  void newton(double dt);            // the step's node travels un_ (from their start in un_)
  void finish_step(double dt);       // the state at the step's end from un_
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
  void element_stresses(const std::vector<T>& u, const std::vector<T>& vel, double dt, std::vector<T>* se,
                        std::vector<T>* sigma, std::vector<T>* stiff) const;

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
  // Work arrays (no allocation in the time loop).
  mutable std::vector<T> un_, vn_, sen_, sign_, kn_, res_, diag_, off_;
  mutable double prony_dt_ = -1.0;
  mutable T e1_, e2_, b1_, b2_;
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
  un_.assign(n_, T(0.0));
  vn_ = sen_ = sign_ = kn_ = res_ = diag_ = off_ = un_;
}

// Stresses of every element at node travels u and velocities vel: elastic
// se, total sigma (with the Prony terms advanced over dt), tangent of sigma
// in the element's strain times A / h (stiff).
template <typename T>
void Column<T>::element_stresses(const std::vector<T>& u, const std::vector<T>& vel, double dt, std::vector<T>* se,
                                 std::vector<T>* sigma, std::vector<T>* stiff) const {
  prony(dt);
  const T &e1 = e1_, &e2 = e2_, &b1 = b1_, &b2 = b2_;
  for (int j = 0; j < n_; ++j) {
    const T ub = j + 1 < n_ ? u[j + 1] : T(0.0), vb = j + 1 < n_ ? vel[j + 1] : T(0.0);
    const T e = es_[j] + (u[j] - ub) / h_[j];
    const T edot = (vel[j] - vb) / h_[j];
    T s, ds;
    elastic(law_[j], e, &s, &ds);
    (*se)[j] = s;
    const T dse = s - se_[j];
    (*sigma)[j] = s + e1 * q1_[j] + b1 * dse + e2 * q2_[j] + b2 * dse + eta_ * edot;
    (*stiff)[j] = T(area_) * (ds * (T(1.0) + b1 + b2) + eta_ * T(2.0 / dt)) / h_[j];
  }
}

template <typename T>
bool Column<T>::step(double dt) {
  // Newton on the node travels at the step's end; start: constant acceleration.
  for (int j = 0; j < n_; ++j) un_[j] = u_[j] + T(dt) * v_[j] + T(0.25 * dt * dt) * a_[j];
  newton(dt);
  finish_step(dt);
  return advance_contact(dt);
}

template <typename T>
void Column<T>::newton(double dt) {
  const T M(imp_.mass_kg), g(imp_.gravity_m_s2), A(area_);
  const T m0 = contact_ ? mass_[0] + M : mass_[0];
  const double c4 = 4.0 / (dt * dt), c2 = 2.0 / dt;
  double scale = 0.0;
  for (int it = 0; it < 30; ++it) {
    for (int j = 0; j < n_; ++j) vn_[j] = T(c2) * (un_[j] - u_[j]) - v_[j];
    element_stresses(un_, vn_, dt, &sen_, &sign_, &kn_);
    double rmax = 0.0;
    for (int j = 0; j < n_; ++j) {
      const T mj = j == 0 ? m0 : mass_[j];
      const T acc = T(c4) * (un_[j] - u_[j] - T(dt) * v_[j]) - a_[j];
      T f = -A * (sign_[j] - ss_[j]);
      if (j > 0) f += A * (sign_[j - 1] - ss_[j - 1]);
      if (j == 0 && contact_) f += M * g;
      res_[j] = mj * acc - f;
      diag_[j] = mj * T(c4) + kn_[j] + (j > 0 ? kn_[j - 1] : T(0.0));
      off_[j] = -kn_[j];  // between j and j + 1
      rmax = std::max(rmax, std::abs(val(res_[j])));
      scale = std::max(scale, std::abs(val(mj * acc)) + std::abs(val(f)));
    }
    const bool converged = rmax <= 1e-10 * std::max(scale, 1e-6);
    // Thomas algorithm on diag / off (symmetric tridiagonal): J du = -res.
    for (int j = 1; j < n_; ++j) {
      const T w = off_[j - 1] / diag_[j - 1];
      diag_[j] -= w * off_[j - 1];
      res_[j] -= w * res_[j - 1];
    }
    res_[n_ - 1] /= diag_[n_ - 1];
    for (int j = n_ - 2; j >= 0; --j) res_[j] = (res_[j] - off_[j] * res_[j + 1]) / diag_[j];
    for (int j = 0; j < n_; ++j) un_[j] -= res_[j];
    if (converged) break;  // one step more than needed: the derivatives converge with it
  }
}

template <typename T>
void Column<T>::finish_step(double dt) {
  const double c4 = 4.0 / (dt * dt), c2 = 2.0 / dt;
  for (int j = 0; j < n_; ++j) vn_[j] = T(c2) * (un_[j] - u_[j]) - v_[j];
  element_stresses(un_, vn_, dt, &sen_, &sign_, &kn_);
  for (int j = 0; j < n_; ++j) {
    q1_[j] = e1_ * q1_[j] + b1_ * (sen_[j] - se_[j]);
    q2_[j] = e2_ * q2_[j] + b2_ * (sen_[j] - se_[j]);
  }
  for (int j = 0; j < n_; ++j) {
    a_[j] = T(c4) * (un_[j] - u_[j] - T(dt) * v_[j]) - a_[j];
    u_[j] = un_[j];
    v_[j] = vn_[j];
    se_[j] = sen_[j];
    sigma_[j] = sign_[j];
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
