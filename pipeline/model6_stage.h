#pragma once
// Model 6 (the foam column, fitting/model6_fit.h) as a candidate final model.
//
// The loop (diagnosis/) closes on Models 1-5 and their effects, all lumped
// chains. When the final model of the loop leaves the held-out residual
// above the noise (the mat stage's remaining structure), the mat may be a
// continuum that no lumped chain describes: Model 6 is fitted on its own
// training trial (the deepest impact, model6_train_ids) and the two are
// judged by held-out prediction on both channels, paired over the trials
// both hold out (diagnosis::choose_by_held_out; no information criterion
// vetoes a model that predicts clearly better).
// When Model 6 wins it is the session's final model: it places each
// trial's contact on the force clock, so the clock offsets and the sync
// verdict are judged again on its contacts.
//
// Plain data and numerics only; outputs.h writes it.
#include <atomic>
#include <limits>
#include <optional>
#include <string>
#include <thread>
#include <vector>

#include "capture/session.h"
#include "diagnosis/diagnosis.h"
#include "diagnosis/model_choice.h"
#include "fitting/model6_fit.h"

namespace dropfit::pipeline {

struct SessionState;

struct Model6Stage {
  bool fitted = false;
  std::string reason;  // why Model 6 was (not) fitted and what was chosen, numbers included
  fitting::Model6FitOptions options;
  std::optional<fitting::Model6FitResult> fit;
  std::optional<diagnosis::HeldOutChoice> choice;
  std::string rival;    // the lumped model it was judged against ("closed_loop" or a model name)
  bool chosen = false;  // Model 6 is the session's final model
  // Model 6's held-out residual RMS in noise SDs, and whether both stay
  // within the mat stage's unexplained_noise_sd (it reaches the noise).
  double heldout_force_sd = std::numeric_limits<double>::quiet_NaN();
  double heldout_impactor_sd = std::numeric_limits<double>::quiet_NaN();
  bool reaches_noise = false;
};

// Model 6's options from the manifest: the top foam is every layer above
// the last (their thicknesses and masses summed), the base foam the last;
// the column's area is the impactor's footprint.
fitting::Model6FitOptions model6_options(const Manifest& manifest);

// True when the loop's mat stage ran and left held-out structure above the
// noise (the final lumped model does not reach the noise).
bool final_model_short_of_noise(const SessionState& state);

// Model 6 fitted on a thread of its own beside the loop's later rounds.
// The loop's mat stage calls back after each round that named an effect;
// when the model it goes on from still leaves more than
// kEarlyModel6NoiseSd noise SDs on a channel, the lumped chains rarely
// reach the noise (a named effect brings a lumped-chain mat to the noise;
// on a foam column the model stays far above it: docs/models.md has the
// measured errors), so Model 6 is started then on the data and training
// trial it would be fitted on after the loop. consider_model6 takes that fit only when its
// inputs are exactly those it would fit on (the same trials, values and
// training trial: the fit is deterministic, so the result is the one it
// would get); otherwise, and when Model 6 is not needed, the early fit is
// cancelled. Only the time changes: on two cores Model 6's single-threaded
// stretches overlap the loop's refits.
inline constexpr double kEarlyModel6NoiseSd = 10.0;

// Model 6's training trial: the deepest impact (the accepted trial with the
// highest impact velocity: a foam's law is nonlinear in strain and a trial
// shows it only up to the strain it reaches, so every other trial is then
// predicted inside what training showed), when that leaves at least
// kModel6MinPairedTrials trials held out by both Model 6 and the rival
// trained on rival_train_ids (the paired choice needs them); else the
// rival's own training trials (a session left with three accepted trials).
inline constexpr int kModel6MinPairedTrials = 2;
std::vector<std::string> model6_train_ids(const std::vector<fitting::TrialData>& accepted,
                                          const std::vector<std::string>& rival_train_ids);

class EarlyModel6 {
 public:
  EarlyModel6() = default;
  EarlyModel6(const EarlyModel6&) = delete;
  EarlyModel6& operator=(const EarlyModel6&) = delete;
  ~EarlyModel6();  // cancels a fit still running and waits for it

  bool started() const { return thread_.joinable(); }
  // Starts fit_model6(data, options) on a thread of its own.
  void start(std::vector<fitting::TrialData> data, fitting::Model6FitOptions options);
  // The fit when it was started on exactly `data` and `options.train_ids`
  // (waits for it; rethrows its failure as fit_model6 would have thrown
  // it); empty otherwise (a fit running is cancelled).
  std::optional<fitting::Model6FitResult> take(const std::vector<fitting::TrialData>& data,
                                               const fitting::Model6FitOptions& options);

 private:
  void stop();
  std::vector<fitting::TrialData> data_;
  fitting::Model6FitOptions options_;
  std::atomic<bool> cancel_{false};
  std::thread thread_;
  std::optional<fitting::Model6FitResult> fit_;
  std::string error_;
};

// The mat stage's callback (diagnosis::DiagnosisOptions::after_mat_round):
// starts `early` on the fit data the pipeline will hold after the loop
// (with the plate correction the mat stage's data carry) and the training
// trial model6_train_ids gives beside `current`, the model the loop goes on
// from, when one of its channels stays above kEarlyModel6NoiseSd.
void start_model6_early(const SessionState& state, EarlyModel6& early, const fitting::FitResult& current,
                        double force_sd, double impactor_sd, const diagnosis::PlateCorrection& correction);

// Fits Model 6 when the final lumped model does not reach the noise and
// judges it against that model (state.model6); a failed fit is a note.
// An early fit on the same inputs (`early`) is taken instead of fitting
// again. Before the judgement, when the loop named no change of the mat
// between trials on the lumped model (whose misfit with speed can hide
// it), the same test (diagnosis::diagnose_order) runs on Model 6, each
// trial's stiffness scale being the factor on every foam stress that
// brings the column's largest travel to the trial's. When the mat changes,
// the effect joins the loop's and each held-out trial is predicted with the
// training trial's column times its trend scale (no interval; its contact
// at the trial's own scale), as for a lumped final model.
void consider_model6(SessionState& state, EarlyModel6* early = nullptr);

// With Model 6 chosen: each trial's clock offset from the contact Model 6
// places on the force clock (the onset estimate kept beside it), its SE
// widened by Model 6's own misfit when Model 6 does not reach the noise,
// and the loop's sync verdict judged again on those offsets.
void apply_model6_offsets(SessionState& state);

}  // namespace dropfit::pipeline
