#pragma once
// Model 5 (fitting/model5.h) templated on the scalar type, so that
// ceres::Jet flows through it (exact derivatives for the fitter), and the
// integrator that keeps it stable and fast at any stiffness and damping.
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

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <type_traits>
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
  double step_s = 0.0;   // integration step (divides output_dt_s)
  int n_sub = 1;         // steps per output step
  int n_first = 0;       // steps to reach first_output_s (0 if it is 0)
  double first_step_s = 0.0;
};

// Validates (throws Error) and builds the layout; the parameters' scalar
// parts choose nothing but are checked.
Layout make_layout(const Model5ParamsT<double>& params, const Model5Geometry& geometry, const Impact& impact);

// Samples a simulation produces for `impact`: t = first_output_s + i * output_dt_s <= duration_s.
int sample_count(const Impact& impact);

// A 3 x 3 matrix of any scalar (no Eigen traits needed).
template <typename T>
struct Small3 {
  T m[9];
  T& operator()(int r, int c) { return m[3 * r + c]; }
  const T& operator()(int r, int c) const { return m[3 * r + c]; }
};

// Forward-mode dual number with N derivatives: what simulate_model5_t runs
// on for a ceres::Jet<double, N> (the same arithmetic as the Jet, in plain
// arrays the compiler inlines; Eigen's 8-vectors behind the Jet were not
// inlined here and cost 4x more).
template <int N>
struct Dual {
  double a = 0.0;
  double v[N] = {};
  Dual() = default;
  explicit Dual(double x) : a(x) {}
  Dual& operator+=(const Dual& o) {
    a += o.a;
    for (int i = 0; i < N; ++i) v[i] += o.v[i];
    return *this;
  }
  Dual& operator-=(const Dual& o) {
    a -= o.a;
    for (int i = 0; i < N; ++i) v[i] -= o.v[i];
    return *this;
  }
  Dual& operator*=(const Dual& o) {
    for (int i = 0; i < N; ++i) v[i] = v[i] * o.a + a * o.v[i];
    a *= o.a;
    return *this;
  }
  Dual& operator*=(double s) {
    a *= s;
    for (int i = 0; i < N; ++i) v[i] *= s;
    return *this;
  }
};
template <int N>
inline Dual<N> operator+(Dual<N> x, const Dual<N>& y) { return x += y; }
template <int N>
inline Dual<N> operator-(Dual<N> x, const Dual<N>& y) { return x -= y; }
template <int N>
inline Dual<N> operator-(Dual<N> x) {
  x.a = -x.a;
  for (int i = 0; i < N; ++i) x.v[i] = -x.v[i];
  return x;
}
template <int N>
inline Dual<N> operator*(Dual<N> x, const Dual<N>& y) { return x *= y; }
template <int N>
inline Dual<N> operator*(Dual<N> x, double s) { return x *= s; }
template <int N>
inline Dual<N> operator*(double s, Dual<N> x) { return x *= s; }
template <int N>
inline Dual<N> operator+(Dual<N> x, double s) {
  x.a += s;
  return x;
}
template <int N>
inline Dual<N> operator+(double s, Dual<N> x) {
  x.a += s;
  return x;
}
template <int N>
inline Dual<N> operator-(Dual<N> x, double s) {
  x.a -= s;
  return x;
}
template <int N>
inline Dual<N> operator-(double s, const Dual<N>& x) {
  Dual<N> r = -x;
  r.a += s;
  return r;
}
template <int N>
inline Dual<N> operator/(const Dual<N>& x, const Dual<N>& y) {
  const double inv = 1.0 / y.a;
  Dual<N> r;
  r.a = x.a * inv;
  for (int i = 0; i < N; ++i) r.v[i] = (x.v[i] - r.a * y.v[i]) * inv;
  return r;
}
template <int N>
inline Dual<N> operator/(const Dual<N>& x, double s) { return x * (1.0 / s); }
template <int N>
inline Dual<N> operator/(double s, const Dual<N>& y) { return Dual<N>(s) / y; }
template <int N>
inline Dual<N> exp(const Dual<N>& x) {
  const double e = std::exp(x.a);
  Dual<N> r = x * e;
  r.a = e;
  return r;
}

template <typename T>
class Integrator {
 public:
  Integrator(const Model5ParamsT<T>& p, const Model5Geometry& g, const Impact& imp, const Layout& L)
      : L_(L), p_(p), M_(imp.mass_kg), g_(imp.gravity_m_s2) {
    const int n = L.n;
    const double nc = static_cast<double>(n);
    k2n_ = p.k2_n_m / nc;
    r2n_ = p.r2_n_s_m / nc;
    k3n_ = p.k3_n_m / nc;
    r3n_ = p.r3_n_s_m / nc;
    m1n_ = p.m1_kg / nc;
    m2n_ = p.m2_kg / nc;
    s1_ = g.shear1_n_m;
    s2_ = g.shear2_n_m;
    c1_ = g.shear_damping1_n_s_m;
    c2_ = g.shear_damping2_n_s_m;
    r_ext_ = p.hysteresis ? p.r1_unload_n_s_m : p.r1_n_s_m;
    for (auto* v : {&z1_, &z2_, &v1_, &v2_, &top_, &d_, &dd_, &fr_, &b1_, &b2_})
      v->assign(n, T(0.0));
    in_.assign(n, 0);
    impulse_.assign(n, T(0.0));
    was_.assign(n, 0);
    unload_.assign(n, 0);
    cached_in_.assign(n, 2);
    cached_unload_.assign(n, 2);
    for (auto* v : {&g1_, &g12_, &g2_, &sa1_, &sa2_, &acol_, &q1r_, &q2r_, &w1r_, &w2r_, &p1_, &p2_, &k1v_, &c1v_,
                    &ab1_, &ab2_})
      v->assign(n, T(0.0));
    for (int l = 0; l + 1 < kStages; ++l)
      for (auto* v : {&sv1_[l], &sv2_[l], &sa1s_[l], &sa2s_[l]}) v->assign(n, T(0.0));
    zc_ = T(L.zc0);
    tx_ = T(L.tx0);
    ty_ = T(L.ty0);
    vc_ = T(imp.velocity_m_s);
    wx_ = T(L.wx0);
    wy_ = T(L.wy0);
    for (int j : L.face) k1v_[j] = p.k1_n_m * L.w[j];
  }

  // Contact decision at the current instant (call once per step, before
  // step()): element 1's compression D and rate per face cell, which cells
  // the face presses (it reaches the element's top and pushes), and the
  // total contact force. Returns the contact force (N).
  T contact() {
    T total = T(0.0);
    for (int j : L_.face) {
      const T u = zc_ + tx_ * L_.lx[j] + ty_ * L_.ly[j];
      const T ud = vc_ + wx_ * L_.lx[j] + wy_ * L_.ly[j];
      d_[j] = u - z1_[j];
      dd_[j] = ud - v1_[j];
      unload_[j] = p_.hysteresis && detail::scalar_of(dd_[j]) < 0.0;
      T f = k1v_[j] * d_[j] + (unload_[j] ? p_.r1_unload_n_s_m : p_.r1_n_s_m) * L_.w[j] * dd_[j];
      if (p_.cubic) f += p_.k1_cubic_n_m3 * L_.w[j] * d_[j] * d_[j] * d_[j];
      fr_[j] = f;
      was_[j] = in_[j];
      // Pressed while it was, or once the face reaches the element's top;
      // released by step() when its impulse pulls.
      in_[j] = in_[j] || detail::scalar_of(d_[j]) >= detail::scalar_of(top_[j]);
      if (in_[j] && detail::scalar_of(f) > 0.0) total += f;
    }
    return total;
  }

  // Advances by h from the instant contact() examined. The contact set is
  // made consistent with the step (active set, as implicit contact
  // time-stepping does): a pressed cell whose contact impulse over the step
  // (the method's quadrature of its stage forces) pulls is released and the
  // step redone (at most kMaxRedo times). The impulse, not the force at
  // one instant, decides: with stiff damping the force at an instant
  // carries the unresolved fast transients, the impulse does not.
  void step(double h) {
    // Only a pressed cell can be released: with none, no state is saved.
    bool pressed = false;
    for (int j : L_.face) pressed = pressed || in_[j];
    for (int iter = 0;; ++iter) {
      const bool may_redo = pressed && iter < kMaxRedo;
      if (may_redo) save();
      advance(h);
      if (!may_redo) break;
      bool redo = false;
      for (int j : L_.face) {
        if (in_[j] && detail::scalar_of(impulse_[j]) < 0.0) {
          in_[j] = 0;
          redo = true;
        }
      }
      if (!redo) break;
      restore();
    }
  }

  // Ground reaction: element 3 of every column plus the frame's share of
  // the shear links (N, downwards on the plate).
  T grf() const {
    T f = T(0.0);
    for (int j = 0; j < L_.n; ++j) f += k3n_ * z2_[j] + r3n_ * v2_[j];
    for (std::size_t e = 0; e < L_.frame_cell.size(); ++e) {
      const int j = L_.frame_cell[e];
      f += L_.frame_f[e] * (s1_ * z1_[j] + c1_ * v1_[j] + s2_ * z2_[j] + c2_ * v2_[j]);
    }
    return f;
  }
  // Bilinear among cell centres under the face centre.
  T probe(const std::vector<T>& z) const {
    auto at = [&](int ix, int iy) { return z[ix * L_.ny + iy]; };
    return (1.0 - L_.fyw) * ((1.0 - L_.fxw) * at(L_.px, L_.py) + L_.fxw * at(L_.px1, L_.py)) +
           L_.fyw * ((1.0 - L_.fxw) * at(L_.px, L_.py1) + L_.fxw * at(L_.px1, L_.py1));
  }
  // Element 1's top under the face centre, from the last contact(): the
  // face where it presses, the relaxing top elsewhere.
  T surface() const {
    std::vector<T>& s = scratch_;
    s.assign(L_.n, T(0.0));
    for (int j : L_.face) s[j] = in_[j] ? d_[j] : top_[j];
    return probe(z1_) + probe(s);
  }
  // The extra volume under the face where it presses below the top layer.
  T face_dent_m3() const {
    T v = T(0.0);
    for (int j : L_.face) {
      const T s = in_[j] ? d_[j] : top_[j];
      if (detail::scalar_of(s) > 0.0) v += L_.w[j] * s;
    }
    return v * L_.face_area;
  }
  T mat_momentum() const {
    T m = T(0.0);
    for (int j = 0; j < L_.n; ++j) m += m1n_ * v1_[j] + m2n_ * v2_[j];
    return m;
  }

  const std::vector<T>& z1() const { return z1_; }
  const std::vector<T>& z2() const { return z2_; }
  const T& zc() const { return zc_; }
  const T& vc() const { return vc_; }
  const T& tilt_x() const { return tx_; }
  const T& tilt_y() const { return ty_; }

 private:
  // One step of length h with the current contact set: element tops relax,
  // half kick, implicit step, half kick.
  void advance(double h) {
    if (h != relax_h_) {
      relax_h_ = h;
      using std::exp;
      relax_ = detail::scalar_of(r_ext_) > 0.0 ? T(exp(-(T(h) / r_ext_) * p_.k1_n_m)) : T(0.0);
    }
    for (int j : L_.face) {
      if (in_[j] || was_[j]) top_[j] = detail::scalar_of(d_[j]) > 0.0 ? d_[j] : T(0.0);
      if (p_.cubic && detail::scalar_of(r_ext_) > 0.0) {
        using std::exp;
        top_[j] *= exp(-(T(h) / r_ext_) * (p_.k1_n_m + p_.k1_cubic_n_m3 * top_[j] * top_[j]));
      } else {
        top_[j] *= relax_;
      }
    }
    kick(pending_ + 0.5 * h);
    implicit_step(h);
    pending_ = 0.5 * h;
  }

 public:
  // Applies the half kick the last step still owes (before reading velocities).
  void sync() {
    kick(pending_);
    pending_ = 0.0;
  }

 private:

  void save() {
    z1s_ = z1_;
    z2s_ = z2_;
    v1s_ = v1_;
    v2s_ = v2_;
    top0_ = top_;
    ab1s_ = ab1_;
    ab2s_ = ab2_;
    pending_s_ = pending_;
    imp_s_[0] = zc_, imp_s_[1] = tx_, imp_s_[2] = ty_, imp_s_[3] = vc_, imp_s_[4] = wx_, imp_s_[5] = wy_;
  }
  void restore() {
    z1_ = z1s_;
    z2_ = z2s_;
    v1_ = v1s_;
    v2_ = v2s_;
    top_ = top0_;
    ab1_ = ab1s_;
    ab2_ = ab2s_;
    pending_ = pending_s_;
    zc_ = imp_s_[0], tx_ = imp_s_[1], ty_ = imp_s_[2], vc_ = imp_s_[3], wx_ = imp_s_[4], wy_ = imp_s_[5];
  }

  // Shear (and cubic) accelerations as a kick of length tau, positions
  // held. The shear damping uses the velocity estimate half-way through the
  // kick from the previous kick's acceleration (one stencil pass per kick;
  // the same second-order device as the explicit scheme's).
  void kick(double tau) {
    if (tau == 0.0) return;
    // The shear damping, explicit here, would cap the step at about
    // 1 / (its fastest rate); sub-kicks of at most 0.8 of that keep it
    // stable at any step (positions are held during the kick, so the shear
    // stiffness alone bounds the step: see make_layout).
    const int m = std::max(1, static_cast<int>(std::ceil(L_.shear_gamma * tau / 0.8 - 1e-9)));
    for (int k = 0; k < m; ++k) kick_once(tau / m);
  }

  void kick_once(double tau) {
    const bool damped = c1_ > 0.0 || c2_ > 0.0;
    const int n = L_.n;
    std::vector<T>& g1 = b1_;
    std::vector<T>& g2 = b2_;
    for (int j = 0; j < n; ++j) {
      g1[j] = s1_ * z1_[j];
      g2[j] = s2_ * z2_[j];
    }
    if (damped) {
      for (int j = 0; j < n; ++j) {
        g1[j] += c1_ * (v1_[j] + (0.5 * tau) * ab1_[j]);
        g2[j] += c2_ * (v2_[j] + (0.5 * tau) * ab2_[j]);
      }
    }
    // Shear stencil on the grid (flat index j = ix * ny + iy): links along
    // x join j and j + ny with factor dy/dx, along y j and j + 1 with dx/dy;
    // frame links (framed edges) pull each edge cell towards travel 0.
    const int nx = L_.nx, ny = L_.ny;
    const double fx = L_.dy / L_.dx, fy = L_.dx / L_.dy;
    for (int j = 0; j < n; ++j) {
      ab1_[j] = -L_.frame_w[j] * g1[j];
      ab2_[j] = -L_.frame_w[j] * g2[j];
    }
    for (int ix = 0; ix + 1 < nx; ++ix) {
      const int o = ix * ny;
      for (int iy = 0; iy < ny; ++iy) {
        const int j = o + iy;
        const T t1 = fx * (g1[j + ny] - g1[j]), t2 = fx * (g2[j + ny] - g2[j]);
        ab1_[j] += t1;
        ab1_[j + ny] -= t1;
        ab2_[j] += t2;
        ab2_[j + ny] -= t2;
      }
    }
    for (int ix = 0; ix < nx; ++ix) {
      const int o = ix * ny;
      for (int iy = 0; iy + 1 < ny; ++iy) {
        const int j = o + iy;
        const T t1 = fy * (g1[j + 1] - g1[j]), t2 = fy * (g2[j + 1] - g2[j]);
        ab1_[j] += t1;
        ab1_[j + 1] -= t1;
        ab2_[j] += t2;
        ab2_[j + 1] -= t2;
      }
    }
    const T im1 = T(1.0) / m1n_, im2 = T(1.0) / m2n_;
    for (int j = 0; j < n; ++j) {
      ab1_[j] *= im1;
      ab2_[j] *= im2;
      v1_[j] += tau * ab1_[j];
      v2_[j] += tau * ab2_[j];
    }
    if (p_.cubic) {
      T fz = T(0.0), fx = T(0.0), fy = T(0.0);
      for (int j : L_.face) {
        if (!in_[j]) continue;
        const T d = zc_ + tx_ * L_.lx[j] + ty_ * L_.ly[j] - z1_[j];
        const T f = p_.k1_cubic_n_m3 * L_.w[j] * d * d * d;
        v1_[j] += tau * f * im1;
        fz += f;
        fx += f * L_.lx[j];
        fy += f * L_.ly[j];
      }
      vc_ -= tau * fz / M_;
      wx_ -= tau * fx / L_.inertia_x;
      wy_ -= tau * fy / L_.inertia_y;
    }
  }

  // The stage matrix (M + beta C + beta^2 K), factored by columns, for the
  // current contact set and unloading pattern; beta = h gamma.
  void build(double beta) {
    const T b2 = beta * r2n_ + (beta * beta) * k2n_;
    const T b3 = beta * r3n_ + (beta * beta) * k3n_;
    Small3<T> S;
    for (T& x : S.m) x = T(0.0);
    S(0, 0) = T(M_);
    S(1, 1) = T(L_.inertia_x);
    S(2, 2) = T(L_.inertia_y);
    {  // free columns share one 2 x 2 inverse
      const T a11 = m1n_ + b2, a22 = m2n_ + b2 + b3;
      const T inv_det = T(1.0) / (a11 * a22 - b2 * b2);
      fg1_ = a22 * inv_det;
      fg12_ = b2 * inv_det;
      fg2_ = a11 * inv_det;
    }
    coupled_.clear();
    free_.clear();
    for (int j = 0; j < L_.n; ++j) {
      if (!in_[j]) {
        free_.push_back(j);
        continue;
      }
      coupled_.push_back(j);
      const T c1 = (unload_[j] ? p_.r1_unload_n_s_m : p_.r1_n_s_m) * L_.w[j];
      c1v_[j] = c1;
      const T a = beta * c1 + (beta * beta) * k1v_[j];
      const T a11 = m1n_ + a + b2, a22 = m2n_ + b2 + b3;
      const T inv_det = T(1.0) / (a11 * a22 - b2 * b2);
      g1_[j] = a22 * inv_det;
      g12_[j] = b2 * inv_det;
      g2_[j] = a11 * inv_det;
      acol_[j] = a;
      sa1_[j] = a * g1_[j];
      sa2_[j] = a * g12_[j];
      const double e[3] = {1.0, L_.lx[j], L_.ly[j]};
      const T c = a * (T(1.0) - sa1_[j]);
      for (int r = 0; r < 3; ++r)
        for (int q = 0; q < 3; ++q) S(r, q) += c * (e[r] * e[q]);
    }
    // Inverse by cofactors (S is symmetric positive definite, 3 x 3).
    const T c00 = S(1, 1) * S(2, 2) - S(1, 2) * S(2, 1), c01 = S(1, 2) * S(2, 0) - S(1, 0) * S(2, 2),
            c02 = S(1, 0) * S(2, 1) - S(1, 1) * S(2, 0);
    const T inv_det_s = T(1.0) / (S(0, 0) * c00 + S(0, 1) * c01 + S(0, 2) * c02);
    s_inv_(0, 0) = c00 * inv_det_s;
    s_inv_(1, 0) = c01 * inv_det_s;
    s_inv_(2, 0) = c02 * inv_det_s;
    s_inv_(0, 1) = (S(0, 2) * S(2, 1) - S(0, 1) * S(2, 2)) * inv_det_s;
    s_inv_(1, 1) = (S(0, 0) * S(2, 2) - S(0, 2) * S(2, 0)) * inv_det_s;
    s_inv_(2, 1) = (S(0, 1) * S(2, 0) - S(0, 0) * S(2, 1)) * inv_det_s;
    s_inv_(0, 2) = (S(0, 1) * S(1, 2) - S(0, 2) * S(1, 1)) * inv_det_s;
    s_inv_(1, 2) = (S(0, 2) * S(1, 0) - S(0, 0) * S(1, 2)) * inv_det_s;
    s_inv_(2, 2) = (S(0, 0) * S(1, 1) - S(0, 1) * S(1, 0)) * inv_det_s;
    cached_beta_ = beta;
    for (int j = 0; j < L_.n; ++j) {
      cached_in_[j] = in_[j];
      cached_unload_[j] = unload_[j];
    }
  }

  bool pattern_changed(double beta) const {
    if (beta != cached_beta_) return true;
    for (int j : L_.face)
      if (cached_in_[j] != in_[j] || (in_[j] && cached_unload_[j] != unload_[j])) return true;
    return false;
  }

  // SDIRK3 (Alexander 1977; Hairer & Wanner, Solving ODEs II, Table IV.6.5):
  // three stages, L-stable, stiffly accurate, order 3, gamma the root of
  // x^3 - 3 x^2 + 3/2 x - 1/6 in (1/6, 1/2).
  static constexpr int kStages = 3;
  static constexpr double kGamma = 0.435866521508458999;
  static double coef(int i, int l) {
    constexpr double g = kGamma;
    constexpr double a21 = (1.0 - g) / 2.0;
    constexpr double b1 = -(6.0 * g * g - 16.0 * g + 1.0) / 4.0;
    constexpr double b2 = (6.0 * g * g - 20.0 * g + 5.0) / 4.0;
    if (i == 1) return a21;
    return l == 0 ? b1 : b2;
  }

  // One implicit step of length h. Stage i: positions Q = Qr + beta V,
  // velocities V from (M + beta C + beta^2 K) V = M Vr + beta F(Qr, 0), with
  // Qr = q_n + h sum_l a_il V_l and Vr = v_n + h sum_l a_il A_l (A_l the
  // stage accelerations, (V_l - Vr_l) / beta); the last stage is the step.
  void implicit_step(double h) {
    const double beta = kGamma * h;
    if (pattern_changed(beta)) build(beta);
    if (h != free_h_) free_propagator(h);
    // Free columns (the face does not press them): linear with constant
    // coefficients, stepped exactly by the exponential (see free_propagator).
    {
      const T* P = free_phi_;
      for (int j : free_) {
        const T a = z1_[j], b = z2_[j], c = v1_[j], d = v2_[j];
        z1_[j] = P[0] * a + P[1] * b + P[2] * c + P[3] * d;
        z2_[j] = P[4] * a + P[5] * b + P[6] * c + P[7] * d;
        v1_[j] = P[8] * a + P[9] * b + P[10] * c + P[11] * d;
        v2_[j] = P[12] * a + P[13] * b + P[14] * c + P[15] * d;
      }
    }
    const T zn = zc_, txn = tx_, tyn = ty_, vn = vc_, wxn = wx_, wyn = wy_;
    T iv[kStages][3], ia[kStages][3];  // impactor stage velocities / accelerations
    for (int i = 0; i < kStages; ++i) {
      const bool last = i + 1 == kStages;
      double c[kStages] = {0.0, 0.0, 0.0};
      for (int l = 0; l < i; ++l) c[l] = h * coef(i, l);
      // Impactor's Qr, Vr.
      T qy[3] = {zn, txn, tyn}, wy[3] = {vn, wxn, wyn};
      for (int l = 0; l < i; ++l)
        for (int r = 0; r < 3; ++r) {
          qy[r] += c[l] * iv[l][r];
          wy[r] += c[l] * ia[l][r];
        }
      auto node_r = [&](int j, T& q1, T& q2, T& w1, T& w2) {
        q1 = z1_[j];
        q2 = z2_[j];
        w1 = v1_[j];
        w2 = v2_[j];
        for (int l = 0; l < i; ++l) {
          q1 += c[l] * sv1_[l][j];
          q2 += c[l] * sv2_[l][j];
          w1 += c[l] * sa1s_[l][j];
          w2 += c[l] * sa2s_[l][j];
        }
      };
      // Columns the face presses: eliminated onto the impactor.
      T ry[3] = {T(M_) * wy[0] + beta * T(M_ * g_), T(L_.inertia_x) * wy[1], T(L_.inertia_y) * wy[2]};
      for (int j : coupled_) {
        T q1, q2, w1, w2;
        node_r(j, q1, q2, w1, w2);
        q1r_[j] = q1;
        q2r_[j] = q2;
        w1r_[j] = w1;
        w2r_[j] = w2;
        const T f12 = k2n_ * (q1 - q2);
        const T fc = k1v_[j] * (qy[0] + qy[1] * L_.lx[j] + qy[2] * L_.ly[j] - q1);
        const T r1 = m1n_ * w1 + beta * (fc - f12);
        const T r2 = m2n_ * w2 + beta * (f12 - k3n_ * q2);
        p1_[j] = g1_[j] * r1 + g12_[j] * r2;
        p2_[j] = g12_[j] * r1 + g2_[j] * r2;
        const T back = acol_[j] * p1_[j] - beta * fc;
        ry[0] += back;
        ry[1] += back * L_.lx[j];
        ry[2] += back * L_.ly[j];
      }
      T y[3];
      for (int r = 0; r < 3; ++r) y[r] = s_inv_(r, 0) * ry[0] + s_inv_(r, 1) * ry[1] + s_inv_(r, 2) * ry[2];
      for (int r = 0; r < 3; ++r) {
        iv[i][r] = y[r];
        ia[i][r] = (y[r] - wy[r]) / beta;
      }
      const double bi = i == 0 ? coef(2, 0) : (i == 1 ? coef(2, 1) : kGamma);
      for (int j : coupled_) {
        const T u = y[0] + y[1] * L_.lx[j] + y[2] * L_.ly[j];
        {  // element 1's force at the stage, into the step's impulse
          const T V1 = p1_[j] + sa1_[j] * u;
          const T d = qy[0] + qy[1] * L_.lx[j] + qy[2] * L_.ly[j] + beta * u - (q1r_[j] + beta * V1);
          const T f = k1v_[j] * d + c1v_[j] * (u - V1);
          impulse_[j] = i == 0 ? bi * f : impulse_[j] + bi * f;
        }
        finish(i, last, j, beta, q1r_[j], q2r_[j], w1r_[j], w2r_[j], p1_[j] + sa1_[j] * u, p2_[j] + sa2_[j] * u);
      }
      if (last) {
        zc_ = qy[0] + beta * y[0];
        tx_ = qy[1] + beta * y[1];
        ty_ = qy[2] + beta * y[2];
        vc_ = y[0];
        wx_ = y[1];
        wy_ = y[2];
      }
    }
  }

  // The exact step of a free column over h: x(t + h) = exp(J h) x(t) for
  // x = (z1, z2, v1, v2) under elements 2 and 3 alone. Computed with the
  // velocities scaled by h (entries of order one), by scaling and squaring
  // with a degree-14 Taylor polynomial (remainder below 1e-15 at norm 1/2).
  void free_propagator(double h) {
    T B[16];
    for (T& x : B) x = T(0.0);
    B[0 * 4 + 2] = T(1.0);
    B[1 * 4 + 3] = T(1.0);
    const T a2 = (h * h) * k2n_, c2 = h * r2n_, a3 = (h * h) * k3n_, c3 = h * r3n_;
    B[2 * 4 + 0] = -a2 / m1n_;
    B[2 * 4 + 1] = a2 / m1n_;
    B[2 * 4 + 2] = -c2 / m1n_;
    B[2 * 4 + 3] = c2 / m1n_;
    B[3 * 4 + 0] = a2 / m2n_;
    B[3 * 4 + 1] = -(a2 + a3) / m2n_;
    B[3 * 4 + 2] = c2 / m2n_;
    B[3 * 4 + 3] = -(c2 + c3) / m2n_;
    double norm = 0.0;
    for (int r = 0; r < 4; ++r) {
      double row = 0.0;
      for (int c = 0; c < 4; ++c) row += std::abs(detail::scalar_of(B[4 * r + c]));
      norm = std::max(norm, row);
    }
    const int sq = norm > 0.5 ? static_cast<int>(std::ceil(std::log2(norm / 0.5))) : 0;
    const double scale = std::ldexp(1.0, -sq);
    for (T& x : B) x *= scale;
    auto mul = [](const T* X, const T* Y, T* Z) {
      for (int r = 0; r < 4; ++r)
        for (int c = 0; c < 4; ++c) Z[4 * r + c] = X[4 * r] * Y[c] + X[4 * r + 1] * Y[4 + c] +
                                               X[4 * r + 2] * Y[8 + c] + X[4 * r + 3] * Y[12 + c];
    };
    // Horner: E = I + X (I + X/2 (I + X/3 (... (I + X/14))))
    T E[16], tmp[16];
    for (int k = 0; k < 16; ++k) E[k] = T(k % 5 == 0 ? 1.0 : 0.0);
    for (int k = 14; k >= 1; --k) {
      mul(B, E, tmp);
      for (int q = 0; q < 16; ++q) E[q] = tmp[q] * (1.0 / k) + (q % 5 == 0 ? 1.0 : 0.0);
    }
    for (int k = 0; k < sq; ++k) {
      mul(E, E, tmp);
      for (int q = 0; q < 16; ++q) E[q] = tmp[q];
    }
    // Back to physical velocities: v = w / h.
    for (int r = 0; r < 4; ++r)
      for (int c = 0; c < 4; ++c) {
        double f = 1.0;
        if (r < 2 && c >= 2) f = h;
        if (r >= 2 && c < 2) f = 1.0 / h;
        free_phi_[4 * r + c] = E[4 * r + c] * f;
      }
    free_h_ = h;
  }

  void finish(int i, bool last, int j, double beta, const T& q1, const T& q2, const T& w1, const T& w2, const T& V1,
              const T& V2) {
    if (last) {
      z1_[j] = q1 + beta * V1;
      z2_[j] = q2 + beta * V2;
      v1_[j] = V1;
      v2_[j] = V2;
      return;
    }
    sv1_[i][j] = V1;
    sv2_[i][j] = V2;
    sa1s_[i][j] = (V1 - w1) / beta;
    sa2s_[i][j] = (V2 - w2) / beta;
  }

  const Layout& L_;
  Model5ParamsT<T> p_;
  double M_, g_;
  T k2n_, r2n_, k3n_, r3n_, m1n_, m2n_, r_ext_;
  double s1_, s2_, c1_, c2_;
  std::vector<T> z1_, z2_, v1_, v2_, top_, d_, dd_, fr_, b1_, b2_;
  std::vector<T> impulse_;  // contact impulse / h of the last step, per cell
  std::vector<char> in_, was_, unload_, cached_in_, cached_unload_;
  std::vector<T> g1_, g12_, g2_, sa1_, sa2_, acol_, q1r_, q2r_, w1r_, w2r_, p1_, p2_, k1v_, c1v_, ab1_, ab2_;
  std::vector<T> sv1_[kStages - 1], sv2_[kStages - 1], sa1s_[kStages - 1], sa2s_[kStages - 1];
  std::vector<int> coupled_, free_;
  T fg1_ = T(0.0), fg12_ = T(0.0), fg2_ = T(0.0);
  T free_phi_[16];
  double free_h_ = -1.0;
  double pending_ = 0.0;  // kick owed to the velocities (half the last step)
  std::vector<T> ab1s_, ab2s_;
  double pending_s_ = 0.0;
  mutable std::vector<T> scratch_;
  static constexpr int kMaxRedo = 3;
  std::vector<T> z1s_, z2s_, v1s_, v2s_, top0_;
  T imp_s_[6];
  double relax_h_ = -1.0;
  T relax_ = T(0.0);
  Small3<T> s_inv_;
  T b2_coef_ = T(0.0);
  double cached_beta_ = -1.0;
  T zc_, tx_, ty_, vc_, wx_, wy_;
};

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
  for (int i = 0; i < n_samples; ++i) {
    if (i > 0) {
      const double t0 = imp.first_output_s + (i - 1) * imp.output_dt_s;
      const int refine = i == 1 ? kStartRefine : 1;
      const int n = L.n_sub * refine;
      const double h = L.step_s / refine;
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
