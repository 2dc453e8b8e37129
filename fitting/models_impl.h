#pragma once
// Internal to fitting/: the equations of Models 1-4 templated on the scalar
// type, so that ceres::Jet flows through for automatic differentiation.
// The physics is documented in fitting/models.h and fitting/models.cpp.
//
// Layout of the state (both integrators), positions downward from first
// contact (m), velocities downward (m/s):
//   0 y0  impactor        1 v0
//   2 y1  mat mass 1      3 v1      (Model 2: m_eff; Models 3, 4: m1)
//   4 y2  mat mass 2      5 v2      (Models 3, 4: m2)
//   6 e   compression of the free (massless) element 1 after separation,
//         Models 1 and 4: the surface sits at y_base + e
//   7     Exact integrator: the constant 1 (carries gravity);
//         RK4: the Maxwell arm's force Fm (N)
// Elements: "massless top" models (1, 4) have element 1 between the
// impactor and its base (ground in Model 1, m1 in Model 4); "rigid top"
// models (2, 3) carry the impactor on m1 while in contact and element 1
// joins m1 to the ground (Model 2) or to m2 (Model 3).
#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <vector>

#include "fitting/models.h"

namespace dropfit::fitting::detail {

inline double scalar_of(double x) { return x; }
template <typename J>
double scalar_of(const J& x) {
  return x.a;
}

template <typename T>
struct ParamsT {
  T k[3], r[3];   // elements 1..3
  T m1, m2;       // mat masses under the layout above (Model 2: m1 = m_eff)
  T k1_cubic, r1_unload, maxwell_k, maxwell_tau, unload_ratio;
  double unload_speed = 0.05;
  bool cubic = false, hysteresis = false, maxwell = false, asymmetric = false;
};

// Which nodes each element joins: upper node index (0 impactor, 1 m1,
// 2 m2) and lower node (-1 = ground).
struct Layout {
  bool rigid_top = false;  // impactor rides on m1 (Models 2, 3)
  int n_mass = 0;          // mat masses 0..2
  int n_elem = 1;
  int upper[3] = {0, 0, 0};
  int lower[3] = {-1, -1, -1};
  int base() const { return lower[0]; }  // massless top: node under element 1
};

inline Layout layout_for(ModelKind kind, bool m_eff_zero) {
  Layout L;
  switch (kind) {
    case ModelKind::Model1:
      L.rigid_top = false; L.n_mass = 0; L.n_elem = 1;
      L.upper[0] = 0; L.lower[0] = -1;
      break;
    case ModelKind::Model2:
      if (m_eff_zero) return layout_for(ModelKind::Model1, false);
      L.rigid_top = true; L.n_mass = 1; L.n_elem = 1;
      L.upper[0] = 1; L.lower[0] = -1;
      break;
    case ModelKind::Model3:
      L.rigid_top = true; L.n_mass = 2; L.n_elem = 2;
      L.upper[0] = 1; L.lower[0] = 2;
      L.upper[1] = 2; L.lower[1] = -1;
      break;
    default:  // Model4
      L.rigid_top = false; L.n_mass = 2; L.n_elem = 3;
      L.upper[0] = 0; L.lower[0] = 1;
      L.upper[1] = 1; L.lower[1] = 2;
      L.upper[2] = 2; L.lower[2] = -1;
      break;
  }
  return L;
}

template <typename T>
struct Trace {
  std::vector<T> grf, impactor, surface, layer1, layer2;
  T separation_s = T(0);
  bool separated = false;
};

template <typename T>
T mass_of(const ParamsT<T>& p, int node, const T& M) {
  return node == 0 ? M : (node == 1 ? p.m1 : p.m2);
}

// ---------------------------------------------------------------------------
// Matrix exponential by scaling and squaring with a degree-16 Taylor
// polynomial evaluated Paterson-Stockmeyer style (7 products); the scaling
// is chosen from the scalar parts so Jets keep one structure.
template <typename T, int N>
double inf_norm(const Eigen::Matrix<T, N, N>& B) {
  double norm = 0.0;
  for (int i = 0; i < N; ++i) {
    double row = 0.0;
    for (int j = 0; j < N; ++j) row += std::abs(scalar_of(B(i, j)));
    norm = std::max(norm, row);
  }
  return norm;
}

template <typename T, int N>
Eigen::Matrix<T, N, N> expm(const Eigen::Matrix<T, N, N>& B) {
  using Mat = Eigen::Matrix<T, N, N>;
  const double norm = inf_norm<T, N>(B);
  int s = 0;
  if (norm > 1.0) s = static_cast<int>(std::ceil(std::log2(norm)));
  // ||X|| <= 1: the remainder after degree 16 is below 3e-15.
  const Mat X = B * T(std::ldexp(1.0, -s));
  const Mat X2 = X.lazyProduct(X), X3 = X2.lazyProduct(X), X4 = X2.lazyProduct(X2);
  double c[17];
  c[0] = 1.0;
  for (int k = 1; k <= 16; ++k) c[k] = c[k - 1] / k;
  auto block = [&](int j) {  // c[4j] I + c[4j+1] X + c[4j+2] X^2 + c[4j+3] X^3
    Mat P = X * T(c[4 * j + 1]) + X2 * T(c[4 * j + 2]) + X3 * T(c[4 * j + 3]);
    P.diagonal().array() += T(c[4 * j]);
    return P;
  };
  Mat E = X4 * T(c[16]) + block(3);
  E = Mat(E.lazyProduct(X4)) + block(2);
  E = Mat(E.lazyProduct(X4)) + block(1);
  E = Mat(E.lazyProduct(X4)) + block(0);
  for (int i = 0; i < s; ++i) E = Mat(E.lazyProduct(E));
  return E;
}

// exp(B s) Z without forming the matrix: Taylor series on the vector in
// sub-steps of norm at most 1/2 (degree 14: remainder below 1e-16).
template <typename T, int N>
Eigen::Matrix<T, N, 1> expmv(const Eigen::Matrix<T, N, N>& B, double norm_B, const T& s,
                             const Eigen::Matrix<T, N, 1>& Z) {
  const double sv = std::max(scalar_of(s), 0.0);
  const int m = std::max(1, static_cast<int>(std::ceil(norm_B * sv / 0.5)));
  const T sub = s / T(static_cast<double>(m));
  Eigen::Matrix<T, N, 1> x = Z;
  for (int p = 0; p < m; ++p) {
    Eigen::Matrix<T, N, 1> term = x, sum = x;
    for (int k = 1; k <= 14; ++k) {
      term = Eigen::Matrix<T, N, 1>(B.lazyProduct(term)) * (sub / T(static_cast<double>(k)));
      sum += term;
    }
    x = sum;
  }
  return x;
}

// ---------------------------------------------------------------------------
// Exact discrete form for the linear models.
//
// Per phase (contact / free) the state obeys X' = A X (X[7] = 1 carries
// gravity). Velocities are scaled by the output step h (w = v h) so that
// B = h S A S^-1 has entries of order one and the exponential needs few
// squarings. Events: contact -> free when the contact force g = c.X turns
// negative, free -> contact when the gap impactor - surface turns positive;
// each is located inside the step by a cubic Hermite guess refined by one
// Newton step on the exact trajectory exp(B s) Z.
template <typename T>
class ExactIntegrator {
 public:
  using Vec = Eigen::Matrix<T, 8, 1>;
  using Mat = Eigen::Matrix<T, 8, 8>;

  ExactIntegrator(const Layout& L, const ParamsT<T>& p, const Impact& imp)
      : L_(L), p_(p), M_(imp.mass_kg), g_(imp.gravity_m_s2), h_out_(imp.output_dt_s) {
    // Internal steps per output step: enough that the scaled dynamics have
    // norm <= 3 (at most about half an oscillation per step), so that the
    // event search below sees at most one sign change.
    for (sub_ = 1;; sub_ *= 2) {
      h_ = h_out_ / sub_;
      for (int i = 0; i < 8; ++i) scale_[i] = (i % 2 == 1 && i < 6) ? h_ : 1.0;
      double dyn = 0.0;
      for (int ph = 0; ph < 2; ++ph) {
        B_[ph] = build(ph == 0);
        Mat D = B_[ph];
        D.row(6).setZero();  // the free element's relaxation is exact at any rate
        dyn = std::max(dyn, inf_norm<T, 8>(D));
      }
      if (dyn <= 3.0 || sub_ >= 4096) break;
    }
    for (int ph = 0; ph < 2; ++ph) {
      normB_[ph] = inf_norm<T, 8>(B_[ph]);
      c_[ph] = event_row(ph == 0);
    }
    Phi_[0] = expm<T, 8>(B_[0]);  // the free phase's on first use
  }

  // Element j's force as a row over the (unscaled) state.
  Eigen::Matrix<T, 1, 8> element_row(int j) const {
    Eigen::Matrix<T, 1, 8> f = Eigen::Matrix<T, 1, 8>::Zero();
    const int a = L_.upper[j], b = L_.lower[j];
    f(2 * a) += p_.k[j];
    f(2 * a + 1) += p_.r[j];
    if (b >= 0) {
      f(2 * b) -= p_.k[j];
      f(2 * b + 1) -= p_.r[j];
    }
    return f;
  }

  // Continuous-time A for one phase, in physical units.
  Mat build_A(bool contact) const {
    Mat A = Mat::Zero();
    for (int n = 0; n < 3; ++n) A(2 * n, 2 * n + 1) = T(1.0);
    // Element forces act on the nodes' velocity rows.
    Eigen::Matrix<T, 3, 8> force = Eigen::Matrix<T, 3, 8>::Zero();  // net downward force per node
    for (int j = 0; j < L_.n_elem; ++j) {
      if (j == 0 && !L_.rigid_top && !contact) continue;  // free massless element: no force
      const auto f = element_row(j);
      force.row(L_.upper[j]) -= f;
      if (L_.lower[j] >= 0) force.row(L_.lower[j]) += f;
    }
    force(0, 7) += M_ * g_;  // the impactor's weight; the mat's is static
    if (L_.rigid_top && contact) {
      const Eigen::Matrix<T, 1, 8> a = (force.row(0) + force.row(1)) / (M_ + p_.m1);
      A.row(1) = a;
      A.row(3) = a;
      if (L_.n_mass > 1) A.row(5) = force.row(2) / p_.m2;
    } else {
      A.row(1) = force.row(0) / M_;
      if (L_.n_mass > 0) A.row(3) = force.row(1) / p_.m1;
      if (L_.n_mass > 1) A.row(5) = force.row(2) / p_.m2;
    }
    if (!L_.rigid_top && !contact) {
      // Free massless element 1: k1 e + r1 e' = 0. Rate capped at 50 / h_out
      // (instant on the output grid) so r1 -> 0 stays finite.
      T rate = T(50.0 / h_out_);
      if (scalar_of(p_.r[0]) * 50.0 / h_out_ > scalar_of(p_.k[0])) rate = p_.k[0] / p_.r[0];
      A(6, 6) = -rate;
    }
    return A;
  }

  Mat build(bool contact) const {
    const Mat A = build_A(contact);
    Mat B;
    for (int i = 0; i < 8; ++i)
      for (int j = 0; j < 8; ++j) B(i, j) = A(i, j) * T(h_ * scale_[i] / scale_[j]);
    return B;
  }

  // Event function as a row over the scaled state Z.
  Eigen::Matrix<T, 1, 8> event_row(bool contact) const {
    Eigen::Matrix<T, 1, 8> c = Eigen::Matrix<T, 1, 8>::Zero();
    if (contact) {
      c = element_row(0);  // element 1's force (massless top: the contact force)
      if (L_.rigid_top) c(7) += p_.m1 * g_;  // contact force ~ F1 + m1 g
    } else {
      // gap = impactor - surface; contact again when it turns positive
      c(0) = T(1.0);
      const int base = L_.rigid_top ? 1 : L_.base();
      if (base >= 0) c(2 * base) -= T(1.0);
      if (!L_.rigid_top) c(6) -= T(1.0);
    }
    for (int j = 0; j < 8; ++j) c(j) /= T(scale_[j]);
    return c;
  }

  Vec to_scaled(const Vec& X) const {
    Vec Z = X;
    for (int i = 0; i < 8; ++i) Z(i) *= T(scale_[i]);
    return Z;
  }
  T velocity(const Vec& Z, int node) const { return Z(2 * node + 1) / T(h_); }

  // Advance Z by one output step; returns true and sets *frac_event
  // (fraction of the output step) at the first phase switch inside it.
  bool step_output(Vec& Z, bool& contact, T* frac_event) {
    bool any = false;
    for (int j = 0; j < sub_; ++j) {
      T s;
      if (step(Z, contact, &s) && !any) {
        any = true;
        *frac_event = (T(static_cast<double>(j)) + s) / T(static_cast<double>(sub_));
      }
    }
    return any;
  }

  // Advance Z by one internal step; returns true and sets *frac_event
  // (fraction of the internal step) if the phase switched inside it.
  bool step(Vec& Z, bool& contact, T* frac_event) {
    const int ph = contact ? 0 : 1;
    if (!have_phi_[ph]) {
      Phi_[ph] = expm<T, 8>(B_[ph]);
      have_phi_[ph] = true;
    }
    Vec Zn = Phi_[ph].lazyProduct(Z);
    const Eigen::Matrix<T, 1, 8>& c = c_[ph];
    const T g0 = c.dot(Z), g1 = c.dot(Zn);
    const bool fired = contact ? (scalar_of(g1) < 0.0) : (scalar_of(g1) > 0.0);
    if (!fired) {
      Z = Zn;
      return false;
    }
    // Hermite cubic on s in [0, 1].
    const T d0 = c.dot(Vec(B_[ph].lazyProduct(Z))), d1 = c.dot(Vec(B_[ph].lazyProduct(Zn)));
    T s = g0 / (g0 - g1);
    if (!(scalar_of(s) > 0.0 && scalar_of(s) < 1.0)) s = T(0.5);
    for (int it = 0; it < 4; ++it) {
      const T s2 = s * s, s3 = s2 * s;
      const T p = (2.0 * s3 - 3.0 * s2 + 1.0) * g0 + (s3 - 2.0 * s2 + s) * d0 +
                  (-2.0 * s3 + 3.0 * s2) * g1 + (s3 - s2) * d1;
      const T dp = (6.0 * s2 - 6.0 * s) * g0 + (3.0 * s2 - 4.0 * s + 1.0) * d0 +
                   (-6.0 * s2 + 6.0 * s) * g1 + (3.0 * s2 - 2.0 * s) * d1;
      if (scalar_of(dp) == 0.0) break;
      s = s - p / dp;
      s = clamp01(s);
    }
    // One Newton step on the exact trajectory.
    Vec Zs = expmv<T, 8>(B_[ph], normB_[ph], s, Z);
    const T gs = c.dot(Zs), ds = c.dot(Vec(B_[ph].lazyProduct(Zs)));
    if (scalar_of(ds) != 0.0) {
      const T s_new = clamp01(s - gs / ds);
      Zs = expmv<T, 8>(B_[ph], normB_[ph], s_new, Z);
      s = s_new;
    }
    switch_phase(Zs, contact);
    const T rest = T(1.0) - s;
    const int nph = contact ? 0 : 1;
    Z = expmv<T, 8>(B_[nph], normB_[nph], rest, Zs);
    *frac_event = s;
    return true;
  }

  // Advance a fraction of a step in the contact phase (no event check:
  // used only for the first, partial sample interval).
  void advance(Vec& Z, double frac) const { Z = expmv<T, 8>(B_[0], normB_[0], T(frac * sub_), Z); }

  void switch_phase(Vec& Z, bool& contact) const {
    if (contact) {
      contact = false;
      if (!L_.rigid_top) {
        // The massless element keeps its compression; from now on its top
        // (the surface) moves on its own.
        const int b = L_.base();
        Z(6) = Z(0) - (b >= 0 ? Z(2 * b) : T(0.0));
      }
    } else {
      contact = true;
      Z(6) = T(0.0);
      if (L_.rigid_top) plastic_collision(Z);
    }
  }

  void plastic_collision(Vec& Z) const {
    // Impactor and m1 share momentum (scaled velocities scale alike).
    const T w = (M_ * Z(1) + p_.m1 * Z(3)) / (M_ + p_.m1);
    Z(1) = w;
    Z(3) = w;
    Z(0) = Z(2);
  }

 private:
  static T clamp01(const T& s) {
    if (scalar_of(s) < 0.0) return T(0.0);
    if (scalar_of(s) > 1.0) return T(1.0);
    return s;
  }

  Layout L_;
  ParamsT<T> p_;
  double M_, g_, h_out_, h_ = 0.0;
  int sub_ = 1;
  double scale_[8];
  Mat B_[2], Phi_[2];
  double normB_[2] = {0.0, 0.0};
  bool have_phi_[2] = {true, false};
  Eigen::Matrix<T, 1, 8> c_[2];
};

// Element 1's force with the effects (d compression, dd its rate, fm the
// Maxwell arm's force).
template <typename T>
T element1_force(const ParamsT<T>& p, const T& d, const T& dd, const T& fm) {
  T f = p.k[0] * d;
  if (p.cubic) f += p.k1_cubic * d * d * d;
  if (p.asymmetric) {
    using std::tanh;
    f *= T(1.0) - p.unload_ratio * (T(1.0) - tanh(dd / p.unload_speed)) * 0.5;
  }
  const T r = (p.hysteresis && scalar_of(dd) < 0.0) ? p.r1_unload : p.r[0];
  f += r * dd;
  if (p.maxwell) f += fm;
  return f;
}

// ---------------------------------------------------------------------------
// Fixed-step RK4 with the contact force clamped inside the step (so the
// separation instant is resolved within the step) and the phase switched at
// the step's end. The free massless element (Models 1, 4) relaxes by a
// semi-implicit step outside RK4 (it only places the surface).
template <typename T>
class Rk4Integrator {
 public:
  using Vec = Eigen::Matrix<T, 8, 1>;

  Rk4Integrator(const Layout& L, const ParamsT<T>& p, const Impact& imp)
      : L_(L), p_(p), M_(imp.mass_kg), g_(imp.gravity_m_s2) {
    // Inverse masses once per simulation (a division of dual numbers costs
    // about twice a product, and every stage divided three times).
    if (L_.n_mass > 0) inv_m1_ = T(1.0) / p_.m1;
    if (L_.n_mass > 1) inv_m2_ = T(1.0) / p_.m2;
    if (p_.maxwell) inv_tau_ = T(1.0) / p_.maxwell_tau;
    // The entries RK4 integrates: the nodes' positions and velocities, and
    // the Maxwell arm's force (entry 6, the free element, relaxes outside).
    for (int i = 0; i < 2 * (L_.n_mass + 1); ++i) active_[n_active_++] = i;
    if (p_.maxwell) active_[n_active_++] = 7;
  }

  // Element j's force given the state (element 1 with effects).
  T elem_force(const Vec& X, int j) const {
    const int a = L_.upper[j], b = L_.lower[j];
    const T d = b >= 0 ? T(X(2 * a) - X(2 * b)) : X(2 * a);
    const T dd = b >= 0 ? T(X(2 * a + 1) - X(2 * b + 1)) : X(2 * a + 1);
    if (j == 0) return element1_force(p_, d, dd, X(7));
    return p_.k[j] * d + p_.r[j] * dd;
  }
  T elem1_rate(const Vec& X) const {
    const int a = L_.upper[0], b = L_.lower[0];
    return b >= 0 ? T(X(2 * a + 1) - X(2 * b + 1)) : X(2 * a + 1);
  }

  // Contact force on the impactor (unclamped) in contact.
  T contact_force(const Vec& X) const {
    const T f1 = elem_force(X, 0);
    if (!L_.rigid_top) return f1;
    return M_ * (p_.m1 * g_ + f1) / (M_ + p_.m1);
  }

  // The derivative of the active entries (the others are left as they are).
  void deriv(const Vec& X, bool contact, Vec& D) const {
    T force[3] = {T(M_ * g_), T(0.0), T(0.0)};
    for (int j = 0; j < L_.n_elem; ++j) {
      const int a = L_.upper[j], b = L_.lower[j];
      T f;
      if (j == 0 && !L_.rigid_top) {
        f = T(0.0);
        if (contact) {
          f = elem_force(X, 0);
          if (scalar_of(f) < 0.0) f = T(0.0);
        }
      } else {
        f = elem_force(X, j);
      }
      force[a] -= f;
      if (b >= 0) force[b] += f;
    }
    if (L_.rigid_top && contact) {
      // Contact force lambda between impactor and m1, clamped at zero.
      T lam = M_ * (p_.m1 * g_ - force[1]) / (M_ + p_.m1);
      if (scalar_of(lam) < 0.0) lam = T(0.0);
      force[0] -= lam;
      force[1] += lam;
    }
    D(0) = X(1);
    D(1) = force[0] * (1.0 / M_);
    if (L_.n_mass > 0) {
      D(2) = X(3);
      D(3) = force[1] * inv_m1_;
    }
    if (L_.n_mass > 1) {
      D(4) = X(5);
      D(5) = force[2] * inv_m2_;
    }
    if (p_.maxwell) {
      const bool active = L_.rigid_top || contact;
      D(7) = active ? T(p_.maxwell_k * elem1_rate(X) - X(7) * inv_tau_) : T(0.0);
    }
  }

  void step(Vec& X, bool contact, double h) const {
    Vec k1, k2, k3, k4, Y = X;
    deriv(X, contact, k1);
    for (int q = 0; q < n_active_; ++q) Y(active_[q]) = X(active_[q]) + k1(active_[q]) * (0.5 * h);
    deriv(Y, contact, k2);
    for (int q = 0; q < n_active_; ++q) Y(active_[q]) = X(active_[q]) + k2(active_[q]) * (0.5 * h);
    deriv(Y, contact, k3);
    for (int q = 0; q < n_active_; ++q) Y(active_[q]) = X(active_[q]) + k3(active_[q]) * h;
    deriv(Y, contact, k4);
    for (int q = 0; q < n_active_; ++q) {
      const int i = active_[q];
      X(i) += (k1(i) + 2.0 * (k2(i) + k3(i)) + k4(i)) * (h / 6.0);
    }
    if (!contact && !L_.rigid_top) relax_free_element(X, h);
  }

  // Free massless element 1: F1(e, e') = 0, backward Euler in e and in the
  // Maxwell arm's force together (the cubic term taken at the step's
  // start):
  //   a k1 (e + de) + c(e) + r de / h + (Fm + mk de) / (1 + h / tau) = 0.
  // Taking Fm at the step's start instead is unstable once mk h / r
  // exceeds about 2 (a stiff, fast arm beside a lightly damped element:
  // mk 1.8e6 N/m, r1 17 N s/m blew up within a few steps of separation).
  void relax_free_element(Vec& X, double h) const {
    const T e = X(6);
    // While it relaxes the element extends: its elastic force is the
    // unloading one.
    const T a = p_.asymmetric ? T(1.0) - p_.unload_ratio : T(1.0);
    const T cubic = p_.cubic ? T(a * p_.k1_cubic * e * e * e) : T(0.0);
    const T relax = p_.maxwell ? T(1.0) + T(h) / p_.maxwell_tau : T(1.0);  // the arm's decay over the step
    const T fm = p_.maxwell ? X(7) : T(0.0);
    const T elastic = a * p_.k[0] * e + cubic + fm;  // > 0: the element extends
    T r = (p_.hysteresis && scalar_of(elastic) > 0.0) ? p_.r1_unload : p_.r[0];
    if (scalar_of(r) * 50.0 / h < scalar_of(p_.k[0]) || scalar_of(r) <= 0.0) r = p_.k[0] * T(h / 50.0);
    T den = a * p_.k[0] + r / T(h);
    T num = a * p_.k[0] * e + cubic;
    if (p_.maxwell) {
      den += p_.maxwell_k / relax;
      num += fm / relax;
    }
    const T de = -num / den;
    if (p_.maxwell) X(7) = (fm + p_.maxwell_k * de) / relax;
    X(6) = e + de;
  }

  T surface(const Vec& X, bool contact) const {
    if (L_.rigid_top) return X(2);
    if (contact) return X(0);
    const int b = L_.base();
    return (b >= 0 ? X(2 * b) : T(0.0)) + X(6);
  }

  // Phase switch at a step's end; returns true if it switched.
  bool check_switch(Vec& X, bool& contact) const {
    if (contact) {
      if (scalar_of(contact_force(X)) >= 0.0) return false;
      contact = false;
      if (!L_.rigid_top) {
        const int b = L_.base();
        X(6) = X(0) - (b >= 0 ? X(2 * b) : T(0.0));
      }
      return true;
    }
    if (scalar_of(X(0) - surface(X, false)) <= 0.0) return false;
    contact = true;
    if (L_.rigid_top) {
      const T v = (M_ * X(1) + p_.m1 * X(3)) / (M_ + p_.m1);
      X(1) = v;
      X(3) = v;
      X(0) = X(2);
    } else {
      X(6) = T(0.0);
    }
    return true;
  }

 private:
  Layout L_;
  ParamsT<T> p_;
  double M_, g_;
  T inv_m1_ = T(0.0), inv_m2_ = T(0.0), inv_tau_ = T(0.0);
  int active_[7] = {0, 0, 0, 0, 0, 0, 0};
  int n_active_ = 0;
};

// ---------------------------------------------------------------------------
// Ground reaction: the force of the element touching the ground (index
// n_elem - 1) from the masses' travels y and velocities w (0: the impactor,
// 1 and 2: the layers), the contact state and the Maxwell arm's force fm.
template <typename T>
T ground_force(const Layout& L, const ParamsT<T>& p, const T& y1, const T& w1, const T& y2, const T& w2,
               const T& y0, const T& w0, bool contact, const T& fm) {
  const int j = L.n_elem - 1;
  const int a = L.upper[j];
  const T ya = a == 0 ? y0 : (a == 1 ? y1 : y2);
  const T va = a == 0 ? w0 : (a == 1 ? w1 : w2);
  if (j == 0) {
    if (!L.rigid_top && !contact) return T(0.0);
    T f = element1_force(p, ya, va, fm);
    if (!L.rigid_top && scalar_of(f) < 0.0) f = T(0.0);
    return f;
  }
  return p.k[j] * ya + p.r[j] * va;
}

// The state at first contact (t = 0+): the impactor (and a rigid top) at
// v_start, everything else at rest.
template <typename Vec, typename T>
Vec contact_state(const Layout& L, const T& v_start) {
  Vec X = Vec::Zero();
  X(1) = v_start;
  if (L.rigid_top) X(3) = v_start;
  return X;
}

// The exponential form (no effects): outputs at t = first_output_s + i h
// from the state at first contact (impactor and rigid top at v_start).
template <typename T>
void run_exact(const Layout& L, const ParamsT<T>& p, const Impact& imp, const T& v_start, int n, Trace<T>& out) {
  const double h = imp.output_dt_s;
  bool contact = true;
  ExactIntegrator<T> ex(L, p, imp);
  auto X = contact_state<typename ExactIntegrator<T>::Vec>(L, v_start);
  X(7) = T(1.0);
  typename ExactIntegrator<T>::Vec Z = ex.to_scaled(X);
  const T hh = T(h);
  if (imp.first_output_s > 0.0) ex.advance(Z, imp.first_output_s / h);
  for (int i = 0; i < n; ++i) {
    if (i > 0) {
      T frac = T(0.0);
      const bool was_contact = contact;
      if (ex.step_output(Z, contact, &frac) && was_contact && !out.separated) {
        out.separated = true;
        out.separation_s = (T(i - 1) + frac) * hh + T(imp.first_output_s);
      }
    }
    const T y0 = Z(0), y1 = Z(2), y2 = Z(4);
    const T w0 = ex.velocity(Z, 0), w1 = ex.velocity(Z, 1), w2 = ex.velocity(Z, 2);
    out.impactor[i] = y0;
    out.layer1[i] = L.n_mass > 0 ? y1 : T(0.0);
    out.layer2[i] = L.n_mass > 1 ? y2 : T(0.0);
    if (L.rigid_top) {
      out.surface[i] = y1;
    } else if (contact) {
      out.surface[i] = y0;
    } else {
      out.surface[i] = (L.base() >= 0 ? Z(2 * L.base()) : T(0.0)) + Z(6);
    }
    out.grf[i] = ground_force(L, p, y1, w1, y2, w2, y0, w0, contact, T(0.0));
  }
}

// RK4's longest step: at most rk4_max_step_s, 0.5 / w and 1 / d, with w a
// rough bound on the fastest oscillation (stiffnesses over the lightest
// mass) and d on the fastest decay (dampings over it, and a Maxwell arm's
// 1 / tau). An oscillation needs the step for accuracy (RK4's phase error
// grows as (h w)^4); a decay only for stability (h d <= 2.8) and for the
// quasi-static force it leaves, which h d <= 1 keeps within 0.001 % of the
// peak (docs/models.md). Separate bounds keep heavily damped layers, which
// the fitter tries, from shortening the step as a stiff one would.
template <typename T>
double rk4_step_bound_s(const Layout& L, const ParamsT<T>& p, const Impact& imp, double rk4_max_step_s) {
  double k_sum = 0.0, r_sum = 0.0, m_min = imp.mass_kg;
  for (int j = 0; j < L.n_elem; ++j) {
    k_sum += std::abs(scalar_of(p.k[j]));
    r_sum += std::abs(scalar_of(p.r[j]));
  }
  if (p.hysteresis) r_sum += std::abs(scalar_of(p.r1_unload));
  if (p.maxwell) k_sum += std::abs(scalar_of(p.maxwell_k));
  if (L.n_mass > 0) m_min = std::min(m_min, scalar_of(p.m1));
  if (L.n_mass > 1) m_min = std::min(m_min, scalar_of(p.m2));
  m_min = std::max(m_min, 1e-6);
  const double w = std::sqrt(k_sum / m_min);
  double d = r_sum / m_min;
  if (p.maxwell) d = std::max(d, 1.0 / std::max(scalar_of(p.maxwell_tau), 1e-9));
  return std::min({rk4_max_step_s, 0.5 / std::max(w, 1e-9), 1.0 / std::max(d, 1e-9)});
}

// RK4 (any effect): each output interval in equal substeps within
// rk4_step_bound_s; the separation instant interpolated on the contact
// force within its substep.
template <typename T>
void run_rk4(const Layout& L, const ParamsT<T>& p, const Impact& imp, const T& v_start, double rk4_max_step_s,
             int n, Trace<T>& out) {
  const double h = imp.output_dt_s;
  bool contact = true;
  Rk4Integrator<T> rk(L, p, imp);
  auto X = contact_state<typename Rk4Integrator<T>::Vec>(L, v_start);
  const double h_max = rk4_step_bound_s(L, p, imp, rk4_max_step_s);
  const int sub = std::max(1, static_cast<int>(std::ceil(h / h_max - 1e-9)));
  const double hs = h / sub;
  if (imp.first_output_s > 0.0) {
    const int k0 = std::max(1, static_cast<int>(std::ceil(imp.first_output_s / h_max - 1e-9)));
    for (int k = 0; k < k0; ++k) {
      rk.step(X, contact, imp.first_output_s / k0);
      rk.check_switch(X, contact);
    }
  }
  for (int i = 0; i < n; ++i) {
    if (i > 0) {
      for (int k = 0; k < sub; ++k) {
        const bool was_contact = contact;
        // Contact force before the step, for the separation instant.
        const T f_before = was_contact ? rk.contact_force(X) : T(0.0);
        rk.step(X, contact, hs);
        if (rk.check_switch(X, contact) && was_contact && !out.separated) {
          const T f_after = rk.contact_force(X);
          T frac = f_before / (f_before - f_after);
          if (!(scalar_of(frac) >= 0.0 && scalar_of(frac) <= 1.0)) frac = T(1.0);
          out.separated = true;
          out.separation_s = T(imp.first_output_s + (i - 1) * h + k * hs) + frac * T(hs);
        }
      }
    }
    out.impactor[i] = X(0);
    out.layer1[i] = L.n_mass > 0 ? X(2) : T(0.0);
    out.layer2[i] = L.n_mass > 1 ? X(4) : T(0.0);
    out.surface[i] = rk.surface(X, contact);
    out.grf[i] = ground_force(L, p, X(2), X(3), X(4), X(5), X(0), X(1), contact, X(7));
  }
}

// Runs one impact and fills `out` at t = i * output_dt, i = 0..n-1.
// use_exact: the exponential form (no effects allowed).
template <typename T>
void run_model(const Layout& L, const ParamsT<T>& p, const Impact& imp, bool use_exact,
               double rk4_max_step_s, int n, Trace<T>& out) {
  out.grf.assign(n, T(0.0));
  out.impactor.assign(n, T(0.0));
  out.surface.assign(n, T(0.0));
  out.layer1.assign(n, T(0.0));
  out.layer2.assign(n, T(0.0));
  out.separated = false;
  out.separation_s = T(0.0);
  const T M = T(imp.mass_kg);
  const T v0 = T(imp.velocity_m_s);
  // Initial state at first contact (t = 0+): rigid-top models share
  // momentum with m1 in a plastic collision.
  const T v_start = L.rigid_top ? M * v0 / (M + p.m1) : v0;
  if (use_exact)
    run_exact(L, p, imp, v_start, n, out);
  else
    run_rk4(L, p, imp, v_start, rk4_max_step_s, n, out);
}

// Maps MatParams (or a parameter block) onto ParamsT for a model.
template <typename T>
ParamsT<T> to_params_t(ModelKind kind, const MatParams& mp) {
  ParamsT<T> p;
  p.k[0] = T(mp.k1_n_m); p.k[1] = T(mp.k2_n_m); p.k[2] = T(mp.k3_n_m);
  p.r[0] = T(mp.r1_n_s_m); p.r[1] = T(mp.r2_n_s_m); p.r[2] = T(mp.r3_n_s_m);
  if (kind == ModelKind::Model2) {
    p.m1 = T(mp.m_eff_kg); p.m2 = T(0.0);
  } else {
    p.m1 = T(mp.m1_kg); p.m2 = T(mp.m2_kg);
  }
  p.k1_cubic = T(mp.k1_cubic_n_m3);
  p.r1_unload = T(std::max(mp.r1_unload_n_s_m, 0.0));
  p.maxwell_k = T(mp.maxwell_k_n_m);
  p.maxwell_tau = T(mp.maxwell_tau_s > 0.0 ? mp.maxwell_tau_s : 1.0);
  p.cubic = mp.k1_cubic_n_m3 != 0.0;
  p.hysteresis = mp.r1_unload_n_s_m >= 0.0;
  p.maxwell = mp.maxwell_k_n_m > 0.0 && mp.maxwell_tau_s > 0.0;
  p.unload_ratio = T(mp.k1_unload_ratio);
  p.unload_speed = mp.k1_unload_speed_m_s > 0.0 ? mp.k1_unload_speed_m_s : 0.05;
  p.asymmetric = mp.k1_unload_ratio > 0.0;
  return p;
}

}  // namespace dropfit::fitting::detail
