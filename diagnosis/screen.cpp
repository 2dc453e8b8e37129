// The session screen (diagnosis.h, screen_trials): trials that cannot be
// measurements of the drops they claim to be, rejected before any fit.
#include <fmt/format.h>

#include <algorithm>
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


// One recording under two trial ids (copied files, or a folder read twice):
// the later ones rejected.
void reject_duplicates(SessionData& state, ScreenResult& out) {
  for (std::size_t i = 0; i < state.trials.size(); ++i) {
    if (!state.trials[i].force || !state.trials[i].result.accepted) continue;
    for (std::size_t j = 0; j < i; ++j) {
      if (!state.trials[j].force || !same_record(*state.trials[i].force, *state.trials[j].force)) continue;
      reject(state, i,
             fmt::format("its force record is {}'s, sample for sample: one drop counted twice (two trials reading "
                         "one recording)",
                         state.trials[j].result.id),
             out);
      break;
    }
  }
}

// Each trial's impulse-momentum balance in the impactor's free flight
// against the other trials' median: the plate's gain and the declared mass
// are the session's, so they move every trial alike (the loop's
// force_scale); one trial alone far off has a fault of its own.
void reject_impulse_outliers(SessionData& state, const ScreenOptions& o, ScreenResult& out) {
  const std::vector<PlateTrial> plates = plate_trials(state, 0.0);
  struct Row {
    std::size_t index;
    double ratio, sd;
  };
  std::vector<Row> rows;
  for (const PlateTrial& p : plates) {
    const ImpulseBalance b = impulse_balance(p, PlateCorrection{}, state.impactor_mass_kg, state.gravity_m_s2);
    if (!std::isfinite(b.ratio)) continue;
    std::size_t index = 0;
    while (index < state.trials.size() && state.trials[index].result.id != p.id) ++index;
    const trial::TrialResult& r = state.trials[index].result;
    // The ratio's own uncertainty: the mat's momentum left in the balance
    // (its spread over the flight window) and the impact velocity's
    // (95 % half-width / 1.96).
    const double v_sd = std::isfinite(r.impact_velocity_ci_m_s) && r.impact_velocity_m_s > 0.0
                            ? r.impact_velocity_ci_m_s / 1.96 / r.impact_velocity_m_s
                            : 0.0;
    rows.push_back({index, b.ratio, std::hypot(b.spread, v_sd)});
  }
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
  reject_impulse_outliers(state, options, out);
  reject_height_inconsistency(state, options, out);
  return out;
}

}  // namespace dropfit::diagnosis
