#pragma once
// Calibrations of Model 6's stated uncertainties against what the session
// itself shows (plain values in, plain values out; no file I/O).
//
// Prediction intervals: each held-out trial's measured peak force, time to
// peak and largest travel against its prediction is a check of the stated
// interval that carries only the measurement's noise. A trial's model
// discrepancy is scaled by what the OTHER held-out trials show (leave one
// out: a trial's own error never sets its own interval), never below the
// training trials' misfit it starts from.
//
// Clock offsets: the clock offset is one number per session, so per-trial
// offsets scattering beyond their SEs about their weighted mean (a Birge
// ratio above 1) show SEs that are too small by that ratio; a bias every
// trial shares (a column of the wrong shape places every contact alike)
// is a common term added in quadrature.
#include <vector>

namespace dropfit::fitting {

// One held-out trial's check of one predicted quantity.
struct HeldOutCheck {
  double residual = 0.0;         // measured less predicted
  double parameter_var = 0.0;    // the parameters' and the velocity's part of the stated variance
  double discrepancy_var = 0.0;  // the model's discrepancy part (training misfit x growth, squared)
  double noise_var = 0.0;        // the measured value's own noise
};

// Each check's calibrated discrepancy variance: with the others' excess
// X = sum_{j != i} (r_j^2 - noise_j - parameter_j) and their discrepancy
// D = sum_{j != i} discrepancy_j, the discrepancy variance times
// max(1, X / D). Where the discrepancy holds under `min_discrepancy_share`
// of the others' stated variance S = sum (parameter + discrepancy) (a
// quantity the training misfit shows none of), the whole stated variance
// is scaled instead: discrepancy_i + (max(1, (X + D) / S) - 1) x (parameter_i
// + discrepancy_i). Fewer than `min_others` other checks: unchanged.
std::vector<double> cross_validated_discrepancy_var(const std::vector<HeldOutCheck>& checks, int min_others = 2,
                                                    double min_discrepancy_share = 0.1);

// The Birge ratio sqrt(chi2 / (n - 1)) of `values` about their
// inverse-variance weighted mean, at least 1 (1 for fewer than two values
// or a non-finite SE).
double birge_ratio(const std::vector<double>& values, const std::vector<double>& ses);

// Per-trial SEs of one session's clock offsets: each independent SE times
// the offsets' Birge ratio, in quadrature with the common term `common_s`.
std::vector<double> calibrated_offset_ses(const std::vector<double>& offsets_s, const std::vector<double>& ses_s,
                                          double common_s);

}  // namespace dropfit::fitting
