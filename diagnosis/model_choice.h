#pragma once
// The mat stage's model choice and the residual's form (see diagnosis.h for
// the loop they serve): which of two mat models predicts the held-out trials
// better, and what the held-out residual of a model looks like against the
// states that tell an elastic shape from a viscous one or a memory.
#include <string>
#include <vector>

#include "diagnosis/diagnosis.h"
#include "fitting/fit.h"

namespace dropfit::diagnosis {

// Model choice by held-out prediction: two models' reports (as the fitters
// return them, train = false on the held-out trials) judged on both
// channels, paired over the held-out trials both predict. B replaces A when
// it is better beyond noise (options.decision: t_critical, min_relative)
// on both channels in one number (per trial sqrt(force^2 + travel^2) in
// noise SDs), or on one channel above options.gate_noise_sd while neither
// channel gets worse (as the mat stage keeps an effect). Better beyond
// noise: the paired t of the drops, or of the errors' logarithms
// (log_paired_t: every trial's error divided by a like factor, at least 3
// trials), at least t_critical, and the mean drop at least min_relative of
// A's mean error. No information criterion can veto that (it may only
// break a tie, which this leaves to A).
struct HeldOutChoice {
  std::string chosen;
  double force_a_sd = 0.0, force_b_sd = 0.0, impactor_a_sd = 0.0, impactor_b_sd = 0.0;  // RMS over trials
  double peak_a_pct_max = 0.0, peak_b_pct_max = 0.0;  // largest |held-out peak error|
  double t = 0.0;      // paired t of the drop from A to B (both channels in one number)
  double t_log = 0.0;  // the same on the errors' logarithms (NaN: fewer than 3 trials)
  int n = 0;       // held-out trials compared
  std::string evidence;
};
HeldOutChoice choose_by_held_out(const std::vector<fitting::TrialData>& trials, const std::string& name_a,
                                 const std::vector<fitting::TrialReport>& a, const std::string& name_b,
                                 const std::vector<fitting::TrialReport>& b, const MatStageOptions& options = {});

// ---- The residual traced to its form ----------------------------------------
//
// The held-out force residual (measured minus predicted, in the plate's
// noise SDs) mapped against the states that tell the missing term apart:
//   deflection          the face's travel (video; the model's in gaps):
//                       an elastic shape (a curve too soft or stiff somewhere);
//   deflection_rate     the model's face speed: a viscous term;
//   time_since_contact  the fitted contact on the force clock: with the
//                       deflection, loading and unloading apart, a memory
//                       (a stress that relaxes: loading and unloading at
//                       the same deflection disagree beyond what rate says);
//   recording_order     each held-out trial's mean residual by its place in
//                       the session: the mat changing between trials.
// Each axis: binned means and the share of the residual's sum of squares
// they explain (r2). The form is the axis that explains most (at least
// min_share); memory when deflection split into loading and unloading
// explains more than deflection and rate alone by min_share.
// (ResidualAxis and ResidualMap are in diagnosis.h: the loop's result carries
// the final models' maps.)
// `reports` as the fitter returns them (simulation on the trial's samples,
// fitted contact shift); held-out ones (train = false) are mapped, each
// trial's recording order being the position of its id in `trials`;
// force_noise_n is the fallback for a trial without measured noise.
ResidualMap map_residual(const std::vector<fitting::TrialData>& trials,
                         const std::vector<fitting::TrialReport>& reports, double force_noise_n = 20.0,
                         double min_share = 0.3);

}  // namespace dropfit::diagnosis
