// The synchronisation stage of the loop: a constant video-force clock offset
// against the declared relation (see diagnosis.h).
#include <fmt/format.h>

#include <algorithm>
#include <cmath>

#include "diagnosis/diagnosis.h"
#include "diagnosis/internal.h"

namespace dropfit::diagnosis {

SyncDiagnosis diagnose_sync(const std::vector<trial::TrialResult>& trials, const SyncStageOptions& options) {
  SyncDiagnosis out;
  std::vector<double> primary, independent;
  std::vector<std::string> ids;
  for (const auto& t : trials) {
    if (!t.accepted || !std::isfinite(t.video_offset_s)) continue;
    primary.push_back(t.video_offset_s);
    independent.push_back(t.video_offset_trajectory_s);
    ids.push_back(t.id);
  }
  const auto n = static_cast<Eigen::Index>(primary.size());
  if (n < 2) {
    if (n == 1) out.offset_s = 0.0;
    out.notes.push_back(fmt::format("sync: {} trial(s) with a clock-offset estimate; synchronisation cannot be "
                                    "judged against held-out trials",
                                    n));
    return out;
  }
  const Eigen::VectorXd d = detail::to_vector(primary);
  Eigen::VectorXd e = detail::to_vector(independent);
  const bool have_independent = e.allFinite();
  // Without the independent estimate every trial, the held-out test uses the
  // other trials' contact-instant estimates.
  if (!have_independent) e = d;

  const double mean = d.mean();
  const double spread = detail::sample_sd(d);
  out.offset_se_s = std::hypot(spread / std::sqrt(static_cast<double>(n)), options.systematic_s);
  out.declared_offset_s = 0.0;
  out.offset_s = out.declared_offset_s;

  // 1-2. Structure: the declared relation's residual is the estimates
  // themselves; a common offset is the one candidate.
  const double ms = 1000.0;
  bool stands_out = std::abs(mean) > std::max(options.min_offset_s, 3.0 * out.offset_se_s);
  // Beyond the onset lag, or supported by the trajectory estimate.
  std::string lag_reason;
  if (stands_out && std::abs(mean) <= 2.0 * options.onset_lag_s) {
    bool supported = false;
    if (have_independent) {
      const double te = e.mean();
      const double te_se = std::hypot(detail::sample_sd(e) / std::sqrt(static_cast<double>(n)), options.systematic_s);
      supported = std::abs(te) > std::max(options.min_offset_s, 3.0 * te_se) && te * mean > 0.0;
      lag_reason = fmt::format(
          "mean offset {:.2f} ms from the contact instant is within 2 x {:.1f} ms of the plate's onset lag and the "
          "contact-phase trajectory estimate ({:.2f} +- {:.2f} ms) does not support it",
          ms * mean, ms * options.onset_lag_s, ms * te, ms * te_se);
    } else {
      lag_reason = fmt::format(
          "mean offset {:.2f} ms from the contact instant is within 2 x {:.1f} ms of the plate's onset lag, and no "
          "trajectory estimate is available to support it",
          ms * mean, ms * options.onset_lag_s);
    }
    if (!supported) stands_out = false;
  }

  // 3. Held out: each trial's independent estimate against the declared
  // relation (before) and the offset from the other trials (after).
  Eigen::VectorXd before(n), after(n);
  for (Eigen::Index i = 0; i < n; ++i) {
    before(i) = ms * std::abs(e(i) - out.declared_offset_s);
    after(i) = ms * std::abs(e(i) - detail::mean_without(d, i));
  }
  const double rss0 = d.squaredNorm(), rss1 = (d.array() - mean).square().sum();
  const detail::Verdict v = detail::judge(before, after, ms * options.systematic_s, rss0, 0, rss1, 1,
                                          static_cast<double>(n), 0.0, Criterion::AICc, options.decision);
  if (stands_out && v.keep()) {
    Effect eff;
    eff.stage = "sync";
    eff.name = "time_offset";
    eff.evidence = fmt::format(
        "video and force clocks disagree by {:.2f} ms (+- {:.2f} ms) in every trial ({:.2f} to {:.2f} ms over {}); "
        "the {} agrees within {:.2f} ms once it is applied (a delay of the force channel nobody declared, e.g. an "
        "amplifier low-pass, 0.225 ms x 1 kHz / corner for a 2nd-order Butterworth, reads as clock offset here: "
        "drop data cannot tell the two apart; [forceplate] lowpass_hz declares it)",
        ms * mean, ms * out.offset_se_s, ms * d.minCoeff(), ms * d.maxCoeff(), n,
        have_independent ? "independent contact-phase trajectory estimate" : "held-out trials' estimate",
        detail::max_abs(after));
    eff.error_before = {{"offset_error_ms_rms", detail::rms(before)}, {"offset_error_ms_max", detail::max_abs(before)}};
    eff.error_after = {{"offset_error_ms_rms", detail::rms(after)}, {"offset_error_ms_max", detail::max_abs(after)}};
    eff.estimate = {{"video_offset_ms", ms * mean}, {"video_offset_se_ms", ms * out.offset_se_s}};
    // The contact instant carries the plate's onset lag; the trajectory
    // estimate does not (but reads the mat's accelerated mass): both shown.
    if (have_independent) eff.estimate.push_back({"video_offset_trajectory_ms", ms * e.mean()});
    out.effects.push_back(std::move(eff));
    out.offset_s = mean;
  } else if (stands_out) {
    out.rejected.push_back({"sync", "time_offset", v.reason("clock-offset error (ms)", Criterion::AICc)});
  } else if (!lag_reason.empty()) {
    out.rejected.push_back({"sync", "time_offset", lag_reason});
  } else {
    out.rejected.push_back(
        {"sync", "time_offset",
         fmt::format("mean offset {:.3f} ms is within max({:.2f} ms, 3 x {:.3f} ms) of the declared relation",
                     ms * mean, ms * options.min_offset_s, ms * out.offset_se_s)});
  }

  // 4. A constant offset cannot explain estimates that scatter between
  // trials by more than a frame.
  const double jitter = detail::sample_sd(d);
  if (jitter > std::max(2.0 * options.min_offset_s, 3.0 * options.systematic_s))
    out.remaining.push_back({"sync", "offset_jitter",
                             fmt::format("the clock offset varies between trials (SD {:.2f} ms, {:.2f} to {:.2f} ms): "
                                         "no constant offset explains it",
                                         ms * jitter, ms * d.minCoeff(), ms * d.maxCoeff())});
  return out;
}

}  // namespace dropfit::diagnosis
