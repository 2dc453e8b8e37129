#pragma once
// The retired explicit integrator of Model 5 (fitting/model5.h): leapfrog,
// every force explicit, its step capped by the stiffest element's stability
// (a few microseconds at the fitter's stiff, damped bounds). Not part of the
// library: an independent reference for tests (at a tiny max_step_s) and the
// "before" of the Model 5 benchmarks. Samples at i * output_dt_s (ignores
// first_output_s). Throws Error for inputs Model 5 cannot use.
#include "fitting/model5.h"

namespace dropfit::bench {

fitting::Model5Result simulate_model5_leapfrog(const fitting::MatParams& params,
                                               const fitting::Model5Geometry& geometry,
                                               const fitting::Impact& impact);

}  // namespace dropfit::bench
