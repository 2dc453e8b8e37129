// The generator's own mat physics (see physics.h). Nothing here comes from
// fitting/: the equations are written out below from the models' figures,
// the integrator is Dormand-Prince 5(4) written here.
#include "samples/generator/physics.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>

#include "core/error.h"

namespace dropfit::synth {

// ---- Dormand-Prince 5(4) --------------------------------------------------------

OdeState OdeStep::at(double t) const {
  const double h = t1 - t0;
  if (h <= 0.0) return y1;
  const double s = std::clamp((t - t0) / h, 0.0, 1.0);
  const double s2 = s * s, s3 = s2 * s;
  const double h00 = 2 * s3 - 3 * s2 + 1, h10 = s3 - 2 * s2 + s, h01 = -2 * s3 + 3 * s2, h11 = s3 - s2;
  return h00 * y0 + h10 * h * f0 + h01 * y1 + h11 * h * f1;
}

DormandPrince::DormandPrince(OdeRhs f, double t0, const OdeState& y0, const OdeOptions& options)
    : f_(std::move(f)), o_(options) {
  restart(t0, y0);
}

void DormandPrince::restart(double t, const OdeState& y) {
  t_ = t;
  y_ = y;
  f0_ = f_(t_, y_);
  ++n_rhs_;
  h_ = std::min(o_.h_initial_s, o_.h_max_s);
}

OdeStep DormandPrince::step(double t_stop) {
  static constexpr double c2 = 1.0 / 5, c3 = 3.0 / 10, c4 = 4.0 / 5, c5 = 8.0 / 9;
  static constexpr double a21 = 1.0 / 5;
  static constexpr double a31 = 3.0 / 40, a32 = 9.0 / 40;
  static constexpr double a41 = 44.0 / 45, a42 = -56.0 / 15, a43 = 32.0 / 9;
  static constexpr double a51 = 19372.0 / 6561, a52 = -25360.0 / 2187, a53 = 64448.0 / 6561, a54 = -212.0 / 729;
  static constexpr double a61 = 9017.0 / 3168, a62 = -355.0 / 33, a63 = 46732.0 / 5247, a64 = 49.0 / 176,
                          a65 = -5103.0 / 18656;
  static constexpr double b1 = 35.0 / 384, b3 = 500.0 / 1113, b4 = 125.0 / 192, b5 = -2187.0 / 6784,
                          b6 = 11.0 / 84;
  static constexpr double e1 = 71.0 / 57600, e3 = -71.0 / 16695, e4 = 71.0 / 1920, e5 = -17253.0 / 339200,
                          e6 = 22.0 / 525, e7 = -1.0 / 40;
  if (!(t_stop > t_)) throw Error("DormandPrince::step: t_stop must lie ahead");
  for (int attempt = 0; attempt < 200; ++attempt) {
    double h = std::min({h_, o_.h_max_s, t_stop - t_});
    const bool last = h >= t_stop - t_;
    const OdeState& k1 = f0_;
    const OdeState k2 = f_(t_ + c2 * h, y_ + h * a21 * k1);
    const OdeState k3 = f_(t_ + c3 * h, y_ + h * (a31 * k1 + a32 * k2));
    const OdeState k4 = f_(t_ + c4 * h, y_ + h * (a41 * k1 + a42 * k2 + a43 * k3));
    const OdeState k5 = f_(t_ + c5 * h, y_ + h * (a51 * k1 + a52 * k2 + a53 * k3 + a54 * k4));
    const OdeState k6 = f_(t_ + h, y_ + h * (a61 * k1 + a62 * k2 + a63 * k3 + a64 * k4 + a65 * k5));
    const double t1 = last ? t_stop : t_ + h;
    const OdeState y1 = y_ + h * (b1 * k1 + b3 * k3 + b4 * k4 + b5 * k5 + b6 * k6);
    const OdeState k7 = f_(t1, y1);
    n_rhs_ += 6;
    const OdeState err = h * (e1 * k1 + e3 * k3 + e4 * k4 + e5 * k5 + e6 * k6 + e7 * k7);
    const OdeState scale = (o_.atol + o_.rtol * y_.cwiseAbs().cwiseMax(y1.cwiseAbs()).array()).matrix();
    const double norm = std::sqrt((err.cwiseQuotient(scale)).squaredNorm() / static_cast<double>(err.size()));
    if (!std::isfinite(norm)) {
      h_ = 0.2 * h;
      if (h_ < 1e-15) throw Error("DormandPrince: the solution is not finite");
      continue;
    }
    const double factor = std::clamp(0.9 * std::pow(std::max(norm, 1e-12), -0.2), 0.2, 5.0);
    if (norm <= 1.0) {
      OdeStep s{t_, t1, y_, y1, f0_, k7};
      t_ = t1;
      y_ = y1;
      f0_ = k7;
      h_ = std::max(h * factor, 1e-14);
      return s;
    }
    h_ = h * std::max(factor, 0.2);
    if (h_ < 1e-14) throw Error("DormandPrince: step size underflow");
  }
  throw Error("DormandPrince: no acceptable step in 200 attempts");
}

// ---- The mat ------------------------------------------------------------------

double element1_force_n(const MatParams& p, double d, double dd, double fm) {
  const double elastic = p.k1_n_m * d + p.k1_cubic_n_m3 * d * d * d;
  const double h = p.k1_hysteresis != 0.0
                       ? 1.0 - p.k1_hysteresis * (1.0 - std::tanh(dd / p.hysteresis_transition_m_s)) / 2.0
                       : 1.0;
  const double r = (dd < 0.0 && p.r1_unload_n_s_m >= 0.0) ? p.r1_unload_n_s_m : p.r1_n_s_m;
  return elastic * h + r * dd + fm;
}

namespace {

enum { X0 = 0, V0, X1, V1, X2, V2, FM, S };
enum class Mode { Contact, Free, Held };

struct Chain {
  ModelKind model;
  MatParams p;
  double M, g;
  bool elastic() const { return model == ModelKind::Model1 || model == ModelKind::Model4; }
  double top_mass() const { return model == ModelKind::Model2 ? p.m_eff_kg : p.m1_kg; }
  bool maxwell() const { return p.maxwell_k_n_m > 0.0 && p.maxwell_tau_s > 0.0; }

  // Element 1's rate d' at which its force vanishes (the free top).
  double free_rate(double d, double fm) const {
    const double target = -(p.k1_n_m * d + p.k1_cubic_n_m3 * d * d * d) - fm;  // r(d') d' must equal this
    const double r_load = p.r1_n_s_m, r_unload = p.r1_unload_n_s_m >= 0.0 ? p.r1_unload_n_s_m : p.r1_n_s_m;
    if (p.k1_hysteresis == 0.0) {
      if (target >= 0.0) return r_load > 0.0 ? target / r_load : 0.0;
      return r_unload > 0.0 ? target / r_unload : 0.0;
    }
    // F1 grows with d' (for d >= 0): Newton's method kept inside a bracket
    // (bisection when a Newton step would leave it).
    auto f = [&](double dd) { return element1_force_n(p, d, dd, fm); };
    const double elastic = p.k1_n_m * d + p.k1_cubic_n_m3 * d * d * d, vt = p.hysteresis_transition_m_s;
    double lo = -1.0, hi = 1.0;
    for (int i = 0; i < 60 && f(lo) > 0.0; ++i) lo *= 2.0;
    for (int i = 0; i < 60 && f(hi) < 0.0; ++i) hi *= 2.0;
    if (f(lo) > 0.0 || f(hi) < 0.0) return 0.0;
    double x = std::clamp(target / std::max(r_load, 1e-9), lo, hi);
    for (int i = 0; i < 100; ++i) {
      const double fx = f(x);
      if (fx > 0.0) hi = x; else lo = x;
      const double sech = 1.0 / std::cosh(x / vt);
      const double slope = elastic * p.k1_hysteresis * sech * sech / (2.0 * vt) + (x < 0.0 ? r_unload : r_load);
      double next = slope > 0.0 ? x - fx / slope : 0.5 * (lo + hi);
      if (!(next > lo && next < hi)) next = 0.5 * (lo + hi);
      if (std::abs(next - x) <= 1e-14 * (1.0 + std::abs(x)) || hi - lo <= 1e-14 * (1.0 + std::abs(x))) return next;
      x = next;
    }
    return x;
  }

  struct Eval {
    OdeState dy = OdeState::Zero();
    double contact = 0.0, grf = 0.0, surface = 0.0;
  };

  Eval eval(Mode mode, const OdeState& y) const {
    Eval e;
    OdeState& dy = e.dy;
    const double fm = maxwell() ? y(FM) : 0.0;
    // Impactor when not in contact.
    if (mode == Mode::Free) {
      dy(X0) = y(V0);
      dy(V0) = g;
    }
    if (elastic()) {
      const bool m4 = model == ModelKind::Model4;
      const double xb = m4 ? y(X1) : 0.0, vb = m4 ? y(V1) : 0.0;
      double f1 = 0.0, dd = 0.0;
      if (mode == Mode::Contact) {
        dd = y(V0) - vb;
        f1 = element1_force_n(p, y(X0) - xb, dd, fm);
        dy(X0) = y(V0);
        dy(V0) = g - f1 / M;
        dy(S) = y(V0);
        e.contact = f1;
        e.surface = y(X0);
      } else {
        dd = free_rate(y(S) - xb, fm);
        dy(S) = vb + dd;
        e.surface = y(S);
      }
      if (maxwell()) dy(FM) = p.maxwell_k_n_m * dd - y(FM) / p.maxwell_tau_s;
      if (m4) {
        const double f2 = p.k2_n_m * (y(X1) - y(X2)) + p.r2_n_s_m * (y(V1) - y(V2));
        const double f3 = p.k3_n_m * y(X2) + p.r3_n_s_m * y(V2);
        dy(X1) = y(V1);
        dy(V1) = (f1 - f2) / p.m1_kg;
        dy(X2) = y(V2);
        dy(V2) = (f2 - f3) / p.m2_kg;
        e.grf = f3;
      } else {
        e.grf = f1;
      }
    } else {
      const bool m3 = model == ModelKind::Model3;
      const double xb = m3 ? y(X2) : 0.0, vb = m3 ? y(V2) : 0.0;
      const double dd = y(V1) - vb;
      const double f1 = element1_force_n(p, y(X1) - xb, dd, fm);
      const double mt = top_mass();
      dy(X1) = y(V1);
      if (mode == Mode::Contact) {
        const double a = (M * g - f1) / (M + mt);
        dy(X0) = y(V0);
        dy(V0) = a;
        dy(V1) = a;
        e.contact = M * (g - a);
      } else {
        dy(V1) = -f1 / mt;
      }
      if (maxwell()) dy(FM) = p.maxwell_k_n_m * dd - y(FM) / p.maxwell_tau_s;
      if (m3) {
        const double f2 = p.k2_n_m * y(X2) + p.r2_n_s_m * y(V2);
        dy(X2) = y(V2);
        dy(V2) = (f1 - f2) / p.m2_kg;
        e.grf = f2;
      } else {
        e.grf = f1;
      }
      e.surface = y(X1);
      dy(S) = dy(X1);
    }
    return e;
  }
};

void check_params(ModelKind model, const MatParams& p) {
  auto nonneg = [](double v, const char* name) {
    if (!(std::isfinite(v) && v >= 0.0)) throw Error(fmt::format("generator physics: {} = {} must be >= 0", name, v));
  };
  auto pos = [](double v, const char* name) {
    if (!(std::isfinite(v) && v > 0.0)) throw Error(fmt::format("generator physics: {} = {} must be > 0", name, v));
  };
  if (model == ModelKind::Model5)
    throw Error("generator physics: Model 5 (area-elastic) is not generated; use Models 1-4");
  const int n = static_cast<int>(model);
  if (n < 1 || n > 5) throw Error(fmt::format("generator physics: no model {}", n));
  nonneg(p.k1_n_m, "k1_n_m");
  nonneg(p.r1_n_s_m, "r1_n_s_m");
  if (model == ModelKind::Model2) pos(p.m_eff_kg, "m_eff_kg");
  if (model == ModelKind::Model3 || model == ModelKind::Model4) {
    pos(p.m1_kg, "m1_kg");
    pos(p.m2_kg, "m2_kg");
    nonneg(p.k2_n_m, "k2_n_m");
    nonneg(p.r2_n_s_m, "r2_n_s_m");
  }
  if (model == ModelKind::Model4) {
    nonneg(p.k3_n_m, "k3_n_m");
    nonneg(p.r3_n_s_m, "r3_n_s_m");
  }
  if (!(p.k1_hysteresis >= 0.0 && p.k1_hysteresis < 1.0))
    throw Error(fmt::format("generator physics: hysteresis h = {} must lie in [0, 1)", p.k1_hysteresis));
  if (p.k1_hysteresis != 0.0) pos(p.hysteresis_transition_m_s, "hysteresis_transition_m_s");
  nonneg(p.maxwell_k_n_m, "maxwell_k_n_m");
  if (p.maxwell_k_n_m > 0.0) pos(p.maxwell_tau_s, "maxwell_tau_s");
}

// Illinois (modified regula falsi) root of g on [a, b], g(a) > 0 >= g(b).
template <class G>
double locate(G g, double a, double ga, double b, double gb) {
  int side = 0;
  for (int i = 0; i < 200 && b - a > 1e-13; ++i) {
    const double c = (a * gb - b * ga) / (gb - ga);
    const double gc = g(c);
    if (gc > 0.0) {
      a = c, ga = gc;
      if (side == -1) gb *= 0.5;
      side = -1;
    } else {
      b = c, gb = gc;
      if (side == 1) ga *= 0.5;
      side = 1;
    }
  }
  return b;  // the first instant at or after the crossing
}

}  // namespace

// Steps per simulated second beyond which simulate_chain gives up: ten
// times what the generator's stiffest sessions take (docs/blind-test.md).
constexpr double kMaxStepsPerSecond = 5e4;

ChainSimulation simulate_chain(ModelChoice choice, const MatParams& params, const ChainImpact& im) {
  const ModelKind model = choice.kind();
  check_params(model, params);
  if (!(im.mass_kg > 0.0 && im.gravity_m_s2 >= 0.0 && im.duration_s > 0.0 && im.output_dt_s > 0.0 &&
        std::isfinite(im.velocity_m_s)))
    throw Error("generator physics: impactor mass, duration and output step must be positive");
  const Chain chain{model, params, im.mass_kg, im.gravity_m_s2};
  const double M = im.mass_kg;
  const long n = static_cast<long>(std::floor(im.duration_s / im.output_dt_s + 1e-9)) + 1;

  ChainSimulation out;
  for (Eigen::VectorXd* v : {&out.t_s, &out.grf_n, &out.contact_n, &out.impactor_m, &out.impactor_v_m_s, &out.surface_m,
                             &out.layer1_m, &out.layer2_m, &out.layer1_v_m_s, &out.layer2_v_m_s, &out.maxwell_n})
    v->setZero(n);

  OdeState y = OdeState::Zero();
  y(V0) = im.velocity_m_s;
  if (!chain.elastic()) {  // a plastic collision with the top mass at first contact
    y(V0) = M * im.velocity_m_s / (M + chain.top_mass());
    y(V1) = y(V0);
  }
  Mode mode = Mode::Contact;
  out.n_contacts = 1;

  auto record = [&](long i, const OdeState& s) {
    const Chain::Eval e = chain.eval(mode, s);
    out.t_s(i) = static_cast<double>(i) * im.output_dt_s;
    out.grf_n(i) = e.grf;
    out.contact_n(i) = e.contact;
    out.impactor_m(i) = s(X0);
    out.impactor_v_m_s(i) = s(V0);
    out.surface_m(i) = e.surface;
    if (model != ModelKind::Model1) {
      out.layer1_m(i) = s(X1);
      out.layer1_v_m_s(i) = s(V1);
    }
    if (model == ModelKind::Model3 || model == ModelKind::Model4) {
      out.layer2_m(i) = s(X2);
      out.layer2_v_m_s(i) = s(V2);
    }
    out.maxwell_n(i) = chain.maxwell() ? s(FM) : 0.0;
  };

  // Event functions of the current mode: a crossing from > 0 to <= 0 fires.
  // 0: separation (contact force), 1: landing again (gap), 2: apex (-v0).
  auto events = [&](const OdeState& s) -> Eigen::Vector3d {
    const double inf = std::numeric_limits<double>::infinity();
    Eigen::Vector3d ev(inf, inf, inf);
    if (mode == Mode::Contact) ev(0) = chain.eval(mode, s).contact;
    if (mode == Mode::Free) {
      ev(1) = (chain.elastic() ? s(S) : s(X1)) - s(X0);
      if (im.catch_at_apex) ev(2) = -s(V0);
    }
    return ev;
  };

  DormandPrince ode([&](double, const OdeState& s) { return chain.eval(mode, s).dy; }, 0.0, y, im.ode);
  const double t_end = static_cast<double>(n - 1) * im.output_dt_s;
  long next = 0;
  record(next++, y);
  int n_events = 0;
  double last_event_t = -1.0;
  // A chain whose modes outrun the explicit integrator (a massless free
  // surface relaxing through a near-zero damping, say) takes steps of tens
  // of nanoseconds: a budget of steps per second simulated turns what would
  // be hours into an error that names it.
  const double step_budget = kMaxStepsPerSecond * std::max(t_end, 1.0);
  long steps = 0;
  while (next < n) {
    const OdeStep st = ode.step(t_end);
    if (++steps > step_budget)
      throw Error(fmt::format("generator physics: the chain is too stiff for its explicit integrator ({} steps by "
                              "t = {:.4f} s, the last {:.2g} s long): draw another mat or effect",
                              steps, st.t1, st.t1 - st.t0));
    const Eigen::Vector3d g0 = events(st.y0), g1 = events(st.y1);
    int which = -1;
    double t_event = st.t1;
    for (int k = 0; k < 3; ++k) {
      if (!(g0(k) > 0.0 && g1(k) <= 0.0) || !std::isfinite(g0(k))) continue;
      const double tk = locate([&](double t) { return events(st.at(t))(k); }, st.t0, g0(k), st.t1, g1(k));
      if (tk <= t_event) {
        t_event = tk;
        which = k;
      }
    }
    while (next < n && static_cast<double>(next) * im.output_dt_s <= t_event)
      record(next, st.at(static_cast<double>(next) * im.output_dt_s)), ++next;
    if (which < 0) continue;
    if (++n_events > 10000 || (t_event - last_event_t) < 1e-12)
      throw Error("generator physics: contact events do not settle (chattering contact)");
    last_event_t = t_event;
    OdeState ye = st.at(t_event);
    if (which == 0) {
      mode = Mode::Free;
      if (std::isnan(out.separation_s)) out.separation_s = t_event;
      if (chain.elastic()) ye(S) = ye(X0);
    } else if (which == 1) {
      mode = Mode::Contact;
      ++out.n_contacts;
      if (chain.elastic()) {
        ye(S) = ye(X0);
      } else {  // plastic collision with the top mass
        const double mt = chain.top_mass();
        const double v = (M * ye(V0) + mt * ye(V1)) / (M + mt);
        ye(V0) = ye(V1) = v;
        ye(X1) = ye(X0);
      }
    } else {
      mode = Mode::Held;
      ye(V0) = 0.0;
      out.caught_s = t_event;
    }
    ode.restart(t_event, ye);
  }
  out.n_rhs = ode.n_rhs();
  return out;
}

}  // namespace dropfit::synth
