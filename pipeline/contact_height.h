#pragma once
// The mat top the trials are measured from, settled by the session as a
// whole (internal to pipeline/).
//
// A trial measures its contact instant, impact velocity and deformation from
// the mat top: the surface markers' rest height when it lies within 5 mm of
// the manifest's mat_top_z_m, else the declared height (trial.h). A trial
// alone cannot tell a mistyped mat_top_z_m from markers that are not on the
// mat top. The session can: a wrong contact height h moves each trial's
// clock offset by h / v, a trend with 1 / impact speed that a clock offset
// (the same in every trial) does not make. When the final model's offsets
// show that trend and the surface markers sit off the declared top by the
// same height, both witnesses agree that the declared height is wrong.
#include <optional>

#include "diagnosis/diagnosis.h"

namespace dropfit::pipeline {

struct SessionState;

struct MatTopCorrection {
  double declared_m = 0.0;   // the manifest's mat_top_z_m
  double surface_m = 0.0;    // the surface markers' rest height (median over accepted trials)
  diagnosis::ContactHeightCheck trend;  // the offsets' 1 / speed regression that confirms it
};

// The correction when both witnesses agree: the trend beyond max(5 mm, 4 SE)
// (as the loop's contact_height check), the surface markers more than the
// trial stage's 5 mm off the declared top, and the two heights within
// max(2 mm, 3 SE) of each other. Empty otherwise.
std::optional<MatTopCorrection> confirmed_mat_top(const SessionState& state);

// The loop's record of a correction: an effect of the sync stage
// ("contact_height") with the clock offsets' spread, their 1 / speed trend
// and the final model's held-out errors before (`before`, built on the
// declared height) and after (`after`, rebuilt on the surface markers').
diagnosis::Effect mat_top_effect(const MatTopCorrection& c, const SessionState& before, const SessionState& after);

}  // namespace dropfit::pipeline
