// The generator's foam column (foam.h): its own law and explicit stepping.
#include "samples/generator/foam.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "core/error.h"

namespace dropfit::synth {

double foam_stress_pa(const FoamLayer& l, double e) {
  if (e <= 0.0) return l.modulus_pa * e;
  const double ed = l.densification_strain;
  const double x = std::min(e, 0.995 * ed);
  double s = l.plateau_pa * (1.0 - std::exp(-l.modulus_pa * e / l.plateau_pa)) + l.hardening_pa * e +
             l.densification_pa * (std::pow(ed / (ed - x), l.densification_exponent) - 1.0);
  if (e > x) s += 1e3 * l.densification_pa * (e - x) / (ed - x);  // a wall past the fully collapsed cells
  return s;
}

namespace {

void check_column(const FoamColumn& c, const ChainImpact& im) {
  for (const FoamLayer* l : {&c.top, &c.base}) {
    if (!(l->thickness_m > 0.0 && l->mass_kg > 0.0 && l->plateau_pa > 0.0 && l->modulus_pa > 0.0 &&
          l->hardening_pa >= 0.0 && l->densification_pa >= 0.0 && l->densification_strain > 0.0 &&
          l->densification_strain <= 1.0 && l->densification_exponent >= 1.0))
      throw Error("foam column: every layer needs a positive thickness, mass, plateau and modulus, e_d in (0, 1]");
  }
  if (c.n_top < 1 || c.n_base < 1 || !(c.area_m2 > 0.0) || c.g1 < 0.0 || c.g2 < 0.0 || !(c.tau1_s > 0.0) ||
      !(c.tau2_s > 0.0) || c.viscosity_pa_s < 0.0)
    throw Error("foam column: needs elements in both layers, a positive area and time constants");
  if (!(im.output_dt_s > 0.0 && im.duration_s > 0.0 && im.mass_kg > 0.0))
    throw Error("foam column: the impact needs a positive mass, output step and duration");
}

// The strain at which a layer carries stress s (its law increases).
double strain_at(const FoamLayer& l, double s) {
  double lo = 0.0, hi = l.densification_strain;
  for (int it = 0; it < 100; ++it) {
    const double mid = 0.5 * (lo + hi);
    (foam_stress_pa(l, mid) < s ? lo : hi) = mid;
  }
  return 0.5 * (lo + hi);
}

}  // namespace

ChainSimulation simulate_foam_column(const FoamColumn& c, const ChainImpact& im) {
  check_column(c, im);
  const int n = c.n_top + c.n_base;  // elements; free nodes 0..n-1, node n on the plate
  std::vector<const FoamLayer*> law(n);
  std::vector<double> h(n), m(n, 0.0), e0(n), s0(n);
  for (int j = 0; j < n; ++j) {
    const bool top = j < c.n_top;
    law[j] = top ? &c.top : &c.base;
    h[j] = top ? c.top.thickness_m / c.n_top : c.base.thickness_m / c.n_base;
    const double me = top ? c.top.mass_kg / c.n_top : c.base.mass_kg / c.n_base;
    m[j] += 0.5 * me;
    if (j + 1 < n) m[j + 1] += 0.5 * me;
  }
  double above = 0.0;
  for (int j = 0; j < n; ++j) {
    above += m[j] * im.gravity_m_s2;
    s0[j] = above / c.area_m2;
    e0[j] = strain_at(*law[j], s0[j]);
  }
  std::vector<double> u(n, 0.0), v(n, 0.0), q1(n, 0.0), q2(n, 0.0), se(s0), f(n, 0.0), sigma(n, 0.0);
  const double M = im.mass_kg, g = im.gravity_m_s2, A = c.area_m2;
  // The plastic collision at first contact.
  v[0] = M * im.velocity_m_s / (M + m[0]);
  bool contact = true, caught = false;
  double z = 0.0, vz = 0.0;

  const long n_out = static_cast<long>(std::floor(im.duration_s / im.output_dt_s + 1e-9)) + 1;
  ChainSimulation out;
  for (Eigen::VectorXd* x : {&out.t_s, &out.grf_n, &out.contact_n, &out.impactor_m, &out.impactor_v_m_s,
                             &out.surface_m, &out.layer1_m, &out.layer2_m, &out.layer1_v_m_s, &out.layer2_v_m_s,
                             &out.maxwell_n})
    x->setZero(n_out);
  out.n_contacts = 1;
  const int mid = c.n_top / 2, interface = c.n_top;
  const double fast_dt = 1e-6;
  const int fast_per = std::max(1, static_cast<int>(std::lround(im.output_dt_s / fast_dt)));
  const int slow_per = std::max(1, static_cast<int>(std::ceil(im.output_dt_s / 1e-5 - 1e-9)));
  double t = 0.0, contact_force = 0.0;
  std::vector<double> se_old(n);

  // Element stresses from the current travels and velocities; the net
  // force on every free node (gravity on the mat cancels the static strain).
  auto forces = [&]() {
    for (int j = 0; j < n; ++j) {
      const double ub = j + 1 < n ? u[j + 1] : 0.0, vb = j + 1 < n ? v[j + 1] : 0.0;
      const double e = e0[j] + (u[j] - ub) / h[j], edot = (v[j] - vb) / h[j];
      se[j] = foam_stress_pa(*law[j], e);
      sigma[j] = se[j] + q1[j] + q2[j] + c.viscosity_pa_s * edot;
    }
    for (int j = 0; j < n; ++j) f[j] = -A * (sigma[j] - s0[j]) + (j > 0 ? A * (sigma[j - 1] - s0[j - 1]) : 0.0);
  };
  auto record = [&](long i) {
    out.t_s[i] = static_cast<double>(i) * im.output_dt_s;
    out.grf_n[i] = A * (sigma[n - 1] - s0[n - 1]);
    out.contact_n[i] = contact ? contact_force : 0.0;
    out.impactor_m[i] = contact ? u[0] : z;
    out.impactor_v_m_s[i] = contact ? v[0] : vz;
    out.surface_m[i] = u[0];
    out.layer1_m[i] = u[mid];
    out.layer1_v_m_s[i] = v[mid];
    out.layer2_m[i] = u[interface];
    out.layer2_v_m_s[i] = v[interface];
  };
  forces();
  contact_force = M * g;
  record(0);
  for (long i = 1; i < n_out; ++i) {
    const bool slow = caught && t > out.caught_s + 0.05;
    const int per = slow ? slow_per : fast_per;
    const double dt = im.output_dt_s / per;
    for (int k = 0; k < per; ++k) {
      forces();
      // Node 0 carries the impactor while the contact pushes.
      std::vector<double>& a = f;  // accelerations, in place
      const double a0 = contact ? (f[0] + M * g) / (M + m[0]) : f[0] / m[0];
      if (contact) contact_force = M * (g - a0);
      for (int j = 1; j < n; ++j) a[j] = f[j] / m[j];
      a[0] = a0;
      if (contact && contact_force < 0.0) {
        contact = false;  // it would pull: the impactor leaves
        z = u[0];
        vz = v[0];
        if (!std::isfinite(out.separation_s)) out.separation_s = t;
        a[0] = f[0] / m[0];
      }
      for (int j = 0; j < n; ++j) {
        v[j] += dt * a[j];
        u[j] += dt * v[j];
      }
      // The memory, from the elastic stress change over the step.
      se_old = se;
      for (int j = 0; j < n; ++j) {
        const double ub = j + 1 < n ? u[j + 1] : 0.0;
        const double ds = foam_stress_pa(*law[j], e0[j] + (u[j] - ub) / h[j]) - se_old[j];
        q1[j] += c.g1 * ds - dt * q1[j] / c.tau1_s;
        q2[j] += c.g2 * ds - dt * q2[j] / c.tau2_s;
      }
      t += dt;
      if (!contact && !caught) {
        const double vz_old = vz;
        vz += dt * g;
        z += dt * vz;
        if (im.catch_at_apex && vz_old < 0.0 && vz >= 0.0) {
          caught = true;  // held at the top of its rebound
          out.caught_s = t;
          vz = 0.0;
        } else if (z >= u[0]) {
          contact = true;  // lands again: a plastic collision with node 0
          ++out.n_contacts;
          v[0] = (M * vz + m[0] * v[0]) / (M + m[0]);
          contact_force = M * g;
        }
      }
    }
    forces();
    record(i);
  }
  return out;
}

}  // namespace dropfit::synth
