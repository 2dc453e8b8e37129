// The session screen (diagnosis.h, screen_trials): trials that cannot be
// measurements of the drops they claim to be, rejected before any fit.
#include <fmt/format.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <limits>

#include "core/median.h"
#include "diagnosis/diagnosis.h"
#include "diagnosis/internal.h"

namespace dropfit::diagnosis {
namespace {

void reject(SessionData& state, std::size_t i, const std::string& reason, ScreenResult& out) {
  trial::TrialResult& r = state.trials[i].result;
  r.accepted = false;
  r.reject_reason = r.reject_reason.empty() ? reason : r.reject_reason + "; " + reason;
  if (i < state.fit_data.size()) state.fit_data[i].accepted = false;
  out.rejected.push_back({r.id, reason});
}

bool same_record(const forceplate::ForceTrial& a, const forceplate::ForceTrial& b) {
  const Eigen::MatrixXd& x = a.plate.f_n;
  const Eigen::MatrixXd& y = b.plate.f_n;
  if (x.rows() != y.rows() || x.cols() != y.cols() || x.rows() == 0) return false;
  return ((x - y).array().abs() <= 1e-9 * (1.0 + x.array().abs())).all();
}


// How far a trial's whole-contact restitution (impulse against its own
// video's momentum) lies outside the 0-1 a rebound allows.
double restitution_miss(const trial::TrialResult& r) {
  return std::isfinite(r.restitution) ? std::abs(r.restitution - std::clamp(r.restitution, 0.0, 1.0))
                                      : std::numeric_limits<double>::infinity();
}

// One recording under two trial ids (copied files, or a folder read twice):
// the later ones rejected. When the earlier trial was already rejected and
// the record's impulse fits its video worse than the later one's (another
// trial's force file copied into its folder), the record is the later
// one's: the later trial stands and the earlier one's reason says whose
// record it holds.
void reject_duplicates(SessionData& state, ScreenResult& out) {
  for (std::size_t i = 0; i < state.trials.size(); ++i) {
    if (!state.trials[i].force || !state.trials[i].result.accepted) continue;
    for (std::size_t j = 0; j < i; ++j) {
      if (!state.trials[j].force || !same_record(*state.trials[i].force, *state.trials[j].force)) continue;
      if (!state.trials[j].result.accepted &&
          restitution_miss(state.trials[j].result) > restitution_miss(state.trials[i].result)) {
        reject(state, j,
               fmt::format("its force record is {}'s, sample for sample, and fits {}'s video: the force file "
                           "belongs to that drop",
                           state.trials[i].result.id, state.trials[i].result.id),
               out);
        continue;
      }
      reject(state, i,
             fmt::format("its force record is {}'s, sample for sample: one drop counted twice (two trials reading "
                         "one recording)",
                         state.trials[j].result.id),
             out);
      break;
    }
  }
}

// Each trial's impulse-momentum balance in the impactor's free flight and
// its own uncertainty: the mat's momentum left in the balance (its spread
// over the flight window) and the impact velocity's (95 % half-width / 1.96).
struct BalanceRow {
  std::size_t index;
  double ratio, sd;
};
std::vector<BalanceRow> balance_rows(const SessionData& state) {
  std::vector<BalanceRow> rows;
  for (const PlateTrial& p : plate_trials(state, 0.0)) {
    const ImpulseBalance b = impulse_balance(p, PlateCorrection{}, state.impactor_mass_kg, state.gravity_m_s2);
    if (!std::isfinite(b.ratio)) continue;
    std::size_t index = 0;
    while (index < state.trials.size() && state.trials[index].result.id != p.id) ++index;
    const trial::TrialResult& r = state.trials[index].result;
    const double v_sd = std::isfinite(r.impact_velocity_ci_m_s) && r.impact_velocity_m_s > 0.0
                            ? r.impact_velocity_ci_m_s / 1.96 / r.impact_velocity_m_s
                            : 0.0;
    rows.push_back({index, b.ratio, std::hypot(b.spread, v_sd)});
  }
  return rows;
}

// Each trial's balance against the other trials' median: the plate's gain
// and the declared mass are the session's, so they move every trial alike
// (the loop's force_scale); one trial alone far off has a fault of its own.
void reject_impulse_outliers(SessionData& state, const ScreenOptions& o, ScreenResult& out) {
  const std::vector<BalanceRow> rows = balance_rows(state);
  if (rows.size() < 3) {
    out.notes.push_back(fmt::format("screen: impulse balance in free flight for {} trial(s); trials not compared",
                                    rows.size()));
    return;
  }
  std::vector<std::size_t> outliers;
  for (std::size_t k = 0; k < rows.size(); ++k) {
    std::vector<double> others;
    for (std::size_t m = 0; m < rows.size(); ++m)
      if (m != k) others.push_back(rows[m].ratio);
    const double centre = median(others);
    std::vector<double> dev;
    for (double r : others) dev.push_back(std::abs(r - centre));
    const double scatter = 1.4826 * median(dev);
    const double tol = std::max(o.min_tolerance, o.sd_factor * std::hypot(rows[k].sd, scatter));
    const double off = rows[k].ratio / centre - 1.0;
    if (std::abs(off) > tol) {
      outliers.push_back(k);
      reject(state, rows[k].index,
             fmt::format("impulse against momentum {:.3f} where the session's other trials give {:.3f} ({:+.1f} %, "
                         "allowed +-{:.1f} % from this trial's mat momentum, its velocity interval and the others' "
                         "scatter): a fault of this trial's own force or video record (a channel, a second impact, "
                         "a wrong frame count), not the plate's gain or the declared mass, which all trials share",
                         rows[k].ratio, centre, 100.0 * off, 100.0 * tol),
             out);
    }
  }
}

// One vertical channel's sensitivity off by e: that channel's share p of
// Fz reads (1 + e) p, so Fz is off by e p and the vertical sensors' twist
// Fz1 - Fz2 + Fz3 - Fz4 (zero on a rigid plate with matched sensors) is
// +-e p of Fz, + for Fz1 and Fz3, - for Fz2 and Fz4: the impulse against
// the momentum is then 1 + twist (Fz1, Fz3) or 1 - twist (Fz2, Fz4) trial
// by trial, following each trial's twist as the landing point moves the
// share. A plate's own twist (sensors that do not share the load as a
// rigid plate would: real plates show several per cent) leaves the sum Fz
// right and the balance at 1; a plate gain or a wrong declared mass moves
// every trial's balance alike, whatever its twist. So the trials are
// rejected when the session's twist is beyond the 1 % a plate gain may be
// before the loop names it, the balances depart from 1 beyond their
// uncertainty, and each trial's balance is 1 +- its twist within 4 of its
// SDs. The channel is the one of the pair whose gain error e = twist / p
// stays the same from trial to trial (the landing points differ a little);
// both are named when they cannot be told apart.
void reject_channel_gain(SessionData& state, const ScreenOptions& o, ScreenResult& out) {
  constexpr double kTolerableTwist = 0.01;
  struct Row {
    BalanceRow balance;
    double twist;
    std::array<double, 4> shares;
  };
  std::vector<Row> rows;
  for (const BalanceRow& b : balance_rows(state)) {
    const auto& force = state.trials[b.index].force;
    if (!state.trials[b.index].result.accepted || !force || !std::isfinite(force->twist_fraction)) continue;
    rows.push_back({b, force->twist_fraction, force->vertical_shares});
  }
  if (rows.size() < 3) return;
  std::vector<double> twists;
  for (const Row& r : rows) twists.push_back(r.twist);
  const double twist = median(twists);
  if (!(std::abs(twist) > kTolerableTwist)) return;
  double chi2_one = 0.0;  // the balances against 1: a plate's own twist
  for (const Row& r : rows) chi2_one += std::pow((r.balance.ratio - 1.0) / r.balance.sd, 2);
  if (!(chi2_one > o.sd_factor * o.sd_factor * static_cast<double>(rows.size()))) return;
  // sign +1: Fz1 or Fz3; -1: Fz2 or Fz4.
  for (int sign : {1, -1}) {
    bool fits = true;
    for (const Row& r : rows)
      fits = fits && std::abs(r.balance.ratio - 1.0 - sign * r.twist) <= o.sd_factor * r.balance.sd;
    if (!fits) continue;
    const std::array<int, 2> pair = sign > 0 ? std::array<int, 2>{0, 2} : std::array<int, 2>{1, 3};
    std::array<double, 2> gain{}, spread{};
    for (int k = 0; k < 2; ++k) {
      std::vector<double> e;
      // The channel's share as read is (1 + e) p; the twist, e p for
      // Fz1 and Fz3, -e p for Fz2 and Fz4 (fractions of the Fz read).
      for (const Row& r : rows)
        e.push_back(sign * r.twist / (r.shares[static_cast<std::size_t>(pair[k])] - sign * r.twist));
      gain[k] = median(e);
      std::vector<double> dev;
      for (double v : e) dev.push_back(std::abs(v - gain[k]));
      spread[k] = 1.4826 * median(dev) / std::abs(gain[k]);
    }
    auto says = [&](int k) {
      return fmt::format("Fz{} reads {:.1f} % {}", pair[k] + 1, 100.0 * std::abs(gain[k]), gain[k] > 0 ? "high" : "low");
    };
    const int best = spread[0] <= spread[1] ? 0 : 1;
    const std::string channel =
        spread[best] < 0.5 * spread[1 - best]
            ? fmt::format("{} (its gain error stays within {:.1f} % of itself from trial to trial; as {}, within "
                          "{:.1f} %)",
                          says(best), 100.0 * spread[best], says(1 - best), 100.0 * spread[1 - best])
            : fmt::format("{} or {} (the landing points do not tell the two apart)", says(0), says(1));
    for (const Row& r : rows)
      reject(state, r.balance.index,
             fmt::format("one vertical channel's sensitivity is off: the vertical sensors' twist Fz1 - Fz2 + Fz3 - "
                         "Fz4 is {:+.2f} % of Fz and the impulse against the momentum {:.4f} (+- {:.4f}), as a "
                         "channel reading {} makes them (the session's twist {:+.2f} %, beyond the {:.0f} % a plate "
                         "gain may be): {}; Fz is off by the twist, differently in each trial, which no plate gain "
                         "or mass corrects",
                         100.0 * r.twist, r.balance.ratio, r.balance.sd,
                         sign * twist > 0 ? "high" : "low", 100.0 * twist, 100.0 * kTolerableTwist, channel),
             out);
    return;
  }
}

// A screen reason from the contact-height regression (empty when none).
std::string height_reason(const ContactHeightCheck& h, const SessionData& state, double floor_m, double sd_factor) {
  if (!h.ok || std::abs(h.dh_m) <= std::max(floor_m, sd_factor * h.se_m)) return {};
  std::string surface;
  for (const auto& t : state.trials)
    if (t.result.accepted && std::isfinite(t.result.surface_rest_z_m)) {
      surface = fmt::format("; the surface markers rest {:+.1f} mm from the declared mat top",
                            1e3 * (t.result.surface_rest_z_m - state.mat_top_z_m));
      break;
    }
  return fmt::format(
      "the trials' clock offsets change with 1 / impact speed as a contact height {:.1f} +- {:.1f} mm off makes them "
      "(offset {:.2f} ms common to all, plus {:+.1f} mm / v; a clock offset is the same in every trial): the face "
      "reaches the mat top {:.1f} mm {} the plate feels it, so the face height (base markers less [impactor] "
      "base_marker_height_m = {:.4g} m) or [forceplate] mat_top_z_m = {:.4g} m is wrong{}; the impact velocity, "
      "deformation and clock offset all depend on it",
      h.dh_m * 1e3, h.se_m * 1e3, 1e3 * h.offset_s, h.dh_m * 1e3, std::abs(h.dh_m) * 1e3,
      h.dh_m < 0.0 ? "before" : "after", state.base_marker_height_m, state.mat_top_z_m, surface);
}

void reject_height_inconsistency(SessionData& state, const ScreenOptions& o, ScreenResult& out) {
  const std::string reason = height_reason(contact_height_check(state.trials), state, o.min_height_error_m,
                                           o.height_sd_factor);
  if (reason.empty()) return;
  for (std::size_t i = 0; i < state.trials.size(); ++i)
    if (state.trials[i].result.accepted && std::isfinite(state.trials[i].result.video_offset_s))
      reject(state, i, reason, out);
}

}  // namespace

ContactHeightCheck contact_height_check(const std::vector<TrialState>& trials) {
  ContactHeightCheck h;
  std::vector<double> x, y;
  for (const auto& t : trials) {
    const trial::TrialResult& r = t.result;
    if (!r.accepted || !std::isfinite(r.video_offset_s) || !(r.impact_velocity_m_s > 0.0)) continue;
    x.push_back(1.0 / r.impact_velocity_m_s);
    y.push_back(r.video_offset_s);
  }
  h.n = static_cast<int>(x.size());
  const detail::LineFit line = detail::fit_line(x, y);
  if (!line.ok) return h;
  h.dh_m = line.slope;
  h.offset_s = line.intercept;
  h.se_m = line.slope_se;
  h.ok = true;
  return h;
}

std::string contact_height_reason(const SessionData& state, double floor_m, double sd_factor) {
  return height_reason(contact_height_check(state.trials), state, floor_m, sd_factor);
}

ScreenResult screen_trials(SessionData& state, const ScreenOptions& options) {
  ScreenResult out;
  reject_duplicates(state, out);
  reject_channel_gain(state, options, out);
  reject_impulse_outliers(state, options, out);
  reject_height_inconsistency(state, options, out);
  return out;
}

}  // namespace dropfit::diagnosis
