// Identifiability beyond the linearised covariance (see detail/identify.h).
#include "fitting/detail/identify.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <limits>
#include <string>
#include <utility>

#include "core/error.h"
#include "fitting/detail/summary.h"
#include "fitting/detail/uncertainty.h"

namespace dropfit::fitting::internal {

namespace {

constexpr double kChi2One95 = 3.841459;  // chi-square, one degree of freedom, 95 %

// The other pair (top, bottom) of a two-mass chain with the same natural
// frequencies: top mass ma on spring xt over mass mb on spring xb to the
// ground, ma also held by a spring a. With T fixed, xb = A - B xt; the
// product D then fixes xt as a root of -B xt^2 + (a - a B + A) xt + ... = 0,
// whose two roots sum to (a - a B + A) / B.
bool conjugate_pair(double a, double xt, double xb, double ma, double mb, double* yt, double* yb) {
  if (!(ma > 0.0) || !(mb > 0.0)) return false;
  const double T = (a + xt) / ma + (xt + xb) / mb;
  const double B = mb / ma + 1.0;
  const double A = mb * T - mb * a / ma;
  *yt = (a - a * B + A) / B - xt;
  *yb = A - B * *yt;
  return std::isfinite(*yt) && std::isfinite(*yb);
}

int index_of(const ParamSpace& space, const std::string& name) {
  for (int j = 0; j < space.size(); ++j)
    if (space.free[j].name == name) return j;
  return -1;
}

// The residuals at u with the clock shifts held (not profiled).
Eigen::VectorXd residuals_held(const std::vector<Prepared>& preps, const ParamSpace& space, const FitOptions& o,
                               const Eigen::VectorXd& u, const std::vector<double>& shifts) {
  const MatParams mp = space.to_mat(u.data());
  Eigen::Index n = 0;
  for (const Prepared& p : preps) n += p.n_residuals();
  Eigen::VectorXd r(n);
  Eigen::Index off = 0;
  for (size_t q = 0; q < preps.size(); ++q) {
    const Prepared& p = preps[q];
    residuals_at(p, simulate_window(p, space, o, mp, nullptr), p.shifted() ? shifts[q] : 0.0, r.data() + off);
    off += p.n_residuals();
  }
  return r;
}

double cost_at(const std::vector<Prepared>& preps, const ParamSpace& space, const FitOptions& o,
               const Eigen::VectorXd& u, const std::vector<double>& shifts) {
  return 0.5 * residuals_held(preps, space, o, u, shifts).squaredNorm();
}

// The likelihood ratio of two optima under the noise as it is. Their cost
// difference is a statistic of the difference d of their fitted curves;
// with white unit noise 2 dC is chi-square distributed, with each block an
// AR(1) process (sigma_b, phi_b: the error budget's) the same statistic is
// 2 dC |d|^2 / d^T S d. The inputs' errors move both optima alike and do
// not enter.
double basin_statistic(const std::vector<Prepared>& preps, const ErrorBudget& budget, const Eigen::VectorXd& d,
                       double delta_cost) {
  double q = 0.0;
  Eigen::Index off = 0;
  size_t b = 0;
  for (const Prepared& p : preps) {
    const int counts[2] = {static_cast<int>(p.f_idx.size()), static_cast<int>(p.k_idx.size())};
    for (int c : counts) {
      const BlockNoise noise = b < budget.blocks.size() ? budget.blocks[b] : BlockNoise{1.0, 0.0};
      ++b;
      const auto seg = d.segment(off, c);
      double sum = seg.squaredNorm(), w = 1.0;
      for (int lag = 1; lag < c; ++lag) {
        w *= noise.phi;
        if (std::abs(w) < 1e-4) break;
        sum += 2.0 * w * seg.head(c - lag).dot(seg.tail(c - lag));
      }
      q += noise.sigma * noise.sigma * sum;
      off += c;
    }
  }
  return q > 0.0 ? 2.0 * delta_cost * d.squaredNorm() / q : std::numeric_limits<double>::infinity();
}

// The profile statistic of each free coordinate (detail/identify.h): the
// linear profile path B_:j / B_jj and the calibration B_jj / V_jj.
struct Profiler {
  const std::vector<Prepared>& preps;
  const ParamSpace& space;
  const FitOptions& o;
  const Optimum& best;
  std::atomic<long>* evals;
  Eigen::MatrixXd B;  // (J^T J)^-1 over the parameters and the fitted shifts
  Eigen::VectorXd calib;

  Profiler(const std::vector<Prepared>& pr, const ParamSpace& sp, const FitOptions& op, const Optimum& b,
           const ErrorBudget& budget, std::atomic<long>* ev)
      : preps(pr), space(sp), o(op), best(b), evals(ev) {
    const Eigen::Index m = b.jacobian.rows(), n = b.jacobian.cols();
    const double s2 = m > n ? b.residuals.squaredNorm() / static_cast<double>(m - n) : 0.0;
    B = s2 > 0.0 ? Eigen::MatrixXd(budget.white_covariance / s2) : Eigen::MatrixXd::Zero(n, n);
    calib = Eigen::VectorXd::Zero(n);
    for (Eigen::Index j = 0; j < n; ++j)
      if (budget.covariance(j, j) > 0.0 && !budget.lost[j]) calib[j] = B(j, j) / budget.covariance(j, j);
  }

  double statistic(int j, double cost) const { return 2.0 * (cost - best.cost) * calib[j]; }

  // The point delta from the optimum along coordinate j's linear profile
  // path (parameters within their bounds, shifts within theirs).
  std::pair<Eigen::VectorXd, std::vector<double>> on_path(int j, double delta) const {
    const int np = space.size();
    Eigen::VectorXd u = best.u + B.col(j).head(np) * (delta / B(j, j));
    for (int i = 0; i < np; ++i) u[i] = std::clamp(u[i], space.free[i].lower, space.free[i].upper);
    u[j] = best.u[j] + delta;
    std::vector<double> sh = best.shifts;
    for (size_t q = 0, b = 0; q < preps.size(); ++q) {
      if (!preps[q].shifted()) continue;
      sh[q] = std::clamp(sh[q] + B(np + b, j) * delta / B(j, j), preps[q].shift_lo_s, preps[q].shift_hi_s);
      ++b;
    }
    return {u, sh};
  }

  // The cost minimised with u_j held at best.u[j] + delta, from the
  // linear path's point.
  Optimum profile_point(int j, double delta) const {
    auto [u0, sh0] = on_path(j, delta);
    FitOptions oo = o;
    oo.max_iterations = 25;
    return run_ceres(preps, space, oo, u0, evals, false, &sh0, 0.0, j);
  }

  // Does the cost at the Wald end (on the linear path) depart from the
  // linear prediction?
  bool nonlinear_side(int j, double half, int dir) const {
    auto [u, sh] = on_path(j, dir * half);
    if (std::abs(u[j] - best.u[j]) < 0.999 * half) return true;  // a bound cuts the Wald interval
    const double w = statistic(j, cost_at(preps, space, o, u, sh));
    return !(std::abs(std::sqrt(std::max(w, 0.0) / kChi2One95) - 1.0) <= 0.1);
  }

  // The end of the 95 % set on one side: the distance (in u) where the
  // statistic reaches 3.84, found on sqrt(W), nearly linear in the
  // distance; the bound when the statistic stays below there.
  double end(int j, int dir, double guess, bool* at_bound) const {
    const FreeParam& f = space.free[j];
    const double room = dir > 0 ? f.upper - best.u[j] : best.u[j] - f.lower;
    *at_bound = room < 1e-6;
    if (*at_bound) return std::max(room, 0.0);
    double lo = 0.0, lo_r = 0.0, hi = std::numeric_limits<double>::infinity(), hi_r = 0.0;
    double d = std::min(guess, room);
    for (int it = 0; it < 4 && d > 0.0; ++it) {
      const Optimum p = profile_point(j, dir * d);
      const double r = std::sqrt(std::max(statistic(j, p.cost), 0.0) / kChi2One95);  // 1 at the end
      if (std::abs(r - 1.0) < 0.05) return d;
      if (r < 1.0) {
        lo = d, lo_r = r;
        if (d >= room) {
          *at_bound = true;
          return room;
        }
      } else {
        hi = d, hi_r = r;
      }
      double next = r > 1e-6 ? d / r : 2.0 * d;  // sqrt(W) proportional to the distance
      if (std::isfinite(hi) && lo > 0.0) next = lo + (hi - lo) * (1.0 - lo_r) / (hi_r - lo_r);
      if (!(next > lo && next < hi)) next = std::isfinite(hi) ? 0.5 * (lo + hi) : std::min(2.0 * d, room);
      d = std::min(next, room);
    }
    if (!std::isfinite(hi)) {
      *at_bound = lo >= room;
      return lo;
    }
    return lo > 0.0 ? lo + (hi - lo) * (1.0 - lo_r) / (hi_r - lo_r) : hi;
  }
};

void set_interval(const ParamSpace& space, const FreeParam& f, double u_lo, double u_hi, ParameterEstimate* e) {
  const double a = space.value_of(f, u_lo), b = space.value_of(f, u_hi);
  e->ci_low = std::min(a, b);
  e->ci_high = std::max(a, b);
}

// Profile intervals where the linearisation fails (detail/identify.h).
void profile_intervals(const Profiler& pf, const ErrorBudget& budget, FitResult* res) {
  const ParamSpace& space = pf.space;
  for (int j = 0; j < space.size(); ++j) {
    const FreeParam& f = space.free[j];
    ParameterEstimate& e = res->estimates[j];
    if (f.transform != Transform::Log || budget.lost[j] || !(pf.calib[j] > 0.0) || e.interval == "basins") continue;
    const double half = kZ95 * std::sqrt(budget.covariance(j, j));
    const bool weak = !e.identifiable;
    bool side[2] = {weak, weak};
    for (int s = 0; s < 2; ++s)
      if (!side[s]) side[s] = pf.nonlinear_side(j, half, s == 0 ? -1 : 1);
    if (!side[0] && !side[1]) continue;
    double ends[2];
    bool bound[2];
    for (int s = 0; s < 2; ++s) {
      bound[s] = false;
      ends[s] = side[s] ? pf.end(j, s == 0 ? -1 : 1, std::min(half, 3.0), &bound[s]) : half;
    }
    set_interval(space, f, pf.best.u[j] - ends[0], pf.best.u[j] + ends[1], &e);
    e.interval = "profile";
    if (bound[0] || bound[1]) {
      e.identifiable = false;
      e.note = fmt::format("the profile likelihood stays within the 95 % threshold up to the search bound ({:.4g}): "
                           "the bound, not the data, limits the interval",
                           space.value_of(f, bound[0] ? f.lower : f.upper));
    } else if (weak) {
      e.identifiable = true;  // the profile closes on both sides within the bounds
      e.note.clear();
    }
  }
}

// A basin the likelihood-ratio test rejects (statistic W above 3.84).
struct Trailing {
  double w;
  Eigen::VectorXd u;
};

// A rejected basin still holds the truth now and then (the test's own 5 %),
// and then every parameter that differs between the basins misses by many
// of this basin's SEs: no SE of one basin describes an error that jumps
// between two. The SE states the spread over the basins as a posterior with
// equal priors weighs them (each basin exp(-W / 2) against the best's 1):
// SE^2 = SE_here^2 + sum_b P_b (value_b - value)^2, P_b the basin's share.
// A basin far behind (W of 20: a share of 5e-5) leaves it as it was. The
// interval stays the likelihood-ratio set, which excludes that basin.
void widen_by_trailing_basins(const ParamSpace& space, const std::vector<Trailing>& trailing, FitResult* res) {
  if (trailing.empty()) return;
  double total = 1.0;
  for (const Trailing& t : trailing) total += std::exp(-0.5 * t.w);
  std::vector<std::string> names;
  double w_min = std::numeric_limits<double>::infinity();
  for (int j = 0; j < space.size(); ++j) {
    ParameterEstimate& e = res->estimates[j];
    if (!(e.se >= 0.0) || e.interval == "basins") continue;
    double spread2 = 0.0;
    for (const Trailing& t : trailing) {
      const double d = space.value_of(space.free[j], t.u[j]) - e.value;
      spread2 += std::exp(-0.5 * t.w) / total * d * d;
    }
    const double se = std::sqrt(e.se * e.se + spread2);
    if (!(se > 1.05 * e.se)) continue;  // the other basins agree on this parameter
    e.basin_se = e.se;
    e.se = se;
    e.rel_se = se / std::max(std::abs(e.value), 1e-300);
    names.push_back(e.name);
  }
  if (names.empty()) return;
  for (const Trailing& t : trailing) w_min = std::min(w_min, t.w);
  res->warnings.push_back(fmt::format("another basin fits less well but not by far (likelihood-ratio statistic {:.2f} > "
                                      "{:.2f}, a posterior share of {:.2g} %): the SEs of {} include the spread over "
                                      "the basins (se_this_basin: this basin's own); the intervals exclude it",
                                      w_min, kChi2One95, 100.0 * std::exp(-0.5 * w_min) / total,
                                      fmt::join(names, ", ")));
}

// The other optima the search found (the conjugate basin's among them)
// that a parameter's 95 % set reaches: that parameter is not identifiable
// and its interval spans both basins.
void basin_intervals(const Profiler& pf, const Search& s, const ErrorBudget& budget, FitResult* res) {
  const ParamSpace& space = pf.space;
  const int np = space.size();
  std::vector<Optimum> sorted = s.others;
  std::sort(sorted.begin(), sorted.end(), [](const Optimum& a, const Optimum& b) { return a.cost < b.cost; });
  std::vector<Eigen::VectorXd> kept = {s.best.u};
  std::vector<Trailing> trailing;
  for (const Optimum& other : sorted) {
    bool seen = false;
    for (const auto& u : kept) seen = seen || (other.u - u).cwiseAbs().maxCoeff() < 0.2;
    if (seen) continue;
    // A basin the 95 % set reaches: every parameter whose value there lies
    // outside its interval here is not identifiable.
    double w = std::numeric_limits<double>::infinity();
    try {
      const Eigen::VectorXd d = residuals_held(pf.preps, space, pf.o, other.u, other.shifts) - s.best.residuals;
      if (d.size() == s.best.residuals.size()) w = basin_statistic(pf.preps, budget, d, other.cost - s.best.cost);
    } catch (const Error&) {
      continue;
    }
    if (!(w <= kChi2One95)) {
      bool again = false;
      for (const Trailing& t : trailing) again = again || (other.u - t.u).cwiseAbs().maxCoeff() < 0.2;
      if (std::isfinite(w) && !again) trailing.push_back({w, other.u});
      continue;
    }
    std::vector<int> reached;
    for (int j = 0; j < np; ++j) {
      const ParameterEstimate& e = res->estimates[j];
      const double v = space.value_of(space.free[j], other.u[j]);
      if (!(v >= e.ci_low && v <= e.ci_high)) reached.push_back(j);
    }
    if (reached.empty()) continue;
    kept.push_back(other.u);
    // The other basin's own intervals, from its own error budget.
    FitOptions one = pf.o;
    one.max_iterations = 0;
    Optimum alt = run_ceres(pf.preps, space, one, other.u, pf.evals, true, &other.shifts);
    alt.cost = other.cost;
    std::vector<ParameterEstimate> alt_est(np);
    for (int j = 0; j < np; ++j) alt_est[j].value = space.value_of(space.free[j], other.u[j]);
    std::vector<double> alt_shift_se;
    std::vector<std::string> ignored;
    const MatParams amp = space.to_mat(other.u.data());
    const ErrorBudget ab =
        budget_at(pf.preps, alt, nuisance_columns(pf.preps, space, pf.o, amp, alt.shifts, alt.residuals.size()));
    covariance(alt, space, pf.o, amp, ab, &alt_est, &alt_shift_se, &ignored);
    Alternative a;
    a.params = amp;
    a.cost = other.cost;
    a.delta_chi2 = w;
    res->alternatives.push_back(a);
    std::vector<std::string> names;
    for (int j : reached) {
      ParameterEstimate& e = res->estimates[j];
      const ParameterEstimate& ae = alt_est[j];
      if (std::isfinite(e.ci_low) && !std::isfinite(e.basin_ci_low)) {
        e.basin_ci_low = e.ci_low;
        e.basin_ci_high = e.ci_high;
      }
      const double lo = std::isfinite(ae.ci_low) ? ae.ci_low : ae.value, hi = std::isfinite(ae.ci_high) ? ae.ci_high : ae.value;
      e.ci_low = std::isfinite(e.ci_low) ? std::min(e.ci_low, lo) : std::min(e.value, lo);
      e.ci_high = std::isfinite(e.ci_high) ? std::max(e.ci_high, hi) : std::max(e.value, hi);
      e.identifiable = false;
      e.interval = "basins";
      e.note = fmt::format("another basin fits as well ({} = {:.4g} there; likelihood-ratio statistic {:.2f} <= "
                           "{:.2f}, chi-square 1 dof 95 %): the interval spans both",
                           e.name, ae.value, w, kChi2One95);
      names.push_back(e.name);
    }
    std::string alt_text;
    for (int j = 0; j < np; ++j)
      alt_text += fmt::format("{}{} {:.4g}", alt_text.empty() ? "" : ", ", param_display(space.free[j]),
                              space.value_of(space.free[j], other.u[j]));
    res->warnings.push_back(fmt::format("not identifiable: another basin fits about as well (likelihood-ratio "
                                        "statistic {:.2f} <= {:.2f}): {}; the intervals of {} span both",
                                        w, kChi2One95, alt_text, fmt::join(names, ", ")));
  }
  widen_by_trailing_basins(space, trailing, res);
}

}  // namespace

Eigen::VectorXd conjugate_start(const ParamSpace& space, const Eigen::VectorXd& u) {
  if (space.model != ModelKind::Model4) return {};
  const int i2 = index_of(space, "k2_n_m"), i3 = index_of(space, "k3_n_m");
  if (i2 < 0 || i3 < 0) return {};
  const MatParams mp = space.to_mat(u.data());
  MatParams c = mp;
  if (!conjugate_pair(mp.k1_n_m, mp.k2_n_m, mp.k3_n_m, mp.m1_kg, mp.m2_kg, &c.k2_n_m, &c.k3_n_m) ||
      !(c.k2_n_m > 0.0) || !(c.k3_n_m > 0.0))
    return {};
  // Damping past zero: the smallest the search allows (from_mat clamps).
  if (!conjugate_pair(mp.r1_n_s_m, mp.r2_n_s_m, mp.r3_n_s_m, mp.m1_kg, mp.m2_kg, &c.r2_n_s_m, &c.r3_n_s_m)) return {};
  c.r2_n_s_m = std::max(c.r2_n_s_m, 1e-9);
  c.r3_n_s_m = std::max(c.r3_n_s_m, 1e-9);
  const Eigen::VectorXd uc = space.from_mat(c);
  // The same basin only when the dampings map near themselves too: a
  // conjugate whose springs lie within 20 % may still exchange most of the
  // layers' damping between r2 and r3, and that is another optimum.
  double moved = 0.0;
  for (const char* name : {"k2_n_m", "k3_n_m", "r2_n_s_m", "r3_n_s_m"})
    if (const int j = index_of(space, name); j >= 0) moved = std::max(moved, std::abs(uc[j] - u[j]));
  if (moved < 0.2) return {};
  return uc;
}

void search_conjugate(const std::vector<Prepared>& preps, const ParamSpace& space, const FitOptions& o,
                      std::atomic<long>* evals, Search* s) {
  const Eigen::VectorXd uc = conjugate_start(space, s->best.u);
  if (uc.size() == 0) return;
  Optimum c;
  try {
    c = run_ceres(preps, space, o, uc, evals, true);
  } catch (const Error&) {
    return;
  }
  if (!std::isfinite(c.cost)) return;
  if (c.cost < s->best.cost && c.jacobian.rows() == s->best.jacobian.rows()) std::swap(c, s->best);
  s->others.push_back(std::move(c));
}

void refine_intervals(const std::vector<Prepared>& preps, const ParamSpace& space, const FitOptions& o,
                      const Search& s, const ErrorBudget& budget, std::atomic<long>* evals, FitResult* res) {
  const Eigen::Index n = s.best.jacobian.cols();
  if (budget.covariance.rows() != n || n < space.size() || s.best.jacobian.rows() <= n) return;
  const Profiler pf(preps, space, o, s.best, budget, evals);
  // Basins first: a parameter whose interval spans two basins needs no
  // profile within one.
  basin_intervals(pf, s, budget, res);
  profile_intervals(pf, budget, res);
}

}  // namespace dropfit::fitting::internal
