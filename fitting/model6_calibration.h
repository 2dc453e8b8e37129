#pragma once
// Calibrations of Model 6's stated uncertainties against what the session
// itself shows (plain values in, plain values out; no file I/O).
//
// Prediction intervals: each held-out trial's measured peak force, time to
// peak and largest travel against its prediction is a check of the stated
// interval that carries only the measurement's noise. What the other
// held-out trials' checks show beyond their stated variance is carried to
// a trial's discrepancy (leave one out: a trial's own error never sets its
// own interval), never below the training trials' misfit it starts from,
// in proportion to its squared distance from the training trials: a law
// fitted on one impact errs little near it and more the further a trial's
// impact is from it (measured in docs/validation.md).
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
  double distance = 1.0;         // how far the trial is from the training trials (Model 6: |1 - E / E_train|)
};

// Each check's calibrated discrepancy variance: discrepancy_i + w_i x
// kappa^2, kappa^2 >= 0 what the OTHER checks show beyond their stated
// variance per unit of w: their excesses e_j = r_j^2 - noise_j -
// parameter_j - discrepancy_j over w_j, averaged with inverse-variance
// weights w_j^2 / (noise_j + parameter_j + discrepancy_j + kappa^2 w_j)^2
// (iterated), so a check whose stated variance dwarfs its shape tells
// little. The shape w = distance^2 x b; b is the discrepancy (the training
// misfit's shape), or, where the discrepancy is on average under
// `min_discrepancy_share` of the others' stated variance (a quantity the
// training misfit shows none of), the whole stated variance, parameter +
// discrepancy. Where the others' distances are all zero, w = b. Fewer than
// `min_others` other checks: unchanged.
std::vector<double> cross_validated_discrepancy_var(const std::vector<HeldOutCheck>& checks, int min_others = 2,
                                                    double min_discrepancy_share = 0.1);

// The number of other checks a held-out check's discrepancy was scaled by
// (the finite ones besides it), 0 where fewer than `min_others`: the
// degrees of freedom of that estimated variance.
std::vector<int> cross_validated_dof(const std::vector<HeldOutCheck>& checks, int min_others = 2);

// The Welch-Satterthwaite degrees of freedom of a variance known_var +
// estimated_var where only estimated_var is estimated, from `dof` degrees
// of freedom: (known + estimated)^2 / (estimated^2 / dof); infinite where
// nothing is estimated (dof < 1 or estimated_var = 0).
double welch_dof(double known_var, double estimated_var, double dof);

// The two-sided 95 % quantile of Student's t with `dof` degrees of freedom
// (the normal's 1.959964 for an infinite dof). A stated variance estimated
// from the few other held-out trials a session has is uncertain itself,
// and an interval of +-1.96 SE on it covers less than 95 %.
double t_quantile_95(double dof);

// The Birge ratio sqrt(chi2 / (n - 1)) of `values` about their
// inverse-variance weighted mean, at least 1 (1 for fewer than two values
// or a non-finite SE).
double birge_ratio(const std::vector<double>& values, const std::vector<double>& ses);

// Per-trial SEs of one session's clock offsets: each independent SE times
// the offsets' Birge ratio, in quadrature with the common term `common_s`.
std::vector<double> calibrated_offset_ses(const std::vector<double>& offsets_s, const std::vector<double>& ses_s,
                                          double common_s);

}  // namespace dropfit::fitting
