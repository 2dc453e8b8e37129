#pragma once
// The impact the Model 5 benchmarks and the scan simulate: the paper's
// trial 3 (24 kg at 5.25 m/s), 0.3 s, output every millisecond.
#include "fitting/models.h"

namespace dropfit::bench {

inline fitting::Impact model5_trial3() {
  fitting::Impact im;
  im.mass_kg = 24.0;
  im.velocity_m_s = 5.25;
  im.duration_s = 0.3;
  im.output_dt_s = 1e-3;
  return im;
}

}  // namespace dropfit::bench
