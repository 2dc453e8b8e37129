// Co-simulation of Models 1-4 (fitting/cosim.h). State scaled to the step:
// time tau = t / dt in [0, 1], velocities w = v dt, so the scaled dynamics
// dZ/dtau = B Z + by y(tau) + bw y'(tau) have entries of order one.
// Forced response (Van Loan): with p = (1, tau, tau^2/2, tau^3/6), p' = N p,
// the augmented matrix [[B, b e4^T], [0, N]] has, in the top-right block of
// its exponential over L, column k = integral_0^L e^{B (L - s)} b s^(3-k)/(3-k)! ds,
// the response to the forcing b tau^(3-k)/(3-k)!.
#include "fitting/cosim.h"

#include <fmt/format.h>

#include <cmath>

#include "core/error.h"
#include "fitting/models_impl.h"

namespace dropfit::fitting {
namespace {

using Mat8 = Eigen::Matrix<double, 8, 8>;

// Hermite cubic of the foot travel over the step, in tau: y = sum c_m tau^m.
void hermite(double y0, double w0, double y1, double w1, double c[4]) {
  c[0] = y0;
  c[1] = w0;
  c[2] = 3.0 * (y1 - y0) - 2.0 * w0 - w1;
  c[3] = 2.0 * (y0 - y1) + w0 + w1;
}
double poly_value(const double c[4], double s) { return c[0] + s * (c[1] + s * (c[2] + s * c[3])); }
double poly_rate(const double c[4], double s) { return c[1] + s * (2.0 * c[2] + s * 3.0 * c[3]); }

}  // namespace

MatContact::MatContact(ModelKind kind, const MatParams& p) : kind_(kind) {
  if (kind == ModelKind::Model5) throw Error("co-simulation is for Models 1-4, not model5");
  if (p.has_effects()) throw Error("co-simulation supports the linear models only (no cubic, hysteresis or Maxwell term)");
  const double ks[3] = {p.k1_n_m, p.k2_n_m, p.k3_n_m}, rs[3] = {p.r1_n_s_m, p.r2_n_s_m, p.r3_n_s_m};
  const detail::Layout L = detail::layout_for(kind, kind == ModelKind::Model2 && p.m_eff_kg == 0.0);
  rigid_top_ = L.rigid_top;
  n_mass_ = L.n_mass;
  n_elem_ = L.n_elem;
  // Model 2's element 1 is (k1, r1); Model 3's elements are (k1, r1), (k2, r2).
  for (int j = 0; j < n_elem_; ++j) {
    upper_[j] = L.upper[j];
    lower_[j] = L.lower[j];
    k_[j] = ks[j];
    r_[j] = rs[j];
    if (!(k_[j] >= 0.0) || !(r_[j] >= 0.0) || !std::isfinite(k_[j]) || !std::isfinite(r_[j]))
      throw Error(fmt::format("co-simulation: element {} needs finite stiffness and damping >= 0", j + 1));
  }
  m_[1] = kind == ModelKind::Model2 ? p.m_eff_kg : p.m1_kg;
  m_[2] = p.m2_kg;
  for (int n = 1; n <= n_mass_; ++n)
    if (!(m_[n] > 0.0) || !std::isfinite(m_[n]))
      throw Error(fmt::format("co-simulation: {} needs layer mass {} > 0", model_name(kind), n));
}

void MatContact::build(bool contact, Mat4& b, Vec4& by, Vec4& bw) const {
  b.setZero();
  by.setZero();
  bw.setZero();
  const double dt = dt_;
  // Node roles: 0 = the foot; 1, 2 = mat masses, index 2 (n - 1) in the
  // state; -1 = ground. In rigid-top contact node 1 moves with the foot.
  auto is_input = [&](int n) { return n == 0 || (n == 1 && rigid_top_ && contact); };
  auto is_dynamic = [&](int n) { return n >= 1 && n <= n_mass_ && !is_input(n); };
  for (int n = 1; n <= n_mass_; ++n)
    if (is_dynamic(n)) b(2 * (n - 1), 2 * (n - 1) + 1) = 1.0;
  for (int j = 0; j < n_elem_; ++j) {
    if (j == 0 && !rigid_top_ && !contact) continue;  // free massless element carries nothing
    const int a = upper_[j], lo = lower_[j];
    // f = k (x_a - x_lo) + r (v_a - v_lo) pushes a up (-f) and lo down (+f).
    const int nodes[2] = {a, lo};
    const double on_node[2] = {-1.0, 1.0}, in_f[2] = {1.0, -1.0};
    for (int d = 0; d < 2; ++d) {
      if (!is_dynamic(nodes[d])) continue;
      const int row = 2 * (nodes[d] - 1) + 1;
      const double kk = on_node[d] * k_[j] * dt * dt / m_[nodes[d]], rr = on_node[d] * r_[j] * dt / m_[nodes[d]];
      for (int q = 0; q < 2; ++q) {
        const int n = nodes[q];
        if (n < 0) continue;
        if (is_input(n)) {
          by(row) += in_f[q] * kk;
          bw(row) += in_f[q] * rr;
        } else if (is_dynamic(n)) {
          b(row, 2 * (n - 1)) += in_f[q] * kk;
          b(row, 2 * (n - 1) + 1) += in_f[q] * rr;
        }
      }
    }
  }
}

MatContact::Propagator MatContact::make(bool contact, double fraction) const {
  Mat4 b;
  Vec4 by, bw;
  build(contact, b, by, bw);
  Propagator out;
  const Vec4* forcing[2] = {&by, &bw};
  Mat4* resp[2] = {&out.ry, &out.rv};
  for (int i = 0; i < 2; ++i) {
    Mat8 a = Mat8::Zero();
    a.topLeftCorner<4, 4>() = b;
    a.block<4, 1>(0, 7) = *forcing[i];
    for (int k = 1; k < 4; ++k) a(4 + k, 4 + k - 1) = 1.0;
    const Mat8 e = detail::expm<double, 8>(Mat8(a * fraction));
    out.phi = e.topLeftCorner<4, 4>();
    double fact = 1.0;
    for (int m = 0; m < 4; ++m) {
      if (m > 0) fact *= m;
      resp[i]->col(m) = fact * e.block<4, 1>(0, 4 + 3 - m);
    }
  }
  return out;
}

void MatContact::set_dt(double dt_s) {
  if (dt_ > 0.0 && std::abs(dt_s - dt_) <= 1e-12 * dt_) return;
  dt_ = dt_s;
  full_[0] = make(false, 1.0);
  full_[1] = make(true, 1.0);
}

// Scaled state z from s0 to s1 (fractions of the step) in one phase, the
// foot travel being the step's polynomial `poly`.
MatContact::Vec4 MatContact::propagate(bool contact, const Vec4& z, const double poly[4], double s0, double s1) const {
  const double len = s1 - s0;
  if (len <= 0.0) return z;
  const bool whole = s0 == 0.0 && s1 == 1.0;
  const Propagator local = whole ? Propagator{} : make(contact, len);
  const Propagator& pr = whole ? full_[contact ? 1 : 0] : local;
  Vec4 out = pr.phi * z;
  if (!contact) return out;
  // The polynomial re-expanded about s0: c'_m = sum_j C(j, m) c_j s0^(j - m).
  double c[4];
  for (int m = 0; m < 4; ++m) {
    c[m] = 0.0;
    for (int j = m; j < 4; ++j) {
      double binom = 1.0;
      for (int i = 0; i < m; ++i) binom = binom * (j - i) / (i + 1);
      c[m] += binom * poly[j] * std::pow(s0, j - m);
    }
  }
  for (int m = 0; m < 4; ++m) {
    out += c[m] * pr.ry.col(m);
    if (m > 0) out += m * c[m] * pr.rv.col(m - 1);
  }
  return out;
}

double MatContact::element1_force(const Vec4& z, double y, double w) const {
  const int base = lower_[0];
  const double xb = base >= 1 ? z(2 * (base - 1)) : 0.0, wb = base >= 1 ? z(2 * (base - 1) + 1) : 0.0;
  return k_[0] * (y - xb) + r_[0] * (w - wb) / dt_;
}

double MatContact::relax_factor(double fraction) const {
  if (k_[0] == 0.0) return 1.0;
  if (r_[0] == 0.0) return 0.0;
  return std::exp(-k_[0] / r_[0] * fraction * dt_);
}

double MatContact::surface_m() const {
  if (contact_) return rigid_top_ ? x_[0] : y_prev_;
  if (rigid_top_) return x_[0];
  return (lower_[0] >= 1 ? x_[0] : 0.0) + e_;
}

void MatContact::reset(double y, double v) {
  if (!std::isfinite(y) || !std::isfinite(v)) throw Error("co-simulation: foot state must be finite");
  x_.setZero();
  e_ = 0.0;
  started_ = true;
  y_prev_ = y;
  v_prev_ = v;
  contact_ = false;
  if (y < 0.0 || (y == 0.0 && v <= 0.0)) return;
  if (rigid_top_) {
    contact_ = true;  // lands now: the top mass takes the foot's state
    x_[0] = y;
    x_[1] = v;
  } else {
    contact_ = k_[0] * y + r_[0] * v > 0.0;
    if (!contact_) e_ = y;
  }
}

ContactForces MatContact::step(double y1, double v1, double dt_s) {
  if (!std::isfinite(y1) || !std::isfinite(v1)) throw Error("co-simulation: foot state must be finite");
  if (!(dt_s > 0.0) || !std::isfinite(dt_s)) throw Error("co-simulation: dt_s must be > 0");
  if (!started_) reset(y1 - v1 * dt_s, v1);
  set_dt(dt_s);
  const double dt = dt_s;
  const double y0 = y_prev_, v0 = v_prev_;
  double poly[4];
  hermite(y0, v0 * dt, y1, v1 * dt, poly);
  Vec4 z = x_;
  z(1) *= dt;
  z(3) *= dt;
  double impulse = 0.0;  // rigid top: collision impulse this step (N s)
  bool landed = false;
  const int base = lower_[0];
  auto base_of = [&](const Vec4& s) { return base >= 1 ? s(2 * (base - 1)) : 0.0; };

  if (contact_ && !rigid_top_) {
    Vec4 z1 = propagate(true, z, poly, 0.0, 1.0);
    const double f1 = element1_force(z1, y1, v1 * dt);
    if (f1 < 0.0) {
      // Separation inside the step: regula falsi on element 1's force.
      double sa = 0.0, fa = element1_force(z, y0, v0 * dt), sb = 1.0, fb = f1;
      double s = 1.0;
      Vec4 zs = z1;
      if (fa <= 0.0) {
        s = 0.0;
        zs = z;
      } else {
        for (int it = 0; it < 6; ++it) {
          s = sa + (sb - sa) * fa / (fa - fb);
          zs = propagate(true, z, poly, 0.0, s);
          const double fs = element1_force(zs, poly_value(poly, s), poly_rate(poly, s));
          if (std::abs(fs) <= 1e-9 * (std::abs(fa) + std::abs(fb))) break;
          if (fs > 0.0) {
            sa = s;
            fa = fs;
          } else {
            sb = s;
            fb = fs;
          }
        }
      }
      contact_ = false;
      e_ = poly_value(poly, s) - base_of(zs);
      z = propagate(false, zs, poly, s, 1.0);
      e_ *= relax_factor(1.0 - s);
    } else {
      z = z1;
    }
  } else if (contact_) {
    z = propagate(true, z, poly, 0.0, 1.0);
    z(0) = y1;
    z(1) = v1 * dt;
  } else {
    const Vec4 z1 = propagate(false, z, poly, 0.0, 1.0);
    const double e1 = e_ * relax_factor(1.0);
    if (rigid_top_) {
      if (y1 >= z1(0)) {  // plastic collision at the step's end
        impulse = m_[1] * (v1 - z1(1) / dt);
        landed = true;
        contact_ = true;
        z = z1;
        z(0) = y1;
        z(1) = v1 * dt;
      } else {
        z = z1;
      }
    } else {
      const double gap0 = y0 - (base_of(z) + e_), gap1 = y1 - (base_of(z1) + e1);
      if (gap1 >= 0.0) {
        const double s = gap0 < 0.0 ? gap0 / (gap0 - gap1) : 0.0;
        const Vec4 zs = propagate(false, z, poly, 0.0, s);
        z = propagate(true, zs, poly, s, 1.0);
        e_ = 0.0;
        contact_ = true;
        if (element1_force(z, y1, v1 * dt) <= 0.0) {  // touched, but the foot withdraws faster
          contact_ = false;
          e_ = y1 - base_of(z);
        }
      } else {
        z = z1;
        e_ = e1;
      }
    }
  }

  x_ = z;
  x_(1) /= dt;
  x_(3) /= dt;
  y_prev_ = y1;
  v_prev_ = v1;

  ContactForces out;
  // Node values at the step's end.
  auto pos = [&](int n) { return n == 0 || (n == 1 && rigid_top_ && contact_) ? y1 : (n < 0 ? 0.0 : x_(2 * (n - 1))); };
  auto vel = [&](int n) { return n == 0 || (n == 1 && rigid_top_ && contact_) ? v1 : (n < 0 ? 0.0 : x_(2 * (n - 1) + 1)); };
  auto elem = [&](int j) {
    return k_[j] * (pos(upper_[j]) - pos(lower_[j])) + r_[j] * (vel(upper_[j]) - vel(lower_[j]));
  };
  const int last = n_elem_ - 1;
  if (!rigid_top_) {
    const double f1 = contact_ ? std::max(elem(0), 0.0) : 0.0;
    out.foot_n = f1;
    out.grf_n = last == 0 ? f1 : elem(last);
  } else {
    out.grf_n = elem(last);
    if (contact_) {
      const double inertia = landed ? 0.0 : m_[1] * (v1 - v0) / dt;
      const double foot = inertia + elem(0) + impulse / dt;
      if (foot < 0.0 && !landed) {
        contact_ = false;  // the top mass leaves the foot with the foot's state
      } else {
        out.foot_n = std::max(foot, 0.0);
      }
    }
  }
  out.contact = contact_;
  return out;
}

}  // namespace dropfit::fitting
