#include "pipeline/contact_height.h"

#include <fmt/format.h>

#include <algorithm>
#include <cmath>
#include <vector>

#include "core/median.h"
#include "pipeline/pipeline.h"
#include "trial/trial.h"

namespace dropfit::pipeline {
namespace {

// What the correction is judged by: the accepted trials' clock offsets
// (their SD, ms), the height their 1 / speed trend implies (mm), and the
// final lumped model's held-out force and travel errors.
diagnosis::ErrorSet contact_errors(const SessionState& s) {
  std::vector<double> offsets;
  for (const auto& t : s.trials)
    if (t.result.accepted && std::isfinite(t.result.video_offset_s)) offsets.push_back(t.result.video_offset_s);
  double mean = 0.0, ss = 0.0;
  for (double o : offsets) mean += o / static_cast<double>(offsets.size());
  for (double o : offsets) ss += (o - mean) * (o - mean);
  const double sd = offsets.size() > 1 ? std::sqrt(ss / static_cast<double>(offsets.size() - 1)) : 0.0;
  const diagnosis::ContactHeightCheck h = diagnosis::contact_height_check(s.trials);
  diagnosis::ErrorSet e = {{"offset_sd_ms", 1e3 * sd}, {"contact_height_trend_mm", h.ok ? 1e3 * h.dh_m : 0.0}};
  if (const fitting::FitResult* f = s.final_fit()) {
    double force = 0.0, travel = 0.0;
    int n = 0;
    for (const auto& t : f->trials) {
      if (t.train || !std::isfinite(t.comparison.rms_force_pct_peak) || !std::isfinite(t.rms_impactor_mm)) continue;
      force += t.comparison.rms_force_pct_peak, travel += t.rms_impactor_mm, ++n;
    }
    if (n > 0) {
      e.emplace_back("heldout_force_rms_pct_peak", force / n);
      e.emplace_back("heldout_impactor_rms_mm", travel / n);
    }
  }
  return e;
}

}  // namespace

std::optional<MatTopCorrection> confirmed_mat_top(const SessionState& state) {
  if (!state.loop) return std::nullopt;
  MatTopCorrection c;
  c.declared_m = state.mat_top_z_m;
  c.trend = diagnosis::contact_height_check(state.trials);
  if (!c.trend.ok || std::abs(c.trend.dh_m) <= std::max(0.005, 4.0 * c.trend.se_m)) return std::nullopt;
  std::vector<double> rest;
  for (const auto& t : state.trials)
    if (t.result.accepted && std::isfinite(t.result.surface_rest_z_m)) rest.push_back(t.result.surface_rest_z_m);
  c.surface_m = median(rest);
  if (!std::isfinite(c.surface_m)) return std::nullopt;
  const double off_m = c.surface_m - c.declared_m;
  // Within the trial stage's reach the surface markers are already the mat top.
  if (std::abs(off_m) <= trial::TrialOptions{}.max_surface_reference_m) return std::nullopt;
  if (std::abs(off_m - c.trend.dh_m) > std::max(0.002, 3.0 * c.trend.se_m)) return std::nullopt;
  return c;
}

diagnosis::Effect mat_top_effect(const MatTopCorrection& c, const SessionState& before, const SessionState& after) {
  const std::string evidence = fmt::format(
      "the declared mat top ([forceplate] mat_top_z_m = {:.4f} m) is {:.1f} mm from where the surface markers rest "
      "({:.4f} m), and the trials' clock offsets change with 1 / impact speed as a contact height {:.1f} +- {:.1f} mm "
      "off makes them: both witnesses agree, so every trial was measured again from the surface markers' height "
      "(the session folder unchanged)",
      c.declared_m, 1e3 * (c.surface_m - c.declared_m), c.surface_m, 1e3 * c.trend.dh_m, 1e3 * c.trend.se_m);
  return {.stage = "sync",
          .name = "contact_height",
          .evidence = evidence,
          .error_before = contact_errors(before),
          .error_after = contact_errors(after),
          .estimate = {{"mat_top_declared_m", c.declared_m},
                       {"mat_top_used_m", c.surface_m},
                       {"contact_height_trend_mm", 1e3 * c.trend.dh_m},
                       {"contact_height_trend_se_mm", 1e3 * c.trend.se_m}}};
}

}  // namespace dropfit::pipeline
