// The force channel's undeclared low-pass, told from a clock offset by its
// shape (see diagnosis.h, "Force channel").
#include <fmt/format.h>

#include <Eigen/QR>
#include <algorithm>
#include <cmath>
#include <exception>
#include <limits>
#include <numbers>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "core/parallel.h"
#include "diagnosis/diagnosis.h"
#include "diagnosis/internal.h"
#include "fitting/force_lowpass.h"

namespace dropfit::diagnosis {
namespace {

// A 2nd-order Butterworth's corner from its group delay (0: no filter).
double corner_of(double delay_s) { return delay_s > 0.0 ? std::sqrt(2.0) / (2.0 * std::numbers::pi * delay_s) : 0.0; }

// The mat model with the force passed through a filter of this group delay:
// the clock-shift window widened by the delay (the filtered onset comes that
// much later than the contact).
fitting::FitOptions options_at(const fitting::FitOptions& base, double delay_s) {
  fitting::FitOptions o = base;
  o.force_lowpass_hz = corner_of(delay_s);
  o.contact_shift_min_s = base.contact_shift_min_s - delay_s;
  o.contact_search_s = std::max(base.contact_search_s, -o.contact_shift_min_s);
  return o;
}

// The mat model's free parameters as the fitter frees them (stiffness and
// damping, the freed effect terms, the top layer's mass with the total
// fixed), each with a finite-difference step.
struct FreeParameter {
  std::string name;
  double step = 0.0;
};

std::vector<FreeParameter> free_parameters(const fitting::FitOptions& o, const fitting::MatParams& p) {
  std::vector<std::string> names = fitting::parameter_names(o.model, false);
  names.insert(names.end(), o.free_effects.begin(), o.free_effects.end());
  if (o.masses_free && (o.model == fitting::ModelKind::Model3 || o.model == fitting::ModelKind::Model4))
    names.push_back("m1_kg");
  std::vector<FreeParameter> out;
  for (const auto& n : names) {
    const double v = fitting::get_parameter(p, n);
    out.push_back({n, 1e-4 * std::max(std::abs(v), n == "k1_cubic_n_m3" ? 1e4 : 1e-3)});
  }
  return out;
}

fitting::MatParams moved(fitting::MatParams p, const FreeParameter& f, double by) {
  fitting::set_parameter(p, f.name, fitting::get_parameter(p, f.name) + by);
  if (f.name == "m1_kg") p.m2_kg -= by;  // the total mass stays
  return p;
}

// Every accepted trial's residuals (its clock shift profiled), trial by
// trial; `offsets` receives where each trial's block starts.
Eigen::VectorXd stacked_residuals(const std::vector<fitting::TrialData>& acc, const fitting::MatParams& p,
                                  const fitting::FitOptions& o, std::vector<Eigen::Index>* offsets = nullptr) {
  std::vector<Eigen::VectorXd> parts;
  Eigen::Index n = 0;
  if (offsets) offsets->clear();
  for (const auto& t : acc) {
    if (offsets) offsets->push_back(n);
    parts.push_back(fitting::residuals({t}, p, o));
    n += parts.back().size();
  }
  Eigen::VectorXd r(n);
  Eigen::Index at = 0;
  for (const auto& q : parts) r.segment(at, q.size()) = q, at += q.size();
  return r;
}

// The residuals at p and their derivatives along the free parameters (per
// step), each trial's clock shift profiled at every point (forward
// differences: the profiled shift moves with the parameters). The points
// are independent: they run on the fitter's threads (o.threads; one for a
// custom simulator, which need not be thread-safe); a failure is rethrown
// as the first failing point's, in order.
std::pair<Eigen::VectorXd, Eigen::MatrixXd> linearised(const std::vector<fitting::TrialData>& acc,
                                                       const fitting::MatParams& p, const fitting::FitOptions& o,
                                                       const std::vector<FreeParameter>& free,
                                                       std::vector<Eigen::Index>* offsets) {
  // Point 0 is p itself, point c + 1 p moved along free[c].
  std::vector<Eigen::VectorXd> points(free.size() + 1);
  std::vector<std::exception_ptr> failures(points.size());
  parallel_for(points.size(), o.simulator ? 1 : o.threads, [&](std::size_t k) {
    try {
      points[k] = k == 0 ? stacked_residuals(acc, p, o, offsets)
                         : stacked_residuals(acc, moved(p, free[k - 1], free[k - 1].step), o);
    } catch (...) {
      failures[k] = std::current_exception();
    }
  });
  for (const auto& f : failures)
    if (f) std::rethrow_exception(f);
  const Eigen::VectorXd& r = points[0];
  Eigen::MatrixXd j(r.size(), static_cast<Eigen::Index>(free.size()));
  for (std::size_t c = 0; c < free.size(); ++c) j.col(static_cast<Eigen::Index>(c)) = points[c + 1] - r;
  return {r, j};
}

// One point of the profile: the mat model refitted jointly to every
// accepted trial at this group delay by a Gauss-Newton step from p (each
// trial's clock shift profiled), its chi-square (2 x cost in noise units)
// and each trial's share.
struct ProfilePoint {
  double delay_s = 0.0;
  bool ok = false;
  double chi2 = 0.0;
  Eigen::VectorXd trial_chi2;
  double rms_sd = 0.0, lag1 = 0.0;  // the residual's RMS (noise SDs) and lag-1 autocorrelation within trials
  fitting::MatParams params;  // after the step
};

ProfilePoint profile_point(const std::vector<fitting::TrialData>& acc, const fitting::FitOptions& wide,
                           const fitting::MatParams& p, double delay_s, int halvings = 0) {
  ProfilePoint pt;
  pt.delay_s = delay_s;
  fitting::FitOptions o = wide;
  o.force_lowpass_hz = corner_of(delay_s);
  try {
    const std::vector<FreeParameter> free = free_parameters(o, p);
    std::vector<Eigen::Index> offsets;
    const auto [r, j] = linearised(acc, p, o, free, &offsets);
    const Eigen::VectorXd step = j.colPivHouseholderQr().solve(-r);
    // The chi-square the model reaches there (not the linear prediction),
    // or at p when the step (halved up to `halvings` times) does not
    // improve on it.
    Eigen::VectorXd res = r;
    pt.params = p;
    double length = 1.0;
    for (int h = 0; h <= halvings; ++h, length *= 0.5) {
      fitting::MatParams stepped = p;
      for (std::size_t c = 0; c < free.size(); ++c)
        stepped = moved(stepped, free[c], length * step(static_cast<Eigen::Index>(c)) * free[c].step);
      try {
        const Eigen::VectorXd rs = stacked_residuals(acc, stepped, o);
        if (rs.allFinite() && rs.squaredNorm() < r.squaredNorm()) {
          res = rs;
          pt.params = stepped;
          break;
        }
      } catch (const std::exception&) {
      }
    }
    pt.chi2 = res.squaredNorm();
    pt.trial_chi2.resize(static_cast<Eigen::Index>(acc.size()));
    double lag = 0.0;
    for (std::size_t i = 0; i < acc.size(); ++i) {
      const Eigen::Index a = offsets[i], b = i + 1 < offsets.size() ? offsets[i + 1] : res.size();
      pt.trial_chi2(static_cast<Eigen::Index>(i)) = res.segment(a, b - a).squaredNorm();
      for (Eigen::Index k = a + 1; k < b; ++k) lag += res(k) * res(k - 1);
    }
    pt.rms_sd = std::sqrt(pt.chi2 / static_cast<double>(std::max<Eigen::Index>(res.size(), 1)));
    pt.lag1 = pt.chi2 > 0.0 ? lag / pt.chi2 : 0.0;
    pt.ok = std::isfinite(pt.chi2) && pt.trial_chi2.allFinite();
  } catch (const std::exception&) {
    pt.ok = false;
  }
  return pt;
}

// Where the profile (chi-square over its minimum, delays increasing)
// crosses `level` on each side of its minimum, its square root interpolated
// linearly between points (exact for a quadratic profile, which a coarse
// grid's straight lines would narrow); an end the profile does not cross
// stays at the grid's end.
std::pair<double, double> crossing(const std::vector<double>& d, const std::vector<double>& c, double level) {
  const std::size_t m = static_cast<std::size_t>(std::min_element(c.begin(), c.end()) - c.begin());
  auto root = [&](std::size_t i) { return std::sqrt(std::max(c[i], 0.0)); };
  const double r = std::sqrt(level);
  double lo = d.front(), hi = d.back();
  for (std::size_t i = m; i > 0; --i)
    if (c[i - 1] > level) {
      lo = d[i - 1] + (r - root(i - 1)) / (root(i) - root(i - 1)) * (d[i] - d[i - 1]);
      break;
    }
  for (std::size_t i = m; i + 1 < d.size(); ++i)
    if (c[i + 1] > level) {
      hi = d[i] + (r - root(i)) / (root(i + 1) - root(i)) * (d[i + 1] - d[i]);
      break;
    }
  return {lo, hi};
}

// The profile: Gauss-Newton to the joint optimum without a filter (from
// the mat stage's optimum, trained on one trial), then every delay of the
// grid from there, refined by a parabola through the best grid point and its
// neighbours; sorted by delay, the first without a filter.
std::vector<ProfilePoint> run_profile(const std::vector<fitting::TrialData>& acc, const fitting::FitOptions& wide,
                                      const fitting::MatParams& start, const LowpassStageOptions& options) {
  fitting::MatParams joint = start;
  double chi2 = std::numeric_limits<double>::infinity();
  for (int it = 0; it < 3; ++it) {
    const ProfilePoint p = profile_point(acc, wide, joint, 0.0);
    if (!p.ok || !(p.chi2 < chi2)) break;
    chi2 = p.chi2;
    joint = p.params;
  }
  std::vector<double> grid = options.delays_s;
  std::sort(grid.begin(), grid.end());
  std::vector<ProfilePoint> pts(grid.size());
  // Two Gauss-Newton steps at each delay, by continuation: each delay
  // starts from the optimum of the one before (a large delay moves the
  // mat's parameters further than one step from no filter reaches).
  auto refined = [&](double delay, const fitting::MatParams& from) {
    ProfilePoint p = profile_point(acc, wide, from, delay);
    if (!p.ok) return p;
    ProfilePoint q = profile_point(acc, wide, p.params, delay);
    return q.ok && q.chi2 < p.chi2 ? q : p;
  };
  fitting::MatParams from = joint;
  for (std::size_t i = 0; i < grid.size(); ++i) {
    pts[i] = refined(grid[i], from);
    if (pts[i].ok) from = pts[i].params;
  }
  std::erase_if(pts, [](const ProfilePoint& p) { return !p.ok; });
  if (pts.size() < 3) return pts;
  std::size_t m = 0;
  for (std::size_t i = 1; i < pts.size(); ++i)
    if (pts[i].chi2 < pts[m].chi2) m = i;
  if (m > 0 && m + 1 < pts.size()) {
    const double x0 = pts[m - 1].delay_s, x1 = pts[m].delay_s, x2 = pts[m + 1].delay_s;
    const double y0 = pts[m - 1].chi2, y1 = pts[m].chi2, y2 = pts[m + 1].chi2;
    const double den = (x0 - x1) * (x0 - x2) * (x1 - x2);
    const double a = (x2 * (y1 - y0) + x1 * (y0 - y2) + x0 * (y2 - y1)) / den;
    const double b = (x2 * x2 * (y0 - y1) + x1 * x1 * (y2 - y0) + x0 * x0 * (y1 - y2)) / den;
    const double xv = a > 0.0 ? -b / (2.0 * a) : x1;
    if (xv > x0 && xv < x2 && std::abs(xv - x1) > 0.01e-3) {
      ProfilePoint p = refined(xv, pts[m].params);
      if (p.ok) pts.push_back(std::move(p));
    }
  }
  std::sort(pts.begin(), pts.end(), [](const auto& a, const auto& b) { return a.delay_s < b.delay_s; });
  return pts;
}

// The model with the named filter, fitted as every model is (its intervals,
// error budget and predictions) from the profile's best point: the session's
// mat fit from here on, and the contacts the sync stage re-judges. When that
// fit fails, each trial predicted at the profile's best point (its clock
// shift fitted) stands in, without intervals.
fitting::FitResult filtered_fit(const std::vector<fitting::TrialData>& acc, const fitting::FitOptions& o,
                                const fitting::MatParams& params) {
  fitting::FitOptions warm = o;
  warm.initial = params;
  warm.starts = 1;
  warm.protect_initial = false;
  warm.search_identifiability = true;
  try {
    return fitting::fit(acc, warm);
  } catch (const std::exception&) {
  }
  fitting::FitResult f;
  f.model = o.model;
  f.params = params;
  f.force_lowpass_hz = o.force_lowpass_hz;
  for (const auto& t : acc) {
    f.trials.push_back(fitting::predict(t, params, o));
    f.trials.back().train = true;
    f.train_ids.push_back(t.id);
  }
  return f;
}

// Each trial's chi-square at the delay the other trials' profile chooses
// (after) and without a filter (before).
std::pair<Eigen::VectorXd, Eigen::VectorXd> held_out_chi2(const std::vector<ProfilePoint>& pts) {
  const Eigen::Index n = pts.front().trial_chi2.size();
  Eigen::VectorXd before(n), after(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    std::size_t best = 0;
    double best_c = std::numeric_limits<double>::infinity();
    for (std::size_t k = 0; k < pts.size(); ++k) {
      const double others = pts[k].trial_chi2.sum() - pts[k].trial_chi2(i);
      if (others < best_c) best_c = others, best = k;
    }
    before(i) = pts.front().trial_chi2(i);
    after(i) = pts[best].trial_chi2(i);
  }
  return {before, after};
}

// The mat's own rival to a filter: a layered mat (Models 3 and 4 with the
// declared split) refitted jointly without a filter with its layer masses
// free (the total fixed), from the profile's joint optimum. The split sets
// how fast the plate force rises after the contact, as a low-pass's delay
// and rounding do, so a lumped model with the wrong split reads as a
// filtered force channel (docs/diagnosis.md). Empty where the masses are
// already free or there are none.
std::optional<ProfilePoint> mass_rival(const std::vector<fitting::TrialData>& acc, const fitting::FitOptions& wide,
                                       const ProfilePoint& none) {
  if (wide.masses_free || (wide.model != fitting::ModelKind::Model3 && wide.model != fitting::ModelKind::Model4))
    return std::nullopt;
  fitting::FitOptions o = wide;
  o.masses_free = true;
  std::optional<ProfilePoint> best;
  fitting::MatParams from = none.params;
  for (int it = 0; it < 5; ++it) {
    ProfilePoint p = profile_point(acc, o, from, 0.0, 5);
    if (!p.ok || (best && !(p.chi2 < best->chi2))) break;
    from = p.params;
    best = std::move(p);
  }
  return best;
}

// The verdict on a fitted profile (the first point without a filter): the
// interval, the held-out and information-criterion tests, the mat's rival
// (the layer masses), the effect or the rejection.
LowpassDiagnosis judge_lowpass(const std::vector<fitting::TrialData>& acc, const fitting::FitOptions& model,
                               const std::vector<ProfilePoint>& pts, const LowpassStageOptions& options,
                               LowpassDiagnosis out) {
  std::size_t m = 0;
  for (std::size_t i = 1; i < pts.size(); ++i)
    if (pts[i].chi2 < pts[m].chi2) m = i;
  const ProfilePoint& none = pts.front();
  const ProfilePoint& best = pts[m];
  // A correlated force residual carries fewer independent samples: the
  // chi-square differences shrink by the AR(1) factor (1 - rho) / (1 + rho).
  const double rho = std::clamp(best.lag1, 0.0, 0.95);
  const double scale = (1.0 - rho) / (1.0 + rho);
  for (const auto& p : pts) {
    out.profile_delay_s.push_back(p.delay_s);
    out.profile_chi2.push_back(scale * (p.chi2 - best.chi2));
  }
  std::tie(out.delay_low_s, out.delay_high_s) = crossing(out.profile_delay_s, out.profile_chi2, options.interval_chi2);
  const double gain = out.profile_chi2.front();  // no filter against the best corner

  const auto [before, after] = held_out_chi2(pts);
  // The mat's free parameters and each trial's clock shift; the corner.
  const int k0 = static_cast<int>(acc.size() + free_parameters(model, none.params).size());
  Eigen::Index n_res = 0;
  for (const auto& t : acc) n_res += fitting::residuals({t}, none.params, model).size();
  const detail::Verdict v = detail::judge(before, after, 0.0, none.chi2, k0, best.chi2, k0 + 1,
                                          static_cast<double>(n_res), rho, Criterion::AICc,
                                          DecisionOptions{options.decision.t_critical, 0.0,
                                                          options.decision.ic_min_drop, options.decision.alpha});
  const double ms = 1e3;
  std::string curve;
  for (std::size_t i = 0; i < pts.size(); ++i)
    curve += fmt::format("{}{:.2f} ms {:.1f}", i ? ", " : "", ms * out.profile_delay_s[i], out.profile_chi2[i]);
  const std::string profile = fmt::format(
      "chi-square {:.1f} lower at a group delay of {:.3f} ms (corner {:.0f} Hz) than without a filter, 95 % profile "
      "{:.3f} to {:.3f} ms over {} trials (profile: {})",
      gain, ms * best.delay_s, corner_of(best.delay_s), ms * out.delay_low_s, ms * out.delay_high_s, acc.size(),
      curve);
  // A filter the layer masses explain as well (within the interval's
  // chi-square) is not told from them: neither is named, and the
  // profile's lag stays ambiguous. The rival is fitted only for a filter
  // that would be named.
  const bool passes = best.delay_s > 0.0 && v.keep() && out.delay_low_s > 0.0;
  const std::optional<ProfilePoint> rival = passes ? mass_rival(acc, model, none) : std::nullopt;
  const double mass_gain = rival ? scale * (none.chi2 - rival->chi2) : 0.0;
  if (rival && gain - mass_gain < options.interval_chi2) {
    const double m1 = fitting::get_parameter(rival->params, "m1_kg");
    const double m1_0 = fitting::get_parameter(none.params, "m1_kg");
    out.rejected.push_back(
        {"forceplate", "force_lowpass",
         fmt::format("{}; but the mat's layer masses, refitted without a filter (m1 {:.2f} kg where the split "
                     "gives {:.2f} kg, the total fixed), lower the chi-square by {:.1f} against the filter's {:.1f}: "
                     "the split sets how fast the plate force rises after the contact, as a low-pass does, and "
                     "the two are not told apart here; neither is named",
                     profile, m1, m1_0, mass_gain, gain)});
    out.delay_low_s = 0.0;
    return out;
  }
  if (passes) {
    out.named = true;
    out.delay_s = best.delay_s;
    out.corner_hz = corner_of(best.delay_s);
    out.fit_options = model;
    out.fit_options.force_lowpass_hz = out.corner_hz;
    out.fit = filtered_fit(acc, out.fit_options, best.params);
    Effect eff;
    eff.stage = "forceplate";
    eff.name = "force_lowpass";
    const bool bounded = out.delay_high_s < pts.back().delay_s;
    eff.evidence = fmt::format(
        "the plate force reads as the mat's through a 2nd-order low-pass nobody declared: {}; corner {:.0f} Hz "
        "(95 % {:.0f} to {}), a lag of {:.2f} ms that is the force channel's, not the clock's; held-out chi-square "
        "per trial {:.1f} -> {:.1f} (t = {:.1f})",
        profile, out.corner_hz, corner_of(out.delay_high_s),
        fmt::format("{:.0f} Hz", corner_of(out.delay_low_s)), ms * out.delay_s, before.mean(), after.mean(),
        v.held_out.t);
    if (!bounded) eff.evidence += "; the data bound the corner from one side only";
    eff.error_before = {{"rms_noise_sd", none.rms_sd}, {"heldout_chi2_per_trial", before.mean()}};
    eff.error_after = {{"rms_noise_sd", best.rms_sd}, {"heldout_chi2_per_trial", after.mean()}};
    eff.estimate = {{"corner_hz", out.corner_hz},
                    {"corner_low_hz", bounded ? corner_of(out.delay_high_s) : kNaN},
                    {"corner_high_hz", corner_of(out.delay_low_s)},
                    {"group_delay_ms", ms * out.delay_s},
                    {"delta_chi2_without", gain}};
    out.effects.push_back(std::move(eff));
  } else {
    out.rejected.push_back({"forceplate", "force_lowpass",
                            profile + (best.delay_s > 0.0 ? "; " + v.reason("chi-square per trial", Criterion::AICc)
                                                          : "; no filter fits best")});
  }
  return out;
}

}  // namespace

LowpassDiagnosis diagnose_force_lowpass(const std::vector<fitting::TrialData>& trials,
                                        const fitting::FitOptions& model, const fitting::MatParams& start,
                                        double held_out_force_sd, double held_out_impactor_sd, double explained_sd,
                                        const LowpassStageOptions& options) {
  LowpassDiagnosis out;
  std::vector<fitting::TrialData> acc;
  for (const auto& t : trials)
    if (t.accepted) acc.push_back(t);
  if (acc.size() < 3 || options.delays_s.size() < 3) {
    out.notes.push_back("forceplate: an undeclared force-channel low-pass needs three accepted trials; not tried");
    return out;
  }
  if (!(held_out_force_sd <= explained_sd) || !(held_out_impactor_sd <= explained_sd)) {
    out.notes.push_back(fmt::format(
        "forceplate: an undeclared force-channel low-pass not tried: the mat model's held-out errors (force {:.2f}, "
        "travel {:.2f} noise SDs) are beyond {:.1f}: the mat is not explained, and a filter would soak up the "
        "model's own error",
        held_out_force_sd, held_out_impactor_sd, explained_sd));
    return out;
  }
  if (model.model == fitting::ModelKind::Model5 || model.simulator) {
    out.notes.push_back("forceplate: an undeclared force-channel low-pass is profiled on Models 1-4 only; not tried");
    return out;
  }
  // Every delay's clock-shift window: the widest (the residuals of every
  // point cover the same samples).
  const double widest = *std::max_element(options.delays_s.begin(), options.delays_s.end());
  const fitting::FitOptions wide = options_at(model, widest);
  const std::vector<ProfilePoint> pts = run_profile(acc, wide, start, options);
  if (pts.size() < 3 || pts.front().delay_s != 0.0) {
    out.notes.push_back("forceplate: the force-channel low-pass profile could not be fitted; not judged");
    return out;
  }
  // The model must reach the noise with the filter at its best: otherwise
  // the filter only stands in for what the model misses.
  const ProfilePoint& best = *std::min_element(pts.begin(), pts.end(), [](const auto& a, const auto& b) {
    return a.chi2 < b.chi2;
  });
  if (best.rms_sd > options.max_rms_sd && best.lag1 > options.max_lag1) {
    out.notes.push_back(fmt::format(
        "forceplate: an undeclared force-channel low-pass not judged: the joint fit's residual stays structured "
        "with the filter at its best ({:.2f} noise SDs, lag-1 {:.2f}); a filter would soak up the model's own error",
        best.rms_sd, best.lag1));
    return out;
  }
  out.tried = true;
  return judge_lowpass(acc, wide, pts, options, std::move(out));
}

}  // namespace dropfit::diagnosis

namespace dropfit::diagnosis::detail {

void attribute_lag(SyncDiagnosis& sync, const LowpassDiagnosis& lp, double min_ambiguity_s) {
  if (!lp.tried) return;
  const double ms = 1e3;
  Effect* eff = nullptr;
  for (auto& e : sync.effects)
    if (e.name == "time_offset") eff = &e;
  // The sync stage's caveat (a force-channel delay reads as clock offset)
  // is replaced by what the profile found.
  if (eff) {
    const auto cut = eff->evidence.find(" (a delay of the force channel");
    if (cut != std::string::npos) eff->evidence.erase(cut);
  }
  if (lp.named) {
    if (!eff) return;
    eff->evidence += fmt::format(
        "; the force channel's low-pass (corner {:.0f} Hz, a {:.2f} ms lag) is in the model that places each "
        "contact, so this offset is the clock's",
        lp.corner_hz, ms * lp.delay_s);
    eff->estimate.push_back({"force_lowpass_delay_ms", ms * lp.delay_s});
    return;
  }
  const double lo = sync.offset_s + lp.delay_low_s, hi = sync.offset_s + lp.delay_high_s;
  if (lp.delay_high_s - lp.delay_low_s < min_ambiguity_s) return;
  const std::string range = fmt::format(
      "a force-channel low-pass with a lag of {:.2f} to {:.2f} ms fits as well (95 % profile): the lag is ambiguous "
      "between the clock and the force channel, and the clock offset lies between {:.2f} and {:.2f} ms",
      ms * lp.delay_low_s, ms * lp.delay_high_s, ms * lo, ms * hi);
  if (eff) {
    eff->evidence += "; " + range;
    eff->estimate.push_back({"video_offset_low_ms", ms * lo});
    eff->estimate.push_back({"video_offset_high_ms", ms * hi});
  } else {
    sync.notes.push_back("sync: " + range);
  }
}

}  // namespace dropfit::diagnosis::detail
