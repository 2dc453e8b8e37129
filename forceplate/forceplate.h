#pragma once
// Force plate: Kistler eight-channel signals to resultant forces, moments
// and centre of pressure (Kistler's standard formulas, as in
// shared/spec/session-format.md), zero offset from the quiet pre-trigger
// part, the trigger instant and the contact onset found from the force.
//
//   Fx = Fx12 + Fx34   Fy = Fy14 + Fy23   Fz = Fz1 + Fz2 + Fz3 + Fz4
//   Mx = b (Fz1 + Fz2 - Fz3 - Fz4)       My = a (-Fz1 + Fz2 + Fz3 - Fz4)
//   Mz = b (-Fx12 + Fx34) + a (Fy14 - Fy23)
//   ax = (Fx az0 - My) / Fz              ay = (Fy az0 + Mx) / Fz
//
// Time on the force clock: t = 0 at the trigger sample.
#include <Eigen/Core>
#include <string>

namespace dropfit::forceplate {

struct PlateGeometry {
  double a_m = 0.120;
  double b_m = 0.200;
  double az0_m = -0.040;
};

// Resultants, one row per sample; NaN COP where |Fz| is below the threshold.
struct Resultants {
  Eigen::VectorXd t_s;     // force clock, trigger at 0
  Eigen::MatrixXd f_n;     // n x 3: Fx Fy Fz
  Eigen::MatrixXd m_n_m;   // n x 3: Mx My Mz
  Eigen::MatrixXd cop_m;   // n x 2: ax ay (plate frame, from the plate centre)
};

// channels: n x 8 (Fx12 Fx34 Fy14 Fy23 Fz1 Fz2 Fz3 Fz4).
Resultants from_eight_channels(const Eigen::VectorXd& t_s, const Eigen::MatrixXd& channels,
                               const PlateGeometry& plate, double cop_min_fz_n = 50.0);

struct ProcessOptions {
  double trigger_threshold_n = 25.0;
  double pretrigger_fraction = 0.10;
  double sample_rate_hz = 1000.0;
  double cop_min_fz_n = 50.0;
  // Channels saturate at this magnitude (amplifier range); 0 disables.
  double saturation_n = 0.0;
};

struct ForceTrial {
  Resultants plate;              // zeroed
  Eigen::Vector3d offset_n;      // removed zero offset (Fx Fy Fz)
  double noise_n = 0.0;          // SD of Fz in the quiet pre-trigger part
  double trigger_time_s = 0.0;   // first crossing of the threshold, force clock
  int trigger_index = 0;
  double contact_time_s = 0.0;   // onset of the rise, before the trigger crossing
  int contact_index = 0;
  double peak_fz_n = 0.0;
  double time_to_peak_s = 0.0;   // from contact
  double end_time_s = 0.0;       // Fz back below the noise band after the peak
};

// Zeroes, finds trigger and contact. Throws dropfit::Error when the record
// has no trigger crossing, is saturated, or its pre-trigger part is missing.
ForceTrial process(const Resultants& raw, const ProcessOptions& options);

}  // namespace dropfit::forceplate
