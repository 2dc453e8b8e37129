#pragma once
// Model 5's integrator, templated on the scalar type (double, or Dual for
// a ceres::Jet): the split into an implicit stiff part and explicit shear
// kicks is described in fitting/model5_impl.h.
#include <algorithm>
#include <cmath>
#include <type_traits>
#include <utility>
#include <vector>

#include "fitting/model5_dual.h"
#include "fitting/model5_layout.h"

namespace dropfit::fitting::model5_detail {

// The integrator's state is structure-of-arrays over the cells (flat index
// j = ix * ny + iy) in two buffers: the state at the step's start (z1_,
// z2_, v1_, v2_ and the last kick's accelerations ab1_, ab2_) and the work
// buffer a step writes (the *w_ vectors). A step that is accepted swaps
// them (pointer swaps); a step redone for its contact set simply starts
// again from the untouched start state, so nothing is copied per step.
// Every cell's arithmetic is the same expression, in the same order, as the
// scalar scheme's (the double path's results are bitwise those of the
// per-cell loops this replaced); the loops run over contiguous cells with
// no per-cell branch, so the compiler vectorises them.
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
    im1_ = T(1.0) / m1n_;
    im2_ = T(1.0) / m2n_;
    s1_ = g.shear1_n_m;
    s2_ = g.shear2_n_m;
    c1_ = g.shear_damping1_n_s_m;
    c2_ = g.shear_damping2_n_s_m;
    r_ext_ = p.hysteresis ? p.r1_unload_n_s_m : p.r1_n_s_m;
    for (auto* v : {&z1_, &z2_, &v1_, &v2_, &ab1_, &ab2_, &z1w_, &z2w_, &v1w_, &v2w_, &ab1w_, &ab2w_, &g1_, &g2_,
                    &top_, &top0_, &d_, &dd_, &k1v_})
      v->assign(n, T(0.0));
    in_.assign(n, 0);
    was_.assign(n, 0);
    unload_.assign(n, 0);
    cached_in_.assign(n, 2);
    cached_unload_.assign(n, 2);
    const int nf = static_cast<int>(L.face.size());  // pressed cells are face cells
    cj_.reserve(nf);
    free_runs_.reserve(2 * nf + 2);
    for (auto* v : {&cg1_, &cg12_, &cg2_, &csa1_, &csa2_, &cacol_, &ck1v_, &cc1v_, &cz1_, &cz2_, &cv1_,
                    &cv2_, &q1r_, &q2r_, &w1r_, &w2r_, &uq_, &p1_, &p2_, &back_, &impulse_})
      v->assign(nf, T(0.0));
    clx_.assign(nf, 0.0);
    cly_.assign(nf, 0.0);
    for (int l = 0; l + 1 < kStages; ++l)
      for (auto* v : {&sv1_[l], &sv2_[l], &sa1s_[l], &sa2s_[l]}) v->assign(nf, T(0.0));
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
    // Members to locals: the stores below could alias them for the compiler.
    const T zc = zc_, tx = tx_, ty = ty_, vc = vc_, wx = wx_, wy = wy_;
    const T r1 = p_.r1_n_s_m, r1u = p_.r1_unload_n_s_m, kc = p_.k1_cubic_n_m3;
    const bool hysteresis = p_.hysteresis, cubic = p_.cubic;
    const double* __restrict lx = L_.lx.data();
    const double* __restrict ly = L_.ly.data();
    const double* __restrict w = L_.w.data();
    const T* __restrict z1 = z1_.data();
    const T* __restrict v1 = v1_.data();
    const T* __restrict k1v = k1v_.data();
    const T* __restrict top = top_.data();
    T* __restrict dv = d_.data();
    T* __restrict ddv = dd_.data();
    char* __restrict in = in_.data();
    char* __restrict was = was_.data();
    char* __restrict unload = unload_.data();
    T total = T(0.0);
    for (int j : L_.face) {
      const T u = zc + tx * lx[j] + ty * ly[j];
      const T ud = vc + wx * lx[j] + wy * ly[j];
      const T d = u - z1[j];
      const T dd = ud - v1[j];
      dv[j] = d;
      ddv[j] = dd;
      const bool un = hysteresis && detail::scalar_of(dd) < 0.0;
      unload[j] = un;
      T f = k1v[j] * d + (un ? r1u : r1) * w[j] * dd;
      if (cubic) f += kc * w[j] * d * d * d;
      was[j] = in[j];
      // Pressed while it was, or once the face reaches the element's top;
      // released by step() when its impulse pulls.
      const bool pressed = in[j] || detail::scalar_of(d) >= detail::scalar_of(top[j]);
      in[j] = pressed;
      if (pressed && detail::scalar_of(f) > 0.0) total += f;
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
      bool redo = false;
      if (may_redo) {
        // coupled cells (cj_) are the pressed ones the step was built for
        for (int k = 0; k < nc_; ++k) {
          if (detail::scalar_of(impulse_[k]) < 0.0) {
            in_[cj_[k]] = 0;
            redo = true;
          }
        }
      }
      if (!redo) break;
      restore();
    }
    commit();
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

  // Whether the face stays clear of the mat for the next span_s: no cell
  // pressed, and every face cell's gap to element 1's top (top - D, D from
  // the last contact()) wider than twice its closing over the span plus
  // kClearance_m (for the accelerations: 1 mm over 1 ms is 2000 m/s^2).
  bool clear_of_contact(double span_s) const {
    for (int j : L_.face) {
      if (in_[j]) return false;
      const double d = detail::scalar_of(d_[j]), closing = std::max(detail::scalar_of(dd_[j]), 0.0);
      if (d + 2.0 * closing * span_s + kClearance_m >= detail::scalar_of(top_[j])) return false;
    }
    return true;
  }
  static constexpr double kClearance_m = 1e-3;
  // Cells the face presses (from the last contact()).
  int pressed_count() const {
    int c = 0;
    for (int j : L_.face) c += in_[j] ? 1 : 0;
    return c;
  }

  // Applies the half kick the last step still owes (before reading velocities).
  void sync() {
    kick(pending_, false);
    pending_ = 0.0;
  }

 private:
  // One step of length h with the current contact set, from the start state
  // into the work buffers: element tops relax, half kick, implicit step,
  // half kick (owed to the next step or sync()).
  void advance(double h) {
    if (h != relax_h_) {
      relax_h_ = h;
      using std::exp;
      relax_ = detail::scalar_of(r_ext_) > 0.0 ? T(exp(-(T(h) / r_ext_) * p_.k1_n_m)) : T(0.0);
    }
    const T relax = relax_;
    const bool cubic_relax = p_.cubic && detail::scalar_of(r_ext_) > 0.0;
    for (int j : L_.face) {
      if (in_[j] || was_[j]) top_[j] = detail::scalar_of(d_[j]) > 0.0 ? d_[j] : T(0.0);
      if (cubic_relax) {
        using std::exp;
        top_[j] *= exp(-(T(h) / r_ext_) * (p_.k1_n_m + p_.k1_cubic_n_m3 * top_[j] * top_[j]));
      } else {
        top_[j] *= relax;
      }
    }
    kick(pending_ + 0.5 * h, true);
    implicit_step(h);
    pending_ = 0.5 * h;
  }

  // The step's start state: the work buffers hold the step, the start
  // state is untouched; only the element tops, the owed kick and the
  // impactor (a few scalars) change in place.
  void save() {
    for (int j : L_.face) top0_[j] = top_[j];
    pending_s_ = pending_;
    imp_s_[0] = zc_, imp_s_[1] = tx_, imp_s_[2] = ty_, imp_s_[3] = vc_, imp_s_[4] = wx_, imp_s_[5] = wy_;
  }
  void restore() {
    for (int j : L_.face) top_[j] = top0_[j];
    pending_ = pending_s_;
    zc_ = imp_s_[0], tx_ = imp_s_[1], ty_ = imp_s_[2], vc_ = imp_s_[3], wx_ = imp_s_[4], wy_ = imp_s_[5];
  }
  // The work buffers become the state.
  void commit() {
    z1_.swap(z1w_);
    z2_.swap(z2w_);
    v1_.swap(v1w_);
    v2_.swap(v2w_);
    ab1_.swap(ab1w_);
    ab2_.swap(ab2w_);
  }

  // Shear (and cubic) accelerations as a kick of length tau, positions
  // held. The shear damping uses the velocity estimate half-way through the
  // kick from the previous kick's acceleration (one stencil pass per kick;
  // the same second-order device as the explicit scheme's). into_work:
  // from the start state into the work buffers (a step), else in place on
  // the state (sync()).
  void kick(double tau, bool into_work) {
    // (The positions need no copy: implicit_step writes every cell's.)
    if (into_work && tau == 0.0) {
      std::copy(v1_.begin(), v1_.end(), v1w_.begin());
      std::copy(v2_.begin(), v2_.end(), v2w_.begin());
      std::copy(ab1_.begin(), ab1_.end(), ab1w_.begin());
      std::copy(ab2_.begin(), ab2_.end(), ab2w_.begin());
      return;
    }
    if (tau == 0.0) return;
    // The shear damping, explicit here, would cap the step at about
    // 1 / (its fastest rate); sub-kicks of at most 0.8 of that keep it
    // stable at any step (positions are held during the kick, so the shear
    // stiffness alone bounds the step: see make_layout).
    const int m = std::max(1, static_cast<int>(std::ceil(L_.shear_gamma * tau / 0.8 - 1e-9)));
    for (int k = 0; k < m; ++k) {
      if (into_work && k == 0) {
        kick_once(tau / m, v1_.data(), v2_.data(), ab1_.data(), ab2_.data(), v1w_.data(), v2w_.data(), ab1w_.data(),
                  ab2w_.data());
      } else if (into_work) {
        kick_once(tau / m, v1w_.data(), v2w_.data(), ab1w_.data(), ab2w_.data(), v1w_.data(), v2w_.data(),
                  ab1w_.data(), ab2w_.data());
      } else {
        kick_once(tau / m, v1_.data(), v2_.data(), ab1_.data(), ab2_.data(), v1_.data(), v2_.data(), ab1_.data(),
                  ab2_.data());
      }
    }
  }

  // Shear accelerations of one layer from its link forces g (stiffness and
  // damping per cell), gathered per cell: the frame link, then the links
  // along x (towards -x, then +x), then along y (-y, +y); the same sums in
  // the same order as the scatter over the links this replaced. Cells
  // [j0, j1) all have (HasL) or lack a -x neighbour, likewise +x (HasR).
  template <bool HasL, bool HasR>
  void shear_x(int j0, int j1, const T* __restrict g, T* __restrict a) const {
    const int ny = L_.ny;
    const double fx = L_.dy / L_.dx;
    const double* __restrict fw = L_.frame_w.data();
    for (int j = j0; j < j1; ++j) {
      T s = -fw[j] * g[j];
      if constexpr (HasL) s -= fx * (g[j] - g[j - ny]);
      if constexpr (HasR) s += fx * (g[j + ny] - g[j]);
      a[j] = s;
    }
  }
  void shear(const T* __restrict g, T* __restrict a) const {
    const int n = L_.n, nx = L_.nx, ny = L_.ny;
    if (nx == 1) {
      shear_x<false, false>(0, n, g, a);
    } else {
      shear_x<false, true>(0, ny, g, a);
      shear_x<true, true>(ny, n - ny, g, a);
      shear_x<true, false>(n - ny, n, g, a);
    }
    if (ny == 1) return;
    const double fy = L_.dx / L_.dy;
    for (int o = 0; o < n; o += ny) {
      T* __restrict ac = a + o;
      const T* __restrict gc = g + o;
      ac[0] += fy * (gc[1] - gc[0]);
      for (int iy = 1; iy + 1 < ny; ++iy) {
        T s = ac[iy];
        s -= fy * (gc[iy] - gc[iy - 1]);
        s += fy * (gc[iy + 1] - gc[iy]);
        ac[iy] = s;
      }
      ac[ny - 1] -= fy * (gc[ny - 1] - gc[ny - 2]);
    }
  }

  // The cell loops as functions of restrict pointers and values (so the
  // compiler knows nothing aliases and vectorises them).
  // A layer's link force per cell: shear stiffness on the travel, damping on
  // the velocity half-way through the kick (from the last kick's acceleration).
  static void link_forces_damped(int n, double s, double c, double half, const T* __restrict z,
                                 const T* __restrict v, const T* __restrict ab, T* __restrict g) {
    for (int j = 0; j < n; ++j) g[j] = s * z[j] + c * (v[j] + half * ab[j]);
  }
  static void link_forces(int n, double s, const T* __restrict z, T* __restrict g) {
    for (int j = 0; j < n; ++j) g[j] = s * z[j];
  }
  // Accelerations from the link forces (a, scaled by 1 / m in place) and
  // the kicked velocities vo = v + tau a (vo may be v).
  static void accelerate(int n, double tau, T im, const T* v, T* __restrict a, T* vo) {
    for (int j = 0; j < n; ++j) {
      a[j] *= im;
      vo[j] = v[j] + tau * a[j];
    }
  }
  // The free columns' exact step on cells [j0, j1): positions from (za, zb),
  // velocities in place in (v1, v2).
  struct Phi {
    T p[16];
  };
  static void free_step(int j0, int j1, const Phi phi, const T* __restrict za, const T* __restrict zb,
                        T* __restrict z1, T* __restrict z2, T* __restrict v1, T* __restrict v2) {
    const T* P = phi.p;
    for (int j = j0; j < j1; ++j) {
      const T a = za[j], b = zb[j], c = v1[j], d = v2[j];
      z1[j] = P[0] * a + P[1] * b + P[2] * c + P[3] * d;
      z2[j] = P[4] * a + P[5] * b + P[6] * c + P[7] * d;
      v1[j] = P[8] * a + P[9] * b + P[10] * c + P[11] * d;
      v2[j] = P[12] * a + P[13] * b + P[14] * c + P[15] * d;
    }
  }

  // One kick of length tau: velocities and accelerations from (v, ab) into
  // (vo, abo) (the same arrays for an in-place kick), positions the state's.
  void kick_once(double tau, const T* v1, const T* v2, const T* ab1, const T* ab2, T* vo1, T* vo2, T* abo1, T* abo2) {
    const bool damped = c1_ > 0.0 || c2_ > 0.0;
    const int n = L_.n;
    if (damped) {
      link_forces_damped(n, s1_, c1_, 0.5 * tau, z1_.data(), v1, ab1, g1_.data());
      link_forces_damped(n, s2_, c2_, 0.5 * tau, z2_.data(), v2, ab2, g2_.data());
    } else {
      link_forces(n, s1_, z1_.data(), g1_.data());
      link_forces(n, s2_, z2_.data(), g2_.data());
    }
    // g is complete before any acceleration is written: (v, ab) may be (vo, abo).
    shear(g1_.data(), abo1);
    shear(g2_.data(), abo2);
    accelerate(n, tau, im1_, v1, abo1, vo1);
    accelerate(n, tau, im2_, v2, abo2, vo2);
    if (p_.cubic) {
      T fz = T(0.0), fx = T(0.0), fy = T(0.0);
      for (int j : L_.face) {
        if (!in_[j]) continue;
        const T d = zc_ + tx_ * L_.lx[j] + ty_ * L_.ly[j] - z1_[j];
        const T f = p_.k1_cubic_n_m3 * L_.w[j] * d * d * d;
        vo1[j] += tau * f * im1_;
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
  // current contact set and unloading pattern; beta = h gamma. The pressed
  // (coupled) columns' constants are packed (index k, cell cj_[k]); the
  // free ones are listed as runs of consecutive cells.
  void build(double beta) {
    const T b2 = beta * r2n_ + (beta * beta) * k2n_;
    const T b3 = beta * r3n_ + (beta * beta) * k3n_;
    Small3<T> S;
    for (T& x : S.m) x = T(0.0);
    S(0, 0) = T(M_);
    S(1, 1) = T(L_.inertia_x);
    S(2, 2) = T(L_.inertia_y);
    cj_.clear();
    free_runs_.clear();
    for (int j = 0; j < L_.n; ++j) {
      if (!in_[j]) {
        if (!free_runs_.empty() && free_runs_.back().second == j) {
          ++free_runs_.back().second;
        } else {
          free_runs_.emplace_back(j, j + 1);
        }
        continue;
      }
      const int k = static_cast<int>(cj_.size());
      cj_.push_back(j);
      const T c1 = (unload_[j] ? p_.r1_unload_n_s_m : p_.r1_n_s_m) * L_.w[j];
      const T a = beta * c1 + (beta * beta) * k1v_[j];
      const T a11 = m1n_ + a + b2, a22 = m2n_ + b2 + b3;
      const T inv_det = T(1.0) / (a11 * a22 - b2 * b2);
      cg1_[k] = a22 * inv_det;
      cg12_[k] = b2 * inv_det;
      cg2_[k] = a11 * inv_det;
      cacol_[k] = a;
      csa1_[k] = a * cg1_[k];
      csa2_[k] = a * cg12_[k];
      ck1v_[k] = k1v_[j];
      cc1v_[k] = c1;
      clx_[k] = L_.lx[j];
      cly_[k] = L_.ly[j];
      const double e[3] = {1.0, L_.lx[j], L_.ly[j]};
      const T c = a * (T(1.0) - csa1_[k]);
      for (int r = 0; r < 3; ++r)
        for (int q = 0; q < 3; ++q) S(r, q) += c * (e[r] * e[q]);
    }
    nc_ = static_cast<int>(cj_.size());
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

  // One implicit step of length h, from the start state's positions and the
  // kicked velocities in the work buffers into the work buffers. Stage i:
  // positions Q = Qr + beta V, velocities V from (M + beta C + beta^2 K) V =
  // M Vr + beta F(Qr, 0), with Qr = q_n + h sum_l a_il V_l and Vr = v_n + h
  // sum_l a_il A_l (A_l the stage accelerations, (V_l - Vr_l) / beta); the
  // last stage is the step.
  void implicit_step(double h) {
    const double beta = kGamma * h;
    if (pattern_changed(beta)) build(beta);
    // A propagator per step length in use is kept (run alternates up to
    // three: creep-limited, free, slow-load): each is computed once.
    int slot = 0;
    while (slot < kPhiSlots && free_h_[slot] != h) ++slot;
    if (slot == kPhiSlots) {
      slot = next_slot_;
      next_slot_ = (next_slot_ + 1) % kPhiSlots;
      free_propagator(h, slot);
    }
    const T* free_phi = free_phi_[slot];
    const int nc = nc_;
    // The pressed columns' start state, packed, before the free columns'
    // exact step overwrites the work buffers.
    for (int k = 0; k < nc; ++k) {
      const int j = cj_[k];
      cz1_[k] = z1_[j];
      cz2_[k] = z2_[j];
      cv1_[k] = v1w_[j];
      cv2_[k] = v2w_[j];
    }
    // Free columns (the face does not press them): linear with constant
    // coefficients, stepped exactly by the exponential (see free_propagator).
    {
      Phi phi;
      std::copy(free_phi, free_phi + 16, phi.p);
      if constexpr (std::is_same_v<T, double>) {
        // One long vectorised loop over every cell beats short runs between
        // the pressed ones; the last stage overwrites the pressed cells.
        free_step(0, L_.n, phi, z1_.data(), z2_.data(), z1w_.data(), z2w_.data(), v1w_.data(), v2w_.data());
      } else {
        for (const auto& run : free_runs_)
          free_step(run.first, run.second, phi, z1_.data(), z2_.data(), z1w_.data(), z2w_.data(), v1w_.data(),
                    v2w_.data());
      }
    }
    const T start[6] = {zc_, tx_, ty_, vc_, wx_, wy_};  // the impactor's q_n, v_n
    T iv[kStages][3], ia[kStages][3];  // impactor stage velocities / accelerations
    stage<0>(h, beta, start, iv, ia);
    stage<1>(h, beta, start, iv, ia);
    stage<2>(h, beta, start, iv, ia);
  }

  // A pressed column's stage values from the impactor's (y0 heave, y1, y2
  // tilt rates): its layers' velocities V1, V2 and element 1's force f
  // (the middle stages and the last share it).
  __attribute__((always_inline)) static inline void column_values(
      int k, double beta, const T& y0, const T& y1, const T& y2, const double* __restrict lx,
      const double* __restrict ly, const T* __restrict p1, const T* __restrict p2, const T* __restrict sa1,
      const T* __restrict sa2, const T* __restrict uq, const T* __restrict q1r, const T* __restrict k1v,
      const T* __restrict c1v, T& V1, T& V2, T& f) {
    const T u = y0 + y1 * lx[k] + y2 * ly[k];
    V1 = p1[k] + sa1[k] * u;
    V2 = p2[k] + sa2[k] * u;
    const T d = uq[k] + beta * u - (q1r[k] + beta * V1);
    f = k1v[k] * d + c1v[k] * (u - V1);
  }

  // The pressed columns' part of stage I before the impactor's solve:
  // their Qr, Vr, the 2 x 2 elimination and the back-substitution term
  // (restrict arguments, as the kernels above).
  template <int I>
  static void stage_columns(int nc, double c0, double c1, T qy0, T qy1, T qy2, double beta, T k2n, T k3n, T m1n,
                            T m2n, const T* __restrict cz1, const T* __restrict cz2, const T* __restrict cv1,
                            const T* __restrict cv2, const T* __restrict sv1a, const T* __restrict sv2a,
                            const T* __restrict sa1a, const T* __restrict sa2a, const T* __restrict sv1b,
                            const T* __restrict sv2b, const T* __restrict sa1b, const T* __restrict sa2b,
                            const double* __restrict lx, const double* __restrict ly, const T* __restrict k1v,
                            const T* __restrict g1, const T* __restrict g12, const T* __restrict g2,
                            const T* __restrict acol, T* __restrict q1r, T* __restrict q2r, T* __restrict w1r,
                            T* __restrict w2r, T* __restrict uq, T* __restrict p1, T* __restrict p2,
                            T* __restrict back) {
    for (int k = 0; k < nc; ++k) {
      T q1 = cz1[k], q2 = cz2[k], w1 = cv1[k], w2 = cv2[k];
      if constexpr (I >= 1) {
        q1 += c0 * sv1a[k];
        q2 += c0 * sv2a[k];
        w1 += c0 * sa1a[k];
        w2 += c0 * sa2a[k];
      }
      if constexpr (I >= 2) {
        q1 += c1 * sv1b[k];
        q2 += c1 * sv2b[k];
        w1 += c1 * sa1b[k];
        w2 += c1 * sa2b[k];
      }
      q1r[k] = q1;
      q2r[k] = q2;
      w1r[k] = w1;
      w2r[k] = w2;
      const T u = qy0 + qy1 * lx[k] + qy2 * ly[k];
      uq[k] = u;
      const T f12 = k2n * (q1 - q2);
      const T fc = k1v[k] * (u - q1);
      const T r1 = m1n * w1 + beta * (fc - f12);
      const T r2 = m2n * w2 + beta * (f12 - k3n * q2);
      const T pp1 = g1[k] * r1 + g12[k] * r2;
      p1[k] = pp1;
      p2[k] = g12[k] * r1 + g2[k] * r2;
      back[k] = acol[k] * pp1 - beta * fc;
    }
  }
  // The pressed columns' stage velocities once the impactor's are known
  // (stages before the last): element 1's force into the step's impulse,
  // the stage values the next stages use.
  template <int I>
  static void stage_velocities(int nc, double bi, double beta, T y0, T y1, T y2, const double* __restrict lx,
                               const double* __restrict ly, const T* __restrict p1, const T* __restrict p2,
                               const T* __restrict sa1, const T* __restrict sa2, const T* __restrict uq,
                               const T* __restrict q1r, const T* __restrict w1r, const T* __restrict w2r,
                               const T* __restrict k1v, const T* __restrict c1v, T* __restrict imp,
                               T* __restrict sv1, T* __restrict sv2, T* __restrict sa1s, T* __restrict sa2s) {
    for (int k = 0; k < nc; ++k) {
      T V1, V2, f;
      column_values(k, beta, y0, y1, y2, lx, ly, p1, p2, sa1, sa2, uq, q1r, k1v, c1v, V1, V2, f);
      if constexpr (I == 0) {
        imp[k] = bi * f;
      } else {
        imp[k] = imp[k] + bi * f;
      }
      sv1[k] = V1;
      sv2[k] = V2;
      sa1s[k] = (V1 - w1r[k]) / beta;
      sa2s[k] = (V2 - w2r[k]) / beta;
    }
  }

  // Stage I of the implicit step for the impactor and the pressed columns
  // (a template: each stage's loops are straight-line, so they vectorise).
  template <int I>
  void stage(double h, double beta, const T (&start)[6], T (&iv)[kStages][3], T (&ia)[kStages][3]) {
    constexpr bool last = I + 1 == kStages;
    const int nc = nc_;
    double c[kStages] = {0.0, 0.0, 0.0};
    for (int l = 0; l < I; ++l) c[l] = h * coef(I, l);
    // Impactor's Qr, Vr.
    T qy[3] = {start[0], start[1], start[2]}, wy[3] = {start[3], start[4], start[5]};
    for (int l = 0; l < I; ++l)
      for (int r = 0; r < 3; ++r) {
        qy[r] += c[l] * iv[l][r];
        wy[r] += c[l] * ia[l][r];
      }
    T* __restrict q1r = q1r_.data();
    T* __restrict q2r = q2r_.data();
    T* __restrict w1r = w1r_.data();
    T* __restrict w2r = w2r_.data();
    T* __restrict uq = uq_.data();
    T* __restrict p1 = p1_.data();
    T* __restrict p2 = p2_.data();
    T* __restrict back = back_.data();
    T* __restrict imp = impulse_.data();
    const double* __restrict lx = clx_.data();
    const double* __restrict ly = cly_.data();
    const T* __restrict k1v = ck1v_.data();
    const T* __restrict c1v = cc1v_.data();
    const T* __restrict g1 = cg1_.data();
    const T* __restrict g12 = cg12_.data();
    const T* __restrict g2 = cg2_.data();
    const T* __restrict acol = cacol_.data();
    const T* __restrict sa1 = csa1_.data();
    const T* __restrict sa2 = csa2_.data();
    const T k2n = k2n_, k3n = k3n_, m1n = m1n_, m2n = m2n_;
    // Columns the face presses: eliminated onto the impactor. Each
    // column's back-substitution term first, then their sum in cell order.
    stage_columns<I>(nc, c[0], c[1], qy[0], qy[1], qy[2], beta, k2n, k3n, m1n, m2n, cz1_.data(), cz2_.data(),
                     cv1_.data(), cv2_.data(), sv1_[0].data(), sv2_[0].data(), sa1s_[0].data(), sa2s_[0].data(),
                     sv1_[1].data(), sv2_[1].data(), sa1s_[1].data(), sa2s_[1].data(), lx, ly, k1v, g1, g12, g2, acol,
                     q1r, q2r, w1r, w2r, uq, p1, p2, back);
    T ry[3] = {T(M_) * wy[0] + beta * T(M_ * g_), T(L_.inertia_x) * wy[1], T(L_.inertia_y) * wy[2]};
    for (int k = 0; k < nc; ++k) {
      ry[0] += back[k];
      ry[1] += back[k] * lx[k];
      ry[2] += back[k] * ly[k];
    }
    T y[3];
    for (int r = 0; r < 3; ++r) y[r] = s_inv_(r, 0) * ry[0] + s_inv_(r, 1) * ry[1] + s_inv_(r, 2) * ry[2];
    for (int r = 0; r < 3; ++r) {
      iv[I][r] = y[r];
      ia[I][r] = (y[r] - wy[r]) / beta;
    }
    const double bi = I == 0 ? coef(2, 0) : (I == 1 ? coef(2, 1) : kGamma);
    const T y0 = y[0], y1 = y[1], y2 = y[2];
    if constexpr (!last) {
      stage_velocities<I>(nc, bi, beta, y0, y1, y2, lx, ly, p1, p2, sa1, sa2, uq, q1r, w1r, w2r, k1v, c1v, imp,
                          sv1_[I].data(), sv2_[I].data(), sa1s_[I].data(), sa2s_[I].data());
    } else {
      T* __restrict z1 = z1w_.data();
      T* __restrict z2 = z2w_.data();
      T* __restrict v1 = v1w_.data();
      T* __restrict v2 = v2w_.data();
      const int* __restrict cj = cj_.data();
      for (int k = 0; k < nc; ++k) {
        T V1, V2, f;
        column_values(k, beta, y0, y1, y2, lx, ly, p1, p2, sa1, sa2, uq, q1r, k1v, c1v, V1, V2, f);
        imp[k] = imp[k] + bi * f;
        const int j = cj[k];
        z1[j] = q1r[k] + beta * V1;
        z2[j] = q2r[k] + beta * V2;
        v1[j] = V1;
        v2[j] = V2;
      }
      zc_ = qy[0] + beta * y[0];
      tx_ = qy[1] + beta * y[1];
      ty_ = qy[2] + beta * y[2];
      vc_ = y[0];
      wx_ = y[1];
      wy_ = y[2];
    }
  }

  // The exact step of a free column over h: x(t + h) = exp(J h) x(t) for
  // x = (z1, z2, v1, v2) under elements 2 and 3 alone. Computed with the
  // velocities scaled by h (entries of order one), by scaling and squaring
  // with a degree-14 Taylor polynomial (remainder below 1e-15 at norm 1/2).
  void free_propagator(double h, int slot) {
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
        free_phi_[slot][4 * r + c] = E[4 * r + c] * f;
      }
    free_h_[slot] = h;
  }

  const Layout& L_;
  Model5ParamsT<T> p_;
  double M_, g_;
  T k2n_, r2n_, k3n_, r3n_, m1n_, m2n_, im1_, im2_, r_ext_;
  double s1_, s2_, c1_, c2_;
  // State at the step's start (per cell) and the work buffers a step writes.
  std::vector<T> z1_, z2_, v1_, v2_, ab1_, ab2_;
  std::vector<T> z1w_, z2w_, v1w_, v2w_, ab1w_, ab2w_;
  std::vector<T> g1_, g2_;  // the kick's link forces per cell
  std::vector<T> top_, top0_, d_, dd_, k1v_;
  std::vector<char> in_, was_, unload_, cached_in_, cached_unload_;
  // Pressed (coupled) columns, packed by k: cell cj_[k], the stage matrix's
  // column factors and constants, the start state, the stages' values.
  int nc_ = 0;
  std::vector<int> cj_;
  std::vector<std::pair<int, int>> free_runs_;  // [first, last) of consecutive free cells
  std::vector<T> cg1_, cg12_, cg2_, csa1_, csa2_, cacol_, ck1v_, cc1v_;
  std::vector<double> clx_, cly_;
  std::vector<T> cz1_, cz2_, cv1_, cv2_, q1r_, q2r_, w1r_, w2r_, uq_, p1_, p2_, back_;
  std::vector<T> impulse_;  // contact impulse / h of the last step, per coupled column
  std::vector<T> sv1_[kStages - 1], sv2_[kStages - 1], sa1s_[kStages - 1], sa2s_[kStages - 1];
  static constexpr int kPhiSlots = 3;
  T free_phi_[kPhiSlots][16];
  double free_h_[kPhiSlots] = {-1.0, -1.0, -1.0};
  int next_slot_ = 0;
  double pending_ = 0.0;  // kick owed to the velocities (half the last step)
  double pending_s_ = 0.0;
  mutable std::vector<T> scratch_;
  static constexpr int kMaxRedo = 3;
  T imp_s_[6];
  double relax_h_ = -1.0;
  T relax_ = T(0.0);
  Small3<T> s_inv_;
  double cached_beta_ = -1.0;
  T zc_, tx_, ty_, vc_, wx_, wy_;
};

}  // namespace dropfit::fitting::model5_detail
