#pragma once
// Force plate: Kistler eight-channel signals (or BioWare's computed
// resultants) to resultant forces, moments and centre of pressure; the zero
// offset from the quiet pre-trigger part; the trigger instant, the contact
// onset found from the force itself, the peak and the end of contact.
//
// Kistler's standard eight-channel formulas (Kistler multicomponent force
// plate manual; as in docs/formats.md), a, b, az0 from the
// plate's certificate:
//
//   Fx = Fx12 + Fx34   Fy = Fy14 + Fy23   Fz = Fz1 + Fz2 + Fz3 + Fz4
//   Mx = b (Fz1 + Fz2 - Fz3 - Fz4)       My = a (-Fz1 + Fz2 + Fz3 - Fz4)
//   Mz = b (-Fx12 + Fx34) + a (Fy14 - Fy23)
//   ax = (Fx az0 - My) / Fz              ay = (Fy az0 + Mx) / Fz
//
// The centre of pressure is only computed where |Fz| reaches an explicit
// threshold (NaN elsewhere): below it the quotient is noise over noise.
//
// Time on the force clock: t = 0 at the trigger sample, i.e. the sample the
// acquisition declared as its trigger (index = pretrigger samples). The
// eight-channel export already has t = 0 there; an absolute BioWare time
// column is rebased to it by process().
#include <Eigen/Core>
#include <array>
#include <limits>
#include <string>
#include <vector>

namespace dropfit::forceplate {

struct PlateGeometry {
  double a_m = 0.120;
  double b_m = 0.200;
  double az0_m = -0.040;  // negative: top surface above the sensor plane
};

// Resultants, one row per sample.
struct Resultants {
  Eigen::VectorXd t_s;     // as recorded (process() rebases it to the force clock)
  Eigen::MatrixXd f_n;     // n x 3: Fx Fy Fz
  Eigen::MatrixXd m_n_m;   // n x 3: Mx My Mz (about the plate centre, sensor plane)
  Eigen::MatrixXd cop_m;   // n x 2: ax ay (plate frame, from the plate centre); NaN where |Fz| < threshold
  // Sensor-plane offset used for the COP. When finite, process() recomputes
  // the COP from the zeroed forces and moments; NaN keeps the COP as given
  // (BioWare's Ax Ay), masked by the zeroed |Fz|.
  double az0_m = std::numeric_limits<double>::quiet_NaN();
  // The signals as recorded (n x k) and their names, for the saturation
  // check: the eight channels, or Fx Fy Fz Mx My Mz for BioWare records.
  Eigen::MatrixXd channels_n;
  std::vector<std::string> channel_names;
  // Resultant channels the record does not have (a BioWare export of a
  // subset, e.g. Fx Fy Fz only): NaN throughout in f_n / m_n_m, never zero.
  std::vector<std::string> absent;
  // Why there is no centre of pressure (cop_m NaN throughout); empty when there is one.
  std::string cop_unavailable;
};

// Names of the eight channels, in column order.
const std::vector<std::string>& eight_channel_names();

// Centre of pressure (n x 2, ax ay) from forces and moments:
// ax = (Fx az0 - My) / Fz, ay = (Fy az0 + Mx) / Fz where |Fz| >= cop_min_fz_n, NaN elsewhere.
Eigen::MatrixXd centre_of_pressure(const Eigen::MatrixXd& f_n, const Eigen::MatrixXd& m_n_m, double az0_m,
                                   double cop_min_fz_n);

// channels: n x 8 (Fx12 Fx34 Fy14 Fy23 Fz1 Fz2 Fz3 Fz4) in newtons.
// Throws dropfit::Error on a wrong column count, a length mismatch with t_s,
// or a NaN in a channel (naming the channel and sample).
Resultants from_eight_channels(const Eigen::VectorXd& t_s, const Eigen::MatrixXd& channels,
                               const PlateGeometry& plate, double cop_min_fz_n = 50.0);

// The BioWare layout (capture::ForceRecord with layout Resultants):
// columns n x 8 (Fx Fy Fz in N, Mx My Mz in N m, Ax Ay in m), extra columns
// ignored. Ax Ay are kept where |Fz| >= cop_min_fz_n (NaN elsewhere); pass the
// plate's az0 to have process() recompute them from the zeroed resultants.
// A column of Fx Fy Mx My Mz that is NaN throughout is a channel the export
// does not have: listed in `absent`, left NaN (never zero). Without Fx Fy Mx
// My the centre of pressure cannot be recomputed, so az0 is ignored and the
// export's own Ax Ay kept; without those too there is none (cop_unavailable
// says why). Throws dropfit::Error on too few columns, Fz absent, or a NaN
// in a present channel of Fx..Mz.
Resultants from_resultant_columns(const Eigen::VectorXd& t_s, const Eigen::MatrixXd& columns,
                                  double cop_min_fz_n = 50.0,
                                  double az0_m = std::numeric_limits<double>::quiet_NaN());

struct ProcessOptions {
  double trigger_threshold_n = 25.0;
  double pretrigger_fraction = 0.10;  // share of the record before the trigger sample
  int pretrigger_samples = -1;        // from the record's header when known; overrides the fraction
  double sample_rate_hz = 1000.0;     // nominal; the time column must agree within 1 %
  // The first threshold crossing must lie within this of the declared trigger sample.
  double max_trigger_mismatch_s = 0.010;
  // Zero offset and noise from the pre-trigger samples ending this long
  // before the trigger (and before the contact onset): the quiet part.
  double quiet_guard_s = 0.050;
  int min_quiet_samples = 50;
  double onset_band_sd = 3.0;         // "at zero" means within this many noise SDs
  double min_noise_n = 0.05;          // floor on the noise SD (quantised or noiseless records)
  double cop_min_fz_n = 50.0;
  // A channel at or beyond this magnitude is saturated (amplifier range); 0 disables.
  double saturation_n = 0.0;
  // Independently of saturation_n: a channel that holds its extreme value for
  // this many samples or more after arriving at it steeply is clipped.
  int saturation_flat_samples = 4;
  // Eight-channel records: reject a record whose channels cannot be one
  // rigid plate's under the contact (a dead, stuck, exchanged or
  // sign-reversed channel; forceplate.cpp).
  bool check_channels = true;
  // The charge amplifier's Butterworth low-pass, when declared (0: none):
  // its group delay is taken out of the force clock (what the sample at t
  // shows happened at t - delay). An undeclared one reads as clock offset.
  double lowpass_hz = 0.0;
  int lowpass_order = 2;

  // Throws dropfit::Error naming the field and value when one is out of
  // range (NaN, a negative rate or time, a zero count); process() calls it.
  void validate() const;
};

struct ForceTrial {
  Resultants plate;              // zeroed, t_s on the force clock
  Eigen::Matrix<double, 6, 1> offset = Eigen::Matrix<double, 6, 1>::Zero();  // removed (Fx Fy Fz N, Mx My Mz N m)
  double noise_n = 0.0;          // SD of Fz in the quiet pre-trigger part
  int quiet_samples = 0;         // samples the offset and noise came from
  int declared_trigger_index = 0;  // the record's trigger sample (t = 0)
  double trigger_time_s = 0.0;   // first crossing of the threshold (interpolated), force clock
  int trigger_index = 0;         // first sample at or above the threshold
  double contact_time_s = 0.0;   // onset of the rise, before the trigger crossing, force clock
  int contact_index = 0;         // first sample at or after contact_time_s
  double peak_fz_n = 0.0;        // largest Fz (parabolic sub-sample refinement)
  double peak_time_s = 0.0;      // force clock
  double time_to_peak_s = 0.0;   // from contact
  double end_time_s = 0.0;       // Fz back within the noise band after the peak (interpolated)
  int end_index = 0;             // first sample at or after end_time_s (n - 1 if never)
  bool end_found = false;        // false when Fz never returned to zero within the record
  // Eight-channel records: the vertical sensors' twist (Fz1 - Fz2 + Fz3 -
  // Fz4) / Fz and each vertical channel's share of Fz (Fz1..Fz4), medians
  // over the contact's samples above 30 % of its peak; NaN otherwise.
  double twist_fraction = std::numeric_limits<double>::quiet_NaN();
  std::array<double, 4> vertical_shares{std::numeric_limits<double>::quiet_NaN(),
                                        std::numeric_limits<double>::quiet_NaN(),
                                        std::numeric_limits<double>::quiet_NaN(),
                                        std::numeric_limits<double>::quiet_NaN()};
  std::vector<std::string> absent;  // channels the record does not have (Resultants::absent)
  std::string cop_unavailable;      // why there is no centre of pressure; empty when there is one

  std::string report() const;
};

// The low-frequency group delay of an order-n Butterworth low-pass at
// corner_hz: sum over its poles of sin((2k - 1) pi / 2n) / (2 pi f_c)
// (2nd order at 520 Hz: 0.433 ms).
double butterworth_delay_s(double corner_hz, int order);

// Zeroes, finds the trigger crossing, the contact onset, the peak and the end
// of contact (methods in forceplate.cpp's comments). Channels in raw.absent
// stay NaN (offset NaN). Throws dropfit::Error when Fz is absent, a present
// force or moment is NaN, a channel is saturated (at the range or flat
// topped), the eight channels are not one rigid plate's, the pre-trigger part
// is too short for a zero offset, there is no trigger crossing, or the
// crossing is far from the declared trigger sample.
ForceTrial process(const Resultants& raw, const ProcessOptions& options);

// A step in one channel once the load has left (channel_step.cpp): each
// channel's line through the quiet pre-trigger part against its line
// through a stretch where the plate carries none of the impactor's load
// (the video shows it in the air), on the force clock. `size_n`: the jump
// between the two; `drift_allowance_n`: what a drift at the larger of the
// two slopes (plus two SEs) moves the channel over the time between them;
// the step is found when the jump exceeds that allowance by more than
// kStepNoiseFactor noise SDs and kStepFloorN. `time_s`: the instant that
// fits the channel best against the load it shares (NaN when it shares
// none, e.g. Fz of a resultant-only record). The fields describe the channel
// with the largest excess even when no step is found (its margin).
constexpr double kStepNoiseFactor = 8.0;
constexpr double kStepFloorN = 5.0;
struct ChannelStep {
  bool found = false;
  std::string channel;
  int column = -1;
  double size_n = std::numeric_limits<double>::quiet_NaN();
  double time_s = std::numeric_limits<double>::quiet_NaN();
  double drift_allowance_n = std::numeric_limits<double>::quiet_NaN();
  double noise_n = std::numeric_limits<double>::quiet_NaN();
  double excess_noise_ratio = std::numeric_limits<double>::quiet_NaN();  // (|jump| - allowance) / noise
  double unloaded_from_s = std::numeric_limits<double>::quiet_NaN();
  double unloaded_to_s = std::numeric_limits<double>::quiet_NaN();
  std::string reason() const;
};
ChannelStep find_channel_step(const ForceTrial& trial, double unloaded_from_s, double unloaded_to_s);

}  // namespace dropfit::forceplate
