#pragma once
// Key characteristics of an impact's ground-reaction-force curve, the ones
// Mills, Pain & Yeadon (2006) asked a mat model to reproduce: the first and
// second impact peaks and their times, the minimum between them and its
// time, the maximum rate of loading, the peak force and the time to peak;
// and the two summary errors the paper reports for a simulated curve
// against a measured one: RMS difference as % of the measured peak, and the
// peak-force difference in %.
//
// Conventions: times are those of the input samples (seconds from first
// contact, or whatever origin the caller uses); values are sample values,
// no sub-sample interpolation, so a hand-computed signal gives exact
// answers. Peaks are local maxima whose topographic prominence (height above
// the higher of the two lowest points separating it from a higher peak or
// from the signal's ends) is at least `prominence_frac` of the global peak
// and whose height is at least `min_peak_frac` of it. The first and second
// impact peaks are the first two such peaks in time; with a single peak the
// second and the minimum are NaN. The rate of loading is the central
// difference (one-sided at the ends) of the force, largest before the
// global peak.
#include <Eigen/Core>
#include <limits>

namespace dropfit::fitting {

struct CharacteristicsOptions {
  double prominence_frac = 0.03;  // of the global peak
  double min_peak_frac = 0.2;     // of the global peak
  int smooth_samples = 1;         // centred moving average before the analysis (odd; 1 = none)
};

struct Characteristics {
  static constexpr double nan = std::numeric_limits<double>::quiet_NaN();
  double peak_force_n = nan, time_to_peak_s = nan;
  double first_peak_n = nan, first_peak_s = nan;
  double second_peak_n = nan, second_peak_s = nan;
  double min_between_n = nan, min_between_s = nan;
  double max_loading_rate_n_s = nan, max_loading_rate_s = nan;
  int n_peaks = 0;  // prominent peaks found
};

// Throws Error if t_s and force_n differ in length or hold fewer than 3
// samples, or t_s is not increasing.
Characteristics characteristics(const Eigen::VectorXd& t_s, const Eigen::VectorXd& force_n,
                                const CharacteristicsOptions& options = {});

// Simulated against measured on the same samples (NaN samples skipped in
// either): RMS of the difference as % of the measured peak, peak force %
// difference (simulated minus measured, % of measured), and time-to-peak
// difference (simulated minus measured, ms).
struct ForceComparison {
  double rms_force_pct_peak = Characteristics::nan;
  double peak_force_pct_diff = Characteristics::nan;
  double time_to_peak_ms_diff = Characteristics::nan;
};
ForceComparison compare_forces(const Eigen::VectorXd& t_s, const Eigen::VectorXd& measured_n,
                               const Eigen::VectorXd& simulated_n);

}  // namespace dropfit::fitting
