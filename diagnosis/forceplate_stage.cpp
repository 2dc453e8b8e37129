// The force-plate stage of the loop: baseline drift from the still parts of
// the record, force scale from impulse and momentum (see diagnosis.h).
#include <fmt/format.h>

#include <Eigen/Dense>
#include <algorithm>
#include <cmath>
#include <optional>

#include "diagnosis/diagnosis.h"
#include "diagnosis/internal.h"
#include "trial/trial.h"

namespace dropfit::diagnosis {
namespace {

// The samples where the zeroed Fz must equal a known level: the quiet
// pre-trigger part (0) and, after the contact has settled, windows whose SD
// is within still_sd_factor noise SDs, at 0 (impactor in the air) or m g
// (impactor at rest). The first such window takes the level nearer its
// mean; each later one keeps the level before it unless its mean jumps from
// the last window's by more than half of m g (the impactor landed or was
// lifted), so a drift that grows past half the impactor's weight over the
// record does not flip the level it is measured against.
struct Still {
  std::vector<Eigen::Index> index;  // into the trial's samples
  std::vector<double> expected_n;
  std::vector<bool> after_contact;
};

double noise_of(const PlateTrial& t) { return std::max(t.noise_n, 1e-3); }

Still still_samples(const PlateTrial& t, const ForceplateStageOptions& o) {
  Still s;
  const Eigen::Index n = t.t_s.size();
  const double weight = o.impactor_mass_kg * o.gravity_m_s2;
  for (Eigen::Index i = 0; i < n; ++i) {
    if (t.t_s(i) >= t.quiet_end_s) break;
    if (!std::isfinite(t.fz_n(i))) continue;
    s.index.push_back(i);
    s.expected_n.push_back(0.0);
    s.after_contact.push_back(false);
  }
  const double dt = n > 1 ? (t.t_s(n - 1) - t.t_s(0)) / static_cast<double>(n - 1) : 1e-3;
  const auto w = std::max<Eigen::Index>(5, static_cast<Eigen::Index>(std::lround(o.still_window_s / dt)));
  const double start = t.end_time_s + o.settle_s;
  Eigen::Index i = 0;
  while (i < n && t.t_s(i) < start) ++i;
  const double limit = o.still_sd_factor * noise_of(t);
  auto nearer = [&](double f) { return std::abs(f) <= std::abs(f - weight) ? 0.0 : weight; };
  bool have_last = false;
  double last_mean = 0.0, last_level = 0.0;
  for (; i + w <= n; i += w) {
    const Eigen::VectorXd seg = t.fz_n.segment(i, w);
    if (!seg.allFinite()) continue;
    const double mean = seg.mean();
    const double sd = std::sqrt((seg.array() - mean).square().sum() / static_cast<double>(w - 1));
    if (sd > limit) continue;
    // After a jump, the level nearer the mean less the offset the last
    // window read (its drift so far).
    const double level = !have_last                                   ? nearer(mean)
                         : std::abs(mean - last_mean) <= 0.5 * weight ? last_level
                                                                      : nearer(mean - (last_mean - last_level));
    have_last = true, last_mean = mean, last_level = level;
    for (Eigen::Index k = i; k < i + w; ++k) {
      s.index.push_back(k);
      s.expected_n.push_back(level);
      s.after_contact.push_back(true);
    }
  }
  return s;
}

// Columns of the drift candidates for one trial at its still samples.
double drift_column(const PlateTrial& t, Eigen::Index i, bool from_contact) {
  return from_contact ? std::max(t.t_s(i) - t.contact_time_s, 0.0) : t.t_s(i);
}

// Least squares of the still residual on per-trial intercepts and one
// common drift column (fit_drift: every row, or only the rows not `late`).
// Returns the drift slope and per-trial intercepts.
struct DriftFit {
  double slope = 0.0;
  Eigen::VectorXd intercept;
  double rss = 0.0;
};

struct Row {
  int trial;
  double residual, column;
  bool late;  // in the later half of its trial's post-contact still data
};

DriftFit fit_drift(const std::vector<Row>& rows, int n_trials, bool with_slope, bool skip_late) {
  // The intercepts are one per trial, so the slope is the within-trial
  // regression (each trial's rows about their own means) and each intercept
  // its trial's mean residual less slope x mean column: O(rows), where the
  // dense design with one column per trial grows as rows x trials. A trial
  // without rows keeps intercept 0.
  auto keep = [&](const Row& r) { return !(skip_late && r.late); };
  Eigen::VectorXd n = Eigen::VectorXd::Zero(n_trials), sum_r = n, sum_c = n;
  for (const auto& r : rows) {
    if (!keep(r)) continue;
    n(r.trial) += 1.0;
    sum_r(r.trial) += r.residual;
    sum_c(r.trial) += r.column;
  }
  const Eigen::VectorXd safe_n = n.cwiseMax(1.0);
  const Eigen::VectorXd mean_r = sum_r.cwiseQuotient(safe_n), mean_c = sum_c.cwiseQuotient(safe_n);
  DriftFit f;
  if (with_slope) {
    double sxy = 0.0, sxx = 0.0;
    for (const auto& r : rows) {
      if (!keep(r)) continue;
      const double dc = r.column - mean_c(r.trial);
      sxy += dc * (r.residual - mean_r(r.trial));
      sxx += dc * dc;
    }
    f.slope = sxx > 0.0 ? sxy / sxx : 0.0;
  }
  f.intercept = mean_r - f.slope * mean_c;
  for (const auto& r : rows) {
    if (!keep(r)) continue;
    const double e = r.residual - f.intercept(r.trial) - f.slope * r.column;
    f.rss += e * e;
  }
  return f;
}

}  // namespace

Eigen::VectorXd PlateCorrection::apply(const Eigen::VectorXd& t_s, const Eigen::VectorXd& fz_n,
                                       double contact_time_s) const {
  Eigen::VectorXd out = fz_n;
  if (drift) {
    for (Eigen::Index i = 0; i < out.size(); ++i)
      out(i) -= drift_from_contact ? drift_n_s * std::max(t_s(i) - contact_time_s, 0.0)
                                   : drift_offset_n + drift_n_s * t_s(i);
  }
  return out / gain;
}

double impulse_ratio(const PlateTrial& t, const PlateCorrection& c, double mass_kg, double g) {
  const double nan = kNaN;
  const Eigen::Index n = t.t_s.size();
  if (n < 10 || !std::isfinite(t.impact_velocity_m_s)) return nan;
  const Eigen::VectorXd f = c.apply(t.t_s, t.fz_n, t.contact_time_s);
  const double dt = (t.t_s(n - 1) - t.t_s(0)) / static_cast<double>(n - 1);
  const double weight = mass_kg * g;
  const double noise = std::max(t.noise_n, 1e-3);
  // t_e: the middle of the first still 30 ms window after the contact's end.
  const auto w = std::max<Eigen::Index>(5, static_cast<Eigen::Index>(std::lround(0.03 / dt)));
  Eigen::Index i = 0;
  while (i < n && t.t_s(i) < t.end_time_s + 0.01) ++i;
  // The contact ended with the force back at zero: the impactor left the
  // mat. A later rise to half its weight is a second landing (or a hand
  // setting it down), whose impulse is not this contact's: the still part
  // is sought before it.
  Eigen::Index limit = i;
  while (limit < n && !(f(limit) > 0.5 * weight)) ++limit;
  Eigen::Index ie = -1;
  bool resting = false;
  for (; i + w <= limit; i += w / 2) {
    const Eigen::VectorXd seg = f.segment(i, w);
    if (!seg.allFinite()) continue;
    const double mean = seg.mean();
    const double sd = std::sqrt((seg.array() - mean).square().sum() / static_cast<double>(w - 1));
    if (sd > 4.0 * noise) continue;
    if (std::abs(mean) < 5.0 * noise + 0.02 * weight) {
      ie = i + w / 2;
      break;
    }
    if (std::abs(mean - weight) < 5.0 * noise + 0.02 * weight) {
      ie = i + w / 2;
      resting = true;
      break;
    }
  }
  if (ie < 0) return nan;
  const double te = t.t_s(ie);
  // The impactor's upward speed at t_e: free flight z = z0 + v (t - te) - g (t - te)^2 / 2
  // over the video frames within 40 ms of it (or 0 at rest).
  double ve = 0.0;
  if (!resting) {
    std::vector<double> ts, zs;
    for (Eigen::Index k = 0; k < t.video_t_s.size(); ++k)
      if (std::abs(t.video_t_s(k) - te) <= 0.04 && std::isfinite(t.face_z_m(k))) {
        ts.push_back(t.video_t_s(k) - te);
        zs.push_back(t.face_z_m(k) + 0.5 * g * (t.video_t_s(k) - te) * (t.video_t_s(k) - te));
      }
    if (ts.size() < 10) return nan;
    Eigen::MatrixXd a(static_cast<Eigen::Index>(ts.size()), 2);
    Eigen::VectorXd b(static_cast<Eigen::Index>(ts.size()));
    for (std::size_t k = 0; k < ts.size(); ++k) {
      a(static_cast<Eigen::Index>(k), 0) = 1.0;
      a(static_cast<Eigen::Index>(k), 1) = ts[k];
      b(static_cast<Eigen::Index>(k)) = zs[k];
    }
    ve = a.colPivHouseholderQr().solve(b)(1);
  }
  // Plate impulse from the contact to t_e (trapezoid; the sample at or just
  // before the contact starts it).
  Eigen::Index i0 = 0;
  while (i0 + 1 < n && t.t_s(i0 + 1) <= t.contact_time_s) ++i0;
  const double t_c = t.t_s(i0);
  const double impulse = trial::integrate(t.t_s, f, t_c, te);
  const double momentum = mass_kg * (t.impact_velocity_m_s + ve) + weight * (te - t_c);
  return momentum > 0.0 ? impulse / momentum : nan;
}

namespace {

// Least squares of free flight z = z0 + v (t - t_ref) - g (t - t_ref)^2 / 2
// (g known) over the given frames: v at t_ref and the fit's RMS.
bool flight_fit(const std::vector<double>& ts, const std::vector<double>& zs, double t_ref, double g, double* v,
                double* z0, double* rms) {
  const auto n = static_cast<Eigen::Index>(ts.size());
  if (n < 3) return false;
  Eigen::MatrixXd a(n, 2);
  Eigen::VectorXd b(n);
  for (Eigen::Index k = 0; k < n; ++k) {
    const double dt = ts[static_cast<std::size_t>(k)] - t_ref;
    a(k, 0) = 1.0;
    a(k, 1) = dt;
    b(k) = zs[static_cast<std::size_t>(k)] + 0.5 * g * dt * dt;
  }
  const Eigen::Vector2d x = a.colPivHouseholderQr().solve(b);
  *z0 = x(0);
  *v = x(1);
  *rms = std::sqrt((b - a * x).squaredNorm() / static_cast<double>(n));
  return true;
}

}  // namespace

ImpulseBalance impulse_balance(const PlateTrial& t, const PlateCorrection& c, double mass_kg, double g) {
  ImpulseBalance out;
  const Eigen::Index n = t.t_s.size();
  if (n < 10 || !std::isfinite(t.impact_velocity_m_s) || !std::isfinite(t.mat_top_z_m)) return out;
  const Eigen::VectorXd f = c.apply(t.t_s, t.fz_n, t.contact_time_s);
  // The flight: video frames after the deepest point with the face clear of
  // the mat top (5 mm: a few marker-noise SDs above the undeformed surface).
  const double clearance_m = 0.005;
  const double after = std::isfinite(t.max_deformation_time_s) ? t.max_deformation_time_s : t.contact_time_s;
  std::vector<double> ts, zs;
  for (Eigen::Index k = 0; k < t.video_t_s.size(); ++k) {
    if (t.video_t_s(k) <= after || !std::isfinite(t.face_z_m(k))) continue;
    if (t.face_z_m(k) > t.mat_top_z_m + clearance_m) {
      ts.push_back(t.video_t_s(k));
      zs.push_back(t.face_z_m(k));
    } else if (!ts.empty()) {
      break;  // landed again: the flight is over
    }
  }
  // At least 10 frames (10 ms at 1 kHz) of flight for a velocity.
  if (ts.size() < 10) return out;
  double v_ref, z0, rms;
  const double t_ref = ts.front();
  if (!flight_fit(ts, zs, t_ref, g, &v_ref, &z0, &rms) || !(v_ref > 0.0)) return out;
  out.flight_frames = static_cast<int>(ts.size());
  out.window_start_s = ts.front();
  out.window_end_s = ts.back();
  // Plate impulse from 10 ms before the contact (the plate reads the mat at
  // rest there) to every force sample in the flight window.
  const double dt = (t.t_s(n - 1) - t.t_s(0)) / static_cast<double>(n - 1);
  const double t0 = t.contact_time_s - 0.010;
  Eigen::Index i = 0;
  while (i + 1 < n && t.t_s(i + 1) <= t0) ++i;
  double impulse = 0.0;
  std::vector<double> ratios, excess;
  for (; i + 1 < n && t.t_s(i + 1) <= out.window_end_s; ++i) {
    impulse += 0.5 * (f(i) + f(i + 1)) * dt;
    const double te = t.t_s(i + 1);
    if (te < out.window_start_s) continue;
    const double v_up = v_ref - g * (te - t_ref);
    // From t0 the impactor fell freely to the contact, so its downward speed
    // at t0 was v_in - g (t_c - t0); impulse = momentum change + m g (te - t0)
    // = m (v_in + v_up) + m g (te - t_c).
    const double momentum = mass_kg * (t.impact_velocity_m_s + v_up) + mass_kg * g * (te - t.contact_time_s);
    if (!(momentum > 0.0)) continue;
    ratios.push_back(impulse / momentum);
    excess.push_back(impulse - momentum);
  }
  if (ratios.size() < 5) return out;
  const Eigen::VectorXd r = detail::to_vector(ratios);
  out.ratio = r.mean();
  out.spread = detail::sample_sd(r);
  const Eigen::VectorXd e = detail::to_vector(excess);
  out.mat_momentum_n_s = std::sqrt((e.array() - e.mean()).square().mean());
  out.method = "free flight";
  return out;
}

namespace {

// The still samples of every trial as drift-fit rows (column filled later),
// with each trial's residual segment for the whiteness test.
struct StillRows {
  std::vector<Still> stills;
  std::vector<Row> rows;
  std::vector<Eigen::VectorXd> segments;
  double noise_n = 0.0;  // RMS over trials of the plate noise
  int post_trials = 0;   // trials with still samples after the contact
};

StillRows collect_still_rows(const std::vector<PlateTrial>& trials, const ForceplateStageOptions& o) {
  StillRows sr;
  const int nt = static_cast<int>(trials.size());
  double noise_sq = 0.0;
  for (int k = 0; k < nt; ++k) {
    const PlateTrial& t = trials[static_cast<std::size_t>(k)];
    sr.stills.push_back(still_samples(t, o));
    const Still& s = sr.stills.back();
    std::vector<double> post_t;
    for (std::size_t j = 0; j < s.index.size(); ++j)
      if (s.after_contact[j]) post_t.push_back(t.t_s(s.index[j]));
    const double split = post_t.empty() ? 0.0 : post_t[post_t.size() / 2];
    if (!post_t.empty()) ++sr.post_trials;
    Eigen::VectorXd seg(static_cast<Eigen::Index>(s.index.size()));
    for (std::size_t j = 0; j < s.index.size(); ++j) {
      const Eigen::Index i = s.index[j];
      Row r;
      r.trial = k;
      r.residual = t.fz_n(i) - s.expected_n[j];
      r.column = 0.0;
      r.late = s.after_contact[j] && t.t_s(i) >= split;
      sr.rows.push_back(r);
      seg(static_cast<Eigen::Index>(j)) = r.residual;
    }
    sr.segments.push_back(seg);
    noise_sq += noise_of(t) * noise_of(t);
  }
  sr.noise_n = std::sqrt(noise_sq / nt);
  return sr;
}

// Which drift shape: regression of the still residual on a line over the
// record and on a ramp from the contact, per-trial intercepts projected out.
// Fills the rows' column with the winner; returns its term (nullptr when
// none) and whether it is the ramp.
std::pair<std::optional<TermScore>, bool> choose_drift_column(const std::vector<PlateTrial>& trials, StillRows& sr,
                                                              double alpha) {
  const int nt = static_cast<int>(trials.size());
  const auto n_rows = static_cast<Eigen::Index>(sr.rows.size());
  Eigen::VectorXd line(n_rows), ramp(n_rows);
  Eigen::Index r = 0;
  for (int k = 0; k < nt; ++k) {
    const Still& s = sr.stills[static_cast<std::size_t>(k)];
    for (std::size_t j = 0; j < s.index.size(); ++j, ++r) {
      line(r) = drift_column(trials[static_cast<std::size_t>(k)], s.index[j], false);
      ramp(r) = drift_column(trials[static_cast<std::size_t>(k)], s.index[j], true);
    }
  }
  StructureOptions so;
  so.alpha = alpha;
  so.centre_segments = true;  // each trial's own zero offset (its segment's intercept)
  const StructureReport st = analyse_residual(sr.segments, {{"t", "time over the record", line},
                                                            {"t - t_contact", "time since the contact", ramp}},
                                              so);
  std::optional<TermScore> best;
  if (!st.terms.empty()) best = st.terms.front();
  const bool from_contact = best && best->name == "t - t_contact";
  for (Eigen::Index i = 0; i < n_rows; ++i) sr.rows[static_cast<std::size_t>(i)].column = from_contact ? ramp(i) : line(i);
  return {best, from_contact};
}

// Held out: fit on everything but each trial's later post-contact half,
// predict that half; per trial the RMS without (first) and with (second) the
// drift.
std::pair<Eigen::VectorXd, Eigen::VectorXd> held_out_drift(const std::vector<Row>& rows, int nt) {
  const DriftFit flat_early = fit_drift(rows, nt, false, true);
  const DriftFit slope_early = fit_drift(rows, nt, true, true);
  Eigen::VectorXd hb = Eigen::VectorXd::Zero(nt), ha = Eigen::VectorXd::Zero(nt), cnt = Eigen::VectorXd::Zero(nt);
  for (const auto& r : rows) {
    if (!r.late) continue;
    const double b = r.residual - flat_early.intercept(r.trial);
    const double a = r.residual - slope_early.intercept(r.trial) - slope_early.slope * r.column;
    hb(r.trial) += b * b;
    ha(r.trial) += a * a;
    cnt(r.trial) += 1.0;
  }
  std::vector<double> vb, va;
  for (int k = 0; k < nt; ++k)
    if (cnt(k) > 0) {
      vb.push_back(std::sqrt(hb(k) / cnt(k)));
      va.push_back(std::sqrt(ha(k) / cnt(k)));
    }
  return {detail::to_vector(vb), detail::to_vector(va)};
}

// Each trial's still residual after the drift fit `slope`.
std::vector<Eigen::VectorXd> residual_after_drift(const StillRows& sr, const DriftFit& slope) {
  std::vector<Eigen::VectorXd> after_segments;
  Eigen::Index r = 0;
  for (std::size_t k = 0; k < sr.segments.size(); ++k) {
    Eigen::VectorXd seg(sr.segments[k].size());
    for (Eigen::Index j = 0; j < seg.size(); ++j, ++r) {
      const Row& row = sr.rows[static_cast<std::size_t>(r)];
      seg(j) = row.residual - slope.intercept(static_cast<Eigen::Index>(k)) - slope.slope * row.column;
    }
    after_segments.push_back(seg);
  }
  return after_segments;
}

// The drift slope's SE: the residual SD over the drift column's spread about
// each trial's own mean (the intercepts absorb the rest), with the AR(1)
// effective sample size.
double drift_slope_se(const std::vector<Row>& rows, int nt, const DriftFit& slope, double rho1) {
  double sxx = 0.0;
  std::vector<double> sum(static_cast<std::size_t>(nt), 0.0), cnt(static_cast<std::size_t>(nt), 0.0);
  for (const auto& row : rows) {
    sum[static_cast<std::size_t>(row.trial)] += row.column;
    cnt[static_cast<std::size_t>(row.trial)] += 1.0;
  }
  for (const auto& row : rows) {
    const double m = sum[static_cast<std::size_t>(row.trial)] / std::max(cnt[static_cast<std::size_t>(row.trial)], 1.0);
    sxx += (row.column - m) * (row.column - m);
  }
  const double sigma = std::sqrt(slope.rss / std::max(static_cast<double>(rows.size()) - nt - 1.0, 1.0));
  const double inflate = std::sqrt((1.0 + std::max(rho1, 0.0)) / (1.0 - std::min(std::max(rho1, 0.0), 0.99)));
  return sxx > 0.0 ? sigma / std::sqrt(sxx) * inflate : kNaN;
}

// baseline_drift (diagnosis.h): effect or rejection into out, then what
// remains in the still parts.
void diagnose_baseline_drift(const std::vector<PlateTrial>& trials, const ForceplateStageOptions& o,
                             ForceplateDiagnosis& out) {
  const DecisionOptions& d = o.decision;
  const int nt = static_cast<int>(trials.size());
  StillRows sr = collect_still_rows(trials, o);
  const double noise = sr.noise_n;
  if (sr.post_trials < 2) {
    out.notes.push_back(fmt::format("forceplate: only {} trial(s) hold still after the contact; baseline drift "
                                    "cannot be tested",
                                    sr.post_trials));
    return;
  }
  const auto [best, from_contact] = choose_drift_column(trials, sr, d.alpha);
  const std::vector<Row>& rows = sr.rows;
  const auto [held_b, held_a] = held_out_drift(rows, nt);
  const DriftFit flat = fit_drift(rows, nt, false, false);
  const DriftFit slope = fit_drift(rows, nt, true, false);
  // rho1 of the drift model's residual, for the effective N.
  const std::vector<Eigen::VectorXd> after_segments = residual_after_drift(sr, slope);
  const double rho1 = autocorrelation(after_segments, 1)(0);
  const detail::Verdict v = detail::judge(held_b, held_a, 0.5 * noise, flat.rss, nt, slope.rss, nt + 1,
                                          static_cast<double>(rows.size()), rho1, Criterion::AICc, d);
  if (v.keep()) {
    Effect e;
    e.stage = "forceplate";
    e.name = "baseline_drift";
    e.evidence = fmt::format(
        "zeroed Fz where it must hold still correlates with {} (r = {:.2f} over {} samples in {} trials): "
        "a drift of {:.1f} N/s",
        best ? best->description : "time", best ? best->r : 0.0, rows.size(), nt, slope.slope);
    e.error_before = {{"still_rms_n", std::sqrt(flat.rss / static_cast<double>(rows.size()))},
                      {"heldout_still_rms_n", detail::rms(held_b)}};
    e.error_after = {{"still_rms_n", std::sqrt(slope.rss / static_cast<double>(rows.size()))},
                     {"heldout_still_rms_n", detail::rms(held_a)}};
    const double slope_se = drift_slope_se(rows, nt, slope, rho1);
    e.estimate = {{"drift_n_s", slope.slope}, {"drift_n_s_se", slope_se}};
    e.evidence += fmt::format(" +- {:.2f} N/s", slope_se);
    out.effects.push_back(std::move(e));
    out.correction.drift = true;
    out.correction.drift_from_contact = from_contact;
    out.correction.drift_n_s = slope.slope;
    // A whole-record line: the zeroing already removed its mean over the
    // quiet part, so the offset is what the intercepts agree on.
    out.correction.drift_offset_n = from_contact ? 0.0 : slope.intercept.mean();
  } else {
    out.rejected.push_back({"forceplate", "baseline_drift", v.reason("still-part RMS (N)", Criterion::AICc)});
  }
  // What remains in the still parts.
  const std::vector<Eigen::VectorXd>& left = out.correction.drift ? after_segments : sr.segments;
  Whiteness w = ljung_box(left, 20, 0, d.alpha);
  const double rms_left = std::sqrt((out.correction.drift ? slope.rss : flat.rss) / static_cast<double>(rows.size()));
  if (!w.white && rms_left > 2.0 * noise) {
    const PeriodicPeak pk = periodogram_peak(left, 1e-3, d.alpha, 2.0);
    out.remaining.push_back(
        {"forceplate", pk.significant ? "periodic_oscillation" : "structured_baseline",
         pk.significant
             ? fmt::format("the still parts of Fz oscillate at {:.1f} Hz ({:.1f} N amplitude, {:.0f} % of their "
                           "variance)",
                           pk.frequency_hz, pk.amplitude, 100.0 * pk.share)
             : fmt::format("the still parts of Fz are not flat ({:.1f} N RMS against {:.1f} N noise, rho1 = {:.2f}; "
                           "strongest frequency {:.1f} Hz)",
                           rms_left, noise, w.rho1(), pk.frequency_hz)});
  }
}

// The trials' free fall before contact over gravity: the inverse-variance
// mean of a / g and its SE (scatter beyond the stated SEs included).
struct FallCheck {
  double ratio = std::numeric_limits<double>::quiet_NaN(), se = std::numeric_limits<double>::quiet_NaN();
  int n = 0;
};
FallCheck mean_fall(const std::vector<PlateTrial>& trials, double gravity_m_s2) {
  double sw = 0.0, swx = 0.0, swx2 = 0.0;
  FallCheck f;
  for (const auto& t : trials) {
    if (!std::isfinite(t.fall_accel_m_s2) || !(t.fall_accel_se_m_s2 > 0.0)) continue;
    const double x = t.fall_accel_m_s2 / gravity_m_s2, w = std::pow(gravity_m_s2 / t.fall_accel_se_m_s2, 2);
    sw += w, swx += w * x, swx2 += w * x * x;
    ++f.n;
  }
  if (f.n == 0) return f;
  f.ratio = swx / sw;
  const double chi2_dof = f.n > 1 ? std::max((swx2 - swx * swx / sw) / (f.n - 1), 1.0) : 1.0;
  f.se = std::sqrt(chi2_dof / sw);
  return f;
}

// The plate impulse over the descent alone: from 10 ms before the contact to
// the impactor's deepest point, over the momentum the mat took from it
// there (m v_in + m g (t_max - t_c): impactor and mat top are at rest at the
// deepest point). The video times the descent (t_max - t_c); `scale` reads
// the force record's times x scale after the contact (1: the declared rate),
// so its window ends at t_c + scale (t_max - t_c). NaN without a deepest point.
double descent_balance(const PlateTrial& t, const PlateCorrection& c, double mass_kg, double g, double scale) {
  const Eigen::Index n = t.t_s.size();
  if (n < 10 || !std::isfinite(t.impact_velocity_m_s) || !std::isfinite(t.max_deformation_time_s) ||
      !(t.max_deformation_time_s > t.contact_time_s))
    return kNaN;
  const Eigen::VectorXd f = c.apply(t.t_s, t.fz_n, t.contact_time_s);
  const double descent_s = t.max_deformation_time_s - t.contact_time_s;
  // Within the record only (no force is read past its ends).
  const double t0 = std::max(t.contact_time_s - 0.010, t.t_s(0));
  const double t1 = std::min(t.contact_time_s + scale * descent_s, t.t_s(n - 1));
  const double impulse = trial::integrate(t.t_s, f, t0, t1);
  const double momentum = mass_kg * (t.impact_velocity_m_s + g * descent_s);
  return momentum > 0.0 ? impulse / momentum : kNaN;
}

// The force record's time base against the video's. A plate gain or a wrong
// declared mass scales the balance over the descent and over the whole
// contact alike, so their quotient is 1 whatever the gain; a force record
// whose sample rate is declared off by f_true / f_declared = s reads every
// impulse x s but also ends the descent's window at s times the video's
// descent, so the quotient moves (a window ending after the deepest point
// takes in the peak of the force). The mean quotient over trials, its SE,
// and the s (bisection over 1/4..4) that brings it to 1.
struct TimeBaseCheck {
  double quotient = kNaN, se = kNaN, scale = kNaN;
  int n = 0;
};
// Beyond this departure of the quotient from 1 (and 3 SE) the time base is
// named. On a sound record the mat's own momentum at the impactor's deepest
// point (a foam column is still moving there) and the deepest instant's
// error move it by a few per cent; a rate off by a quarter moves it by
// tens of per cent, and one off by less than about 8 % is not told from a
// gain (the measured spread: docs/diagnosis.md, "the force time base").
constexpr double kTimeBaseTolerance = 0.15;
TimeBaseCheck force_time_base(const std::vector<PlateTrial>& trials, const std::vector<double>& whole,
                              const PlateCorrection& c, double mass_kg, double g) {
  TimeBaseCheck out;
  auto mean_quotient = [&](double scale, std::vector<double>* each) {
    std::vector<double> q;
    for (std::size_t k = 0; k < trials.size() && k < whole.size(); ++k) {
      const double d = descent_balance(trials[k], c, mass_kg, g, scale);
      if (std::isfinite(d) && std::isfinite(whole[k]) && whole[k] > 0.0) q.push_back(d / whole[k]);
    }
    if (each) *each = q;
    return q.empty() ? kNaN : detail::to_vector(q).mean();
  };
  std::vector<double> q;
  out.quotient = mean_quotient(1.0, &q);
  out.n = static_cast<int>(q.size());
  if (out.n < 2) return out;
  out.se = detail::sample_sd(detail::to_vector(q)) / std::sqrt(static_cast<double>(out.n));
  double lo = 0.25, hi = 4.0;  // the quotient grows with the scale
  if (!(mean_quotient(lo, nullptr) < 1.0 && mean_quotient(hi, nullptr) > 1.0)) return out;
  for (int it = 0; it < 40; ++it) {
    const double mid = std::sqrt(lo * hi);
    (mean_quotient(mid, nullptr) < 1.0 ? lo : hi) = mid;
  }
  out.scale = std::sqrt(lo * hi);
  return out;
}

// With the fall at g, a balance over the descent unlike the whole contact's
// is not a gain but the force record's time base (its declared sample rate):
// named in `remaining` (true: nothing is to be corrected). Otherwise the
// force scale's evidence says the time base is not the cause.
bool name_force_time_base(const std::vector<PlateTrial>& trials, const TimeBaseCheck& time_base, double gain,
                          double se, Effect& e, ForceplateDiagnosis& out) {
  if (time_base.n < 2) return false;
  if (std::abs(time_base.quotient - 1.0) <= std::max(kTimeBaseTolerance, 3.0 * time_base.se)) {
    e.evidence += fmt::format("; the balance over the descent is {:.3f} +- {:.3f} times the whole contact's, as a "
                              "gain leaves it, so the force record's time base is not the cause",
                              time_base.quotient, time_base.se);
    return false;
  }
  const Eigen::VectorXd& ts = trials.front().t_s;
  const double rate_hz = ts.size() > 1 ? static_cast<double>(ts.size() - 1) / (ts(ts.size() - 1) - ts(0)) : kNaN;
  out.remaining.push_back(
      {"forceplate", "force_time_base",
       fmt::format("the plate's impulse is {:.1f} % {} the video's momentum (ratio {:.4f} +- {:.4f}), but its "
                   "balance over the descent (to the video's deepest point) is {:.3f} +- {:.3f} times its balance "
                   "over the whole contact ({} trials), where a plate gain or a wrong mass scales both alike: the "
                   "force record's time base is off, reading every impulse x f / f0 and ending the descent at the "
                   "wrong sample. The declared [forceplate] sample_rate_hz = {:.0f} Hz would be {:.0f} Hz for the "
                   "two to agree; nothing is corrected",
                   100.0 * std::abs(gain - 1.0), gain > 1.0 ? "above" : "below", gain, se, time_base.quotient,
                   time_base.se, time_base.n, rate_hz, rate_hz * time_base.scale)});
  return true;
}

// Impulse ratios that scatter between trials beyond 3 %: no constant gain
// explains them (left in the stage's remaining structure).
void note_impulse_scatter(const Eigen::VectorXd& rho, const std::vector<std::string>& ids, ForceplateDiagnosis& out) {
  const double scatter = detail::sample_sd(rho) / rho.mean();
  if (!(scatter > 0.03)) return;
  std::string per_trial;
  for (Eigen::Index i = 0; i < rho.size(); ++i)
    per_trial += fmt::format("{}{} {:.3f}", i ? ", " : "", ids[static_cast<std::size_t>(i)], rho(i));
  out.remaining.push_back({"forceplate", "impulse_scatter",
                           fmt::format("impulse/momentum scatters by {:.1f} % between trials ({}): no constant gain "
                                       "explains it",
                                       100.0 * scatter, per_trial)});
}

// force_scale (diagnosis.h): the plate's impulse against the video's
// momentum over trials, with the drift correction found so far.
void diagnose_force_scale(const std::vector<PlateTrial>& trials, const ForceplateStageOptions& o,
                          ForceplateDiagnosis& out) {
  const DecisionOptions& d = o.decision;
  std::vector<double> ratios, spreads, mat_momenta;
  std::vector<std::string> ids;
  int by_flight = 0;
  for (const auto& t : trials) {
    const ImpulseBalance b = impulse_balance(t, out.correction, o.impactor_mass_kg, o.gravity_m_s2);
    double r = b.ratio;
    if (std::isfinite(r)) {
      ++by_flight;
      spreads.push_back(b.spread);
      mat_momenta.push_back(b.mat_momentum_n_s);
    } else {
      r = impulse_ratio(t, out.correction, o.impactor_mass_kg, o.gravity_m_s2);
    }
    out.impulse_ratios.push_back(r);
    if (std::isfinite(r)) {
      ratios.push_back(r);
      ids.push_back(t.id);
    }
  }
  const auto nr = static_cast<Eigen::Index>(ratios.size());
  if (nr < 2) {
    out.notes.push_back(fmt::format("forceplate: impulse-momentum ratio available for {} trial(s) (no free flight "
                                    "after separation in the video, no still plate); force scale cannot be judged",
                                    nr));
    return;
  }
  const Eigen::VectorXd rho = detail::to_vector(ratios);
  const double gain = rho.mean();
  // Between-trial scatter, and the mat's momentum left in each trial's
  // balance (the ratio's spread over its flight window), both in the SE.
  const double mat_bound = spreads.empty() ? 0.0 : detail::rms(detail::to_vector(spreads));
  const double se = std::hypot(detail::sample_sd(rho), mat_bound) / std::sqrt(static_cast<double>(nr));
  Eigen::VectorXd before(nr), after(nr);
  for (Eigen::Index i = 0; i < nr; ++i) {
    before(i) = 100.0 * std::abs(rho(i) - 1.0);
    after(i) = 100.0 * std::abs(rho(i) / detail::mean_without(rho, i) - 1.0);
  }
  const double rss0 = (rho.array() - 1.0).square().sum(), rss1 = (rho.array() - gain).square().sum();
  const detail::Verdict v = detail::judge(before, after, 0.0, rss0, 0, rss1, 1, static_cast<double>(nr), 0.0,
                                          Criterion::AICc, d);
  const bool stands_out = std::abs(gain - 1.0) > std::max(o.min_scale_error, 3.0 * se);
  // An undefined criterion (two trials) cannot veto a gain under which
  // each trial's held-out error at least halves, as in the mat stage.
  const bool kept = v.keep() || (v.held_out.significant && !std::isfinite(v.ic.delta) &&
                                 paired_improvement(before, after, d.t_critical, 0.5, 0.0).significant);
  if (stands_out && kept) {
    Effect e;
    e.stage = "forceplate";
    e.name = "force_scale";
    e.evidence = fmt::format(
        "the plate's impulse over the contact is {:.1f} % {} the impactor's momentum change from video in every "
        "trial ({:.4f} to {:.4f} over {}): plate gain {:.4f} +- {:.4f}",
        100.0 * std::abs(gain - 1.0), gain > 1.0 ? "above" : "below", rho.minCoeff(), rho.maxCoeff(), nr, gain, se);
    e.error_before = {{"impulse_error_pct_rms", detail::rms(before)}, {"impulse_error_pct_max", detail::max_abs(before)}};
    e.error_after = {{"impulse_error_pct_rms", detail::rms(after)}, {"impulse_error_pct_max", detail::max_abs(after)}};
    e.estimate = {{"gain", gain}, {"gain_se", se}};
    if (!mat_momenta.empty())
      e.estimate.push_back({"mat_momentum_bound_n_s", detail::rms(detail::to_vector(mat_momenta))});
    e.evidence += fmt::format("; balance ends in the impactor's free flight after separation in {} of {} trials",
                              by_flight, nr);
    // The balance weighs the plate's gain times the true mass against the
    // declared mass: a gain error and a wrong declared mass give the same
    // ratio (and so does the plate's weighing of the impactor at rest), so
    // both are named.
    e.evidence += fmt::format(
        "; equally an impactor of {:.2f} kg where the manifest declares {:.2f} kg (impulse against momentum "
        "cannot tell a plate gain from a wrong declared mass: weigh the impactor, or check the plate's calibration)",
        gain * o.impactor_mass_kg, o.impactor_mass_kg);
    e.estimate.push_back({"impactor_mass_if_gain_is_1_kg", gain * o.impactor_mass_kg});
    // A third cause the fall itself tells apart: a video time base off by
    // f / f0 reads every video velocity x f / f0 (so the balance reads a
    // gain near f0 / f) and the free fall x (f / f0)^2, where a plate gain or
    // a wrong mass leaves the fall at g. A fall off g in the direction the
    // balance points names the time base (and the rate that makes the fall
    // free); then nothing is corrected, the velocities being wrong.
    const FallCheck fall = mean_fall(trials, o.gravity_m_s2);
    if (fall.n > 0) {
      const bool at_g = std::abs(fall.ratio - 1.0) <= 3.0 * fall.se + 0.01;
      if (!at_g && (fall.ratio < 1.0) == (gain > 1.0)) {
        out.remaining.push_back(
            {"forceplate", "video_time_base",
             fmt::format("the plate's impulse is {:.1f} % {} the video's momentum (ratio {:.4f} +- {:.4f}) and the "
                         "video's free fall is {:.4f} +- {:.4f} g: a video time base that is off makes both (the "
                         "velocities x f / f0, the fall x (f / f0)^2); a plate gain or a wrong mass would leave the "
                         "fall at 1 g, a guide's friction would slow the fall but not move the impulse. The declared "
                         "[video] frame_rate_hz = {:g} Hz would be {:.0f} Hz for a free fall; every impact velocity "
                         "and video time is off with it, so nothing is corrected",
                         100.0 * std::abs(gain - 1.0), gain > 1.0 ? "above" : "below", gain, se, fall.ratio,
                         fall.se, o.frame_rate_hz, o.frame_rate_hz / std::sqrt(fall.ratio))});
        return;
      }
      e.estimate.push_back({"fall_over_gravity", fall.ratio});
      e.estimate.push_back({"fall_over_gravity_se", fall.se});
      e.evidence += fmt::format("; the video's free fall is {:.4f} +- {:.4f} g over {} trials, so the video's time "
                                "base is not the cause",
                                fall.ratio, fall.se, fall.n);
    }
    const TimeBaseCheck time_base =
        force_time_base(trials, out.impulse_ratios, out.correction, o.impactor_mass_kg, o.gravity_m_s2);
    if (name_force_time_base(trials, time_base, gain, se, e, out)) return;
    out.effects.push_back(std::move(e));
    out.correction.gain = gain;
  } else if (stands_out) {
    out.rejected.push_back({"forceplate", "force_scale", v.reason("impulse error (%)", Criterion::AICc)});
  } else {
    out.rejected.push_back({"forceplate", "force_scale",
                            fmt::format("impulse/momentum {:.4f} +- {:.4f}: within max({:.0f} %, 3 SE) of 1", gain, se,
                                        100.0 * o.min_scale_error)});
  }
  note_impulse_scatter(rho, ids, out);
}

}  // namespace

ForceplateDiagnosis diagnose_forceplate(const std::vector<PlateTrial>& trials, const ForceplateStageOptions& o) {
  ForceplateDiagnosis out;
  if (trials.empty()) return out;
  diagnose_baseline_drift(trials, o, out);
  diagnose_force_scale(trials, o, out);
  return out;
}

}  // namespace dropfit::diagnosis
