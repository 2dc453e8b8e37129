#pragma once
// Model 6 (the foam column, fitting/model6_fit.h) as a candidate final model.
//
// The loop (diagnosis/) closes on Models 1-5 and their effects, all lumped
// chains. When the final model of the loop leaves the held-out residual
// above the noise (the mat stage's remaining structure), the mat may be a
// continuum that no lumped chain describes: Model 6 is fitted on the same
// training trial and the two are judged by held-out prediction on both
// channels, paired over the held-out trials (diagnosis::choose_by_held_out;
// no information criterion vetoes a model that predicts clearly better).
// When Model 6 wins it is the session's final model: it places each
// trial's contact on the force clock, so the clock offsets and the sync
// verdict are judged again on its contacts.
//
// Plain data and numerics only; outputs.h writes it.
#include <limits>
#include <optional>
#include <string>

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

// Fits Model 6 when the final lumped model does not reach the noise and
// judges it against that model (state.model6); a failed fit is a note.
void consider_model6(SessionState& state);

// With Model 6 chosen: each trial's clock offset from the contact Model 6
// places on the force clock (the onset estimate kept beside it), its SE
// widened by Model 6's own misfit when Model 6 does not reach the noise,
// and the loop's sync verdict judged again on those offsets.
void apply_model6_offsets(SessionState& state);

}  // namespace dropfit::pipeline
