#pragma once
// Helpers shared by the diagnosis stages (not part of the public API).
#include <fmt/format.h>

#include <Eigen/Core>
#include <algorithm>
#include <cmath>
#include <string>
#include <vector>

#include "core/line_fit.h"
#include "diagnosis/diagnosis.h"

namespace dropfit::diagnosis::detail {

// The outcome of the two tests every candidate faces.
struct Verdict {
  PairedImprovement held_out;
  ModelComparison ic;
  bool keep() const { return held_out.significant && ic.larger_supported; }
  // Why it was not kept, in words.
  std::string reason(const std::string& error_name, Criterion criterion) const {
    std::string r;
    if (!held_out.significant)
      r = fmt::format("held-out {} {:.3g} -> {:.3g} (mean drop {:.3g}, t = {:.1f}): not beyond noise", error_name,
                      held_out.mean_before, held_out.mean_after, held_out.mean_drop, held_out.t);
    if (!ic.larger_supported) {
      if (!r.empty()) r += "; ";
      if (std::isfinite(ic.delta))
        r += fmt::format("{} change {:+.1f} on N_eff = {:.0f}: not supported", criterion_name(criterion), ic.delta,
                         ic.n_eff);
      else
        r += fmt::format("{} undefined on N_eff = {:.0f} for {} parameters (residual too correlated)",
                         criterion_name(criterion), ic.n_eff, ic.larger.k);
    }
    return r;
  }
};

inline Verdict judge(const Eigen::VectorXd& held_before, const Eigen::VectorXd& held_after, double min_absolute,
                     double rss_small, int k_small, double rss_large, int k_large, double n, double rho1,
                     Criterion criterion, const DecisionOptions& d) {
  Verdict v;
  v.held_out = paired_improvement(held_before, held_after, d.t_critical, d.min_relative, min_absolute);
  v.ic = compare_models(rss_small, k_small, rss_large, k_large, n, rho1, criterion, d.ic_min_drop);
  return v;
}

inline double rms(const Eigen::VectorXd& v) {
  return v.size() > 0 ? std::sqrt(v.squaredNorm() / static_cast<double>(v.size())) : 0.0;
}

inline double max_abs(const Eigen::VectorXd& v) { return v.size() > 0 ? v.cwiseAbs().maxCoeff() : 0.0; }

inline Eigen::VectorXd to_vector(const std::vector<double>& v) {
  return Eigen::Map<const Eigen::VectorXd>(v.data(), static_cast<Eigen::Index>(v.size()));
}

// Mean of all but element i.
inline double mean_without(const Eigen::VectorXd& v, Eigen::Index i) {
  if (v.size() < 2) return v.size() == 1 ? v(0) : 0.0;
  return (v.sum() - v(i)) / static_cast<double>(v.size() - 1);
}

// The least-squares line (core/line_fit.h).
using dropfit::fit_line;
using dropfit::LineFit;

inline double sample_sd(const Eigen::VectorXd& v) {
  if (v.size() < 2) return 0.0;
  return std::sqrt((v.array() - v.mean()).square().sum() / static_cast<double>(v.size() - 1));
}

// The sync verdict told what the force-channel low-pass profile found: a
// named filter's lag is the force channel's (the offset, judged on contacts
// the filtered model placed, is the clock's); an unidentified one leaves
// the lag ambiguous, and the clock offsets it allows are reported
// (diagnosis/lowpass_stage.cpp).
void attribute_lag(SyncDiagnosis& sync, const LowpassDiagnosis& lowpass, double min_ambiguity_s);

}  // namespace dropfit::diagnosis::detail
