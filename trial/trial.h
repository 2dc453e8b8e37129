#pragma once
// One drop trial from plain values: the processed force record, the
// reconstructed marker trajectories and the session's constants in; impact
// velocity with its 95 % interval, the video-force clock offset, maximum
// deformation, tilt, acceptance and the contact series out (the fields of
// OUT/trials/TRIAL/trial.json and series.csv, docs/formats.md).
//
// Clocks. Force clock: t = 0 at the plate's trigger sample (forceplate.h).
// Video clock: frame i at (i - trigger_frame) / frame_rate, the nominal
// relation. The actual relation is estimated from the data:
//   video_offset_s = (an instant's video-clock time) - (its force-clock time),
// and every video-derived series is placed on the force clock with it.
//
// Methods.
// - Contact face height: the mean height of the impactor's base markers
//   minus base_marker_height_m, only in frames where all base markers are
//   present (a subset's mean would jump when the impactor is tilted).
// - Impact velocity: least squares of the free-fall path
//   z(t) = z0 + v0 (t - t_ref) - g (t - t_ref)^2 / 2 (g known, two unknowns)
//   over the face heights of the frames in freefall_window_s before the
//   face reaches the mat top (frames within freefall_clearance_m of it left
//   out; one pass dropping residuals beyond 4 robust SDs). The contact
//   instant is where the fitted path reaches the contact height (below;
//   sub-frame); the downward speed there is
//   s = sqrt(v0^2 - 2 g (contact_height - z0)). Its 95 %
//   interval: residual variance times (X'X)^-1 propagated through s by the
//   delta method (ds/dz0 = g/s, ds/dv0 = v0/s), Student t with n - 2
//   degrees of freedom.
// - Synchronisation (primary): the contact instant seen by both clocks, the
//   free-fall fit's arrival at the mat top (video) against the plate's
//   contact onset (forceplate::ForceTrial::contact_time_s). Its precision is
//   the fit's (about 0.05 ms at 0.5 mm marker noise); its accuracy rests on
//   the contact height (1 mm there is 0.2 ms at 5 m/s) and on the plate's onset
//   being the instant the face touches the mat. With a massless mat it is
//   (0.02 ms in tests); when the mat's top layer has mass the plate force
//   starts as t^2..t^3 and stays inside the noise longer, so the onset and
//   with it the offset read late (about 0.1-0.6 ms for 0.5-6 kg layers at
//   2 N plate noise in our simulations); a foam's wave transmission delay
//   would likewise be read as clock offset. Without a video contact (free
//   fall not seen) the nominal relation (offset 0) places the series and
//   video_offset_s is NaN; the trial is then rejected anyway.
//   Second estimate, reported beside it (video_offset_trajectory_s): the
//   face heights during contact against the free-fall path plus the plate
//   force's double integral divided by the impactor mass, shifted by the
//   offset that fits best (least squares, 0.01 ms grid then parabola). It does
//   not use mat_top_z_m or the onset, but the plate reads the mat's force,
//   which differs from the impactor's by the mat's accelerated mass, so it is
//   a consistency check, not the reported value (the loop takes that bias,
//   and the plate's gain and drift, out with the fitted mat model:
//   diagnosis::trajectory_estimate_bias_s).
// - Contact height: the mat top as the same cameras see it. When the surface
//   markers are seen at rest (their mean over at least min_rest_frames
//   frames before the face first comes within 20 mm of the mat) within
//   max_surface_reference_m of mat_top_z_m, their rest height replaces
//   mat_top_z_m for the contact instant, the impact velocity, the
//   deformation and the series: the face and the surface share the
//   calibration's height error near the mat (a lens-distortion fit leaves
//   1-2 mm there: 0.2-0.4 ms of contact instant at 5 m/s, seen as a travel
//   residual proportional to the face's velocity), which the surveyed
//   height does not. A larger gap means the markers are not on the
//   surface; the manifest's height is kept (TrialResult::contact_height_m).
//   Beyond max_surface_disagreement_m the cameras and the manifest
//   disagree on where the mat is (a mistyped mat_top_z_m, or markers that
//   are not on the mat top: which one is not known) and the trial is
//   rejected naming both: at 5 m/s 15 mm is 3 ms of contact instant and
//   15 mm of deformation, far outside any interval the trial states.
// - Max deformation: the contact height minus the lowest face height during contact,
//   from a quadratic fitted to the frames within
//   deformation_fit_half_window_s of the lowest one; it needs two frames
//   seen on each side of the lowest one within that window, or within twice
//   it when a gap is in the way (otherwise the bottom lies in a gap and the
//   trial is rejected).
// - Rigidity: the distance between each pair of base markers, from the
//   free-fall window to the end of contact, must stay within max(10 mm, 6
//   robust SDs) of its median (the impactor is rigid); a frame beyond it has
//   a marker mistracked, swapped or loose, and the trial is rejected naming
//   the pair and the frame.
// - Tilt: per frame, with two base markers the base line's angle from
//   horizontal (the tilt about the line itself cannot be seen); with three or
//   more the angle of the base plane's normal (least squares plane, SVD) from
//   vertical. The per-frame sine (two markers) or normal (three or more) is
//   averaged over tilt_smoothing_frames before taking the angle, so that
//   marker noise does not inflate the maximum; tilt_deg is the largest over
//   the contact.
// - Marker coverage: each base marker must be present in min_marker_coverage
//   of the frames from coverage_lead_s before contact to the end of contact,
//   with no gap longer than max_marker_gap_s. Digitised tracks have short
//   gaps (1-5 frames, in one camera or both, and a gap in one camera can
//   abut one in the other); such a trial is kept and its gaps stay NaN.
//   Surface markers are optional (the impactor may hide them); their mean
//   is NaN where any is missing.
// - Series: every force sample from series_lead_s before contact to the end
//   of contact; video values linearly interpolated between two present
//   neighbouring frames at the sample's video-clock time, NaN otherwise.
// - Impulse check: the plate impulse above the impactor's weight from contact
//   to maximum deformation (where impactor and mat are at rest) over the
//   impactor's momentum at contact; 1 when force scale, mass and video agree.
//
// Rejections (accepted = false, reason given, everything measured still
// reported): a bad force record (forceplate's Error text forwarded), the
// face never seen reaching the mat, too few free-fall frames, base markers
// missing around contact (named), the lowest point in a gap, tilt beyond
// max_tilt_deg, clocks disagreeing by more than max_video_offset_s, and the
// plausibility gates below. Bad options (an index out of range, no base
// markers) throw dropfit::Error.
//
// Plausibility gates (physics, not tuning; each names what it saw):
// - Force spike: a non-finite Fz sample during contact, or one sample
//   anywhere in the record (one in the free flight biases the impulse
//   balance too) that stands away from both neighbours (same sign) by more
//   than max_spike_fraction of the contact's median-filtered peak. Through a
//   compliant mat the plate force rises over milliseconds; a smooth curve
//   sampled at 1 kHz or faster cannot leave and return to its neighbours by
//   15 % of its peak within one sample (over 960 trials of the validation
//   sessions and ten archives of the independent world, stiffening top
//   layers and sharp impact peaks included, no sample stands more than
//   3.4 % of the peak away from both neighbours; 15 % catches a 1500 N
//   spike on a 9 kN peak, which the earlier 50 % let into the fit).
// - Impact velocity, video against force: the impulse above the impactor's
//   weight from contact to maximum deformation divided by the mass is the
//   impact speed the force implies (impulse_ratio = that over the video's).
//   The plate also carries the mat layers' momentum at that instant (at
//   most m_mat v_in) and the force scale is known to a few per cent, so the
//   ratio must lie within 1 +- (impulse_tolerance + mat_mass_kg /
//   impactor_mass_kg). A wrong frame rate, mass or force scale leaves it.
// - Impulse against momentum over the whole contact (when the force returns
//   to zero): J = M (v_in + v_out) with 0 <= v_out <= v_in, so the
//   restitution J / (M v_in) - 1 must lie in [0, 1], with the same
//   tolerance. A negative impulse or one beyond twice the momentum is
//   impossible.
// - Free fall against gravity: the face heights over the fall before
//   contact (up to fall_check_window_s, and never before 0.8 v / g, where
//   a drop from rest at the contact speed v would have been released),
//   fitted with the acceleration free, must fall at g: air drag on the
//   impactor is under 1 % of its weight at 6 m/s, a guide's friction can only
//   slow it. An apparent acceleration above g (1 + fall_accel_excess) or
//   below g (1 - fall_accel_deficit) by more than fall_accel_sigma SEs
//   rejects the trial naming what scales it: the video's time base (a
//   declared frame rate f reads a true one f0 as a = g (f / f0)^2, so the
//   rate that makes the fall free is given), the calibration's length scale
//   (a = g x scale), or the declared gravity. A 5 % frame-rate error is 10 %
//   of acceleration; the velocity (x f / f0) and every clock-derived number
//   would be off with nothing else to show it, since the force impulse gate
//   allows the mat's momentum.
// - Force channels back at their zero: once the video shows the impactor
//   in the air (airborne_stretch_s) the plate carries what it carried
//   before the drop, so every channel must read its pre-trigger zero again
//   within what a drift at its own slopes allows; a channel that jumped (a
//   charge amplifier's reset, a knocked cable: forceplate::
//   find_channel_step) rejects the trial as its first reason, naming the
//   channel, the step and its instant (its margin on clean sessions:
//   docs/faults.md).
// - Reprojection and calibration: apply_calibration_gates() (below), given
//   the calibration's own quality, rejects a trial whose markers' median
//   reprojection residual is far above what the calibration achieved, and
//   every trial of a calibration that failed its own check.
#include <Eigen/Core>
#include <limits>
#include <string>
#include <utility>
#include <vector>

#include "forceplate/forceplate.h"
#include "reconstruction/reconstruction.h"

namespace dropfit::trial {

struct TrialOptions {
  std::string id;
  double impactor_mass_kg = 24.0;
  double gravity_m_s2 = 9.81;
  double frame_rate_hz = 1000.0;
  int trigger_frame = 0;                  // 0-based frame recorded at the plate trigger
  std::vector<int> base_markers;          // indices among the trajectories' points
  std::vector<int> surface_markers;       // may be empty
  std::vector<std::string> point_names;   // optional, for messages
  double base_marker_height_m = 0.0;      // base markers above the contact face
  double mat_top_z_m = 0.205;             // undeformed mat top, lab frame
  double max_surface_reference_m = 0.005; // surface markers' rest height used within this of it
  double max_surface_disagreement_m = 0.015;  // beyond: rejected (see above)
  int min_rest_frames = 5;                // ... seen at rest in at least this many frames
  double max_tilt_deg = 6.0;              // the paper's trials: 2.6 +- 0.87 deg
  double freefall_window_s = 0.060;
  double freefall_clearance_m = 0.002;
  int min_freefall_frames = 10;
  double coverage_lead_s = 0.010;
  double min_marker_coverage = 0.75;       // digitising leaves 1-5-frame gaps, some in both cameras
  double max_marker_gap_s = 0.010;        // ... and gaps in the two cameras can abut
  double max_video_offset_s = 0.050;
  double deformation_fit_half_window_s = 0.005;
  int tilt_smoothing_frames = 5;
  double series_lead_s = 0.010;
  double mat_mass_kg = 0.0;               // all layers; bounds the mat's share of the plate impulse
  double impulse_tolerance = 0.15;        // force scale (a few %) and velocity CI (~1-3 %), generously
  double max_spike_fraction = 0.15;       // of the median-filtered contact peak
  double fall_check_window_s = 0.250;     // free fall the acceleration check reads (see above)
  double fall_accel_excess = 0.03;        // above g: nothing but a wrong time base or scale
  double fall_accel_deficit = 0.15;       // below g: a guide's friction allowed
  double fall_accel_sigma = 4.0;

  // Throws dropfit::Error naming the field and value when one is out of
  // range (NaN, a non-positive rate or mass, a negative window, a zero
  // count); analyse() calls it. Marker indices are checked against the
  // trajectories there.
  void validate() const;
};

// The free-fall fit of the face height (video clock).
struct FreeFallFit {
  bool ok = false;
  double t_ref_s = 0.0;                   // fit origin
  double z_ref_m = 0.0, v_ref_m_s = 0.0;  // height and vertical velocity (up positive) at t_ref
  Eigen::Matrix2d covariance = Eigen::Matrix2d::Zero();  // of (z_ref, v_ref)
  double rms_m = 0.0;
  int n_frames = 0;                       // used (after dropping outliers)
  double contact_time_s = std::numeric_limits<double>::quiet_NaN();  // reaches the contact height
  double contact_speed_m_s = std::numeric_limits<double>::quiet_NaN();  // downward
  double contact_speed_ci_m_s = std::numeric_limits<double>::quiet_NaN();  // 95 % half-width
  // One-sigma errors of the fit's contact speed and instant (the fit's
  // covariance carried through the arrival at the contact height; the
  // height itself exact) and their covariance: both come from the same two
  // fitted numbers, so a trial's speed and contact instant err together.
  double contact_speed_se_m_s = std::numeric_limits<double>::quiet_NaN();
  double contact_time_se_s = std::numeric_limits<double>::quiet_NaN();
  double speed_time_cov = std::numeric_limits<double>::quiet_NaN();  // m/s x s
  double height_at(double t_s, double gravity_m_s2) const;
};

// Fits z(t) = z0 + v0 (t - t_ref) - g (t - t_ref)^2 / 2 to (t_s, z_m) (all
// finite), then evaluates the arrival at contact_height_m. ok = false when
// fewer than 3 points or the path never reaches the height.
FreeFallFit fit_free_fall(const Eigen::VectorXd& t_s, const Eigen::VectorXd& z_m, double gravity_m_s2,
                          double contact_height_m, double t_ref_s);

// The free fall's own acceleration: z = z0 + v0 t - a t^2 / 2 fitted with
// a free (least squares, one pass dropping residuals beyond 4 robust SDs);
// ok = false with fewer than four points or a degenerate span.
struct FallAcceleration {
  bool ok = false;
  double accel_m_s2 = std::numeric_limits<double>::quiet_NaN();  // downward
  double se_m_s2 = std::numeric_limits<double>::quiet_NaN();
  int n_frames = 0;
  double span_s = 0.0;
};
FallAcceleration fit_fall_acceleration(const Eigen::VectorXd& t_s, const Eigen::VectorXd& z_m);
// The gate's verdict (see "Free fall against gravity"): empty when the fall
// is consistent with options.gravity_m_s2, else the reason naming the
// frame rate that would make it free.
std::string fall_acceleration_reason(const FallAcceleration& fall, const TrialOptions& options);

// The stretch of the force clock where the plate carries none of the
// impactor's load, for find_channel_step (forceplate.h). h: the face
// heights per video frame; the face first rises 5 mm above the contact
// height top_m after contact_frame at time t_leave (video clock); its free
// flight over the frames it is then seen in the air (least squares, gravity
// known) gives its upward speed v_up, and it cannot land again before
// 2 v_up / g has passed (a catcher only keeps it off the mat longer). The
// stretch runs from 50 ms after leaving (the mat's top layer rings down) to
// 90 % of that time, on the force clock (video time - offset_s). {NaN, NaN}
// when the video does not see it leave, sees it in the air in fewer than
// 10 frames, or the stretch is shorter than 50 ms.
std::pair<double, double> airborne_stretch_s(const Eigen::VectorXd& h, double top_m, double contact_frame,
                                             double frame_rate_hz, int trigger_frame, double offset_s,
                                             double gravity_m_s2);

// The second synchronisation estimate's core (video_offset_trajectory_s; the
// loop runs it on a simulated impact for its bias, diagnosis::
// trajectory_estimate_bias_s): the face's lag behind free fall, lag_m at
// video times lag_t_s, matched with the plate force's double integral over
// the impactor mass (force_n on the uniform times force_t_s, integrated from
// sample force_first, zero before it). Returns the clock shift within
// +-search_s of centre_s that fits best (least squares on a 0.01 ms grid,
// then a parabola through the best point and its neighbours); a lag time
// shifted before the record reads 0, after it the integral's last value.
// NaN with fewer than 10 lag points.
double trajectory_shift_s(const Eigen::VectorXd& force_t_s, const Eigen::VectorXd& force_n, Eigen::Index force_first,
                          double mass_kg, const std::vector<double>& lag_t_s, const std::vector<double>& lag_m,
                          double centre_s, double search_s = 0.005);

// Quantile of Student's t distribution (p in (0, 1), dof >= 1).
double student_t_quantile(double p, double dof);

// Tilt from vertical (degrees) of the impactor's base in one frame: with two
// points, the line's angle from horizontal; with three or more, the plane
// normal's angle from vertical. NaN when a point is missing.
double base_tilt_deg(const std::vector<Eigen::Vector3d>& base_points_m);

// series.csv: one row per force sample over the contact, force clock.
struct Series {
  Eigen::VectorXd t_s;
  Eigen::VectorXd fz_n;
  Eigen::VectorXd impactor_z_m;   // contact face height, lab frame; NaN across video gaps
  Eigen::VectorXd deformation_m;  // contact_height_m - impactor_z_m
  Eigen::VectorXd surface_z_m;    // mean of the surface markers
};

struct TrialResult {
  std::string id;
  bool accepted = false;
  std::string reject_reason;
  double impact_velocity_m_s = std::numeric_limits<double>::quiet_NaN();     // downward speed at contact
  double impact_velocity_ci_m_s = std::numeric_limits<double>::quiet_NaN();  // 95 % half-width
  double max_deformation_m = std::numeric_limits<double>::quiet_NaN();
  double tilt_deg = std::numeric_limits<double>::quiet_NaN();
  double peak_force_n = std::numeric_limits<double>::quiet_NaN();
  double time_to_peak_s = std::numeric_limits<double>::quiet_NaN();  // from contact
  double contact_time_s = std::numeric_limits<double>::quiet_NaN();  // force clock
  double contact_height_m = std::numeric_limits<double>::quiet_NaN();  // the mat top used (see above)
  double surface_rest_z_m = std::numeric_limits<double>::quiet_NaN();  // the surface markers at rest (NaN: not seen)
  double video_offset_s = std::numeric_limits<double>::quiet_NaN();  // video clock minus force clock
  // When the mat fit placed the contact on the force clock (the main run):
  // its standard error, and the estimate from the plate's onset it replaced.
  double video_offset_se_s = std::numeric_limits<double>::quiet_NaN();
  double video_offset_onset_s = std::numeric_limits<double>::quiet_NaN();

  // The error budget of the video's measurements (one sigma; the fit
  // carries them as nuisance parameters with these priors):
  // - impact_velocity_se_m_s: the free-fall fit's alone (digitising noise);
  // - video_contact_time_se_s: the video contact instant's, from the
  //   free-fall fit and the contact height's own error (a height error dH
  //   moves the arrival by dH / v);
  // - velocity_contact_time_cov: the covariance of the two (the same fit);
  // - contact_height_se_m: the error of the height travel is measured from:
  //   the surface markers' rest mean's standard error, or, on the manifest's
  //   mat top, the calibration's vertical accuracy at that height;
  // - calibration_scale_sd: the relative error of lengths along z (common to
  //   every trial of the session: velocity, travel and deformation scale
  //   with it), and calibration_uncertainty the source of that number
  //   ("check markers", or "declared: ..." when the calibration could not be
  //   checked, e.g. coefficients given without check markers).
  double impact_velocity_se_m_s = std::numeric_limits<double>::quiet_NaN();
  double video_contact_time_se_s = std::numeric_limits<double>::quiet_NaN();
  double velocity_contact_time_cov = std::numeric_limits<double>::quiet_NaN();
  double contact_height_se_m = std::numeric_limits<double>::quiet_NaN();
  double calibration_scale_sd = std::numeric_limits<double>::quiet_NaN();
  std::string calibration_uncertainty;

  // Beyond trial.json's minimum.
  double video_offset_trajectory_s = std::numeric_limits<double>::quiet_NaN();  // second estimate
  double video_contact_time_s = std::numeric_limits<double>::quiet_NaN();       // video clock
  double max_deformation_time_s = std::numeric_limits<double>::quiet_NaN();     // force clock
  double end_time_s = std::numeric_limits<double>::quiet_NaN();                 // force clock
  double freefall_rms_m = std::numeric_limits<double>::quiet_NaN();
  int freefall_frames = 0;
  // The fall's own acceleration (the check against gravity) and its SE.
  double fall_accel_m_s2 = std::numeric_limits<double>::quiet_NaN();
  double fall_accel_se_m_s2 = std::numeric_limits<double>::quiet_NaN();
  double impulse_ratio = std::numeric_limits<double>::quiet_NaN();
  double force_noise_n = std::numeric_limits<double>::quiet_NaN();  // Fz SD in the quiet pre-trigger part
  double velocity_from_impulse_m_s = std::numeric_limits<double>::quiet_NaN();  // impulse to max deformation / M
  double restitution = std::numeric_limits<double>::quiet_NaN();  // whole-contact impulse / (M v_in) - 1
  double reprojection_residual_px = std::numeric_limits<double>::quiet_NaN();  // median, base markers
  // The plate correction closing the loop found (gain, drift), applied to
  // series.fz_n and peak_force_n; the peak as the plate read it beside it.
  // Empty / NaN when the loop corrected nothing.
  std::string force_correction;
  double peak_force_uncorrected_n = std::numeric_limits<double>::quiet_NaN();
  // The force channel's low-pass (2nd-order Butterworth corner, Hz; NaN:
  // none) and where it came from: "declared" in the manifest (its group
  // delay taken out of the force clock) or "named" by closing the loop (the
  // final mat model's plate force passes it, so the clock offset is the
  // clock's alone).
  double force_lowpass_hz = std::numeric_limits<double>::quiet_NaN();
  std::string force_lowpass_source;
  Series series;

  std::string report() const;
};

// Trapezoid integral of f (samples on the increasing times t) from a to b,
// the ends interpolated linearly between samples; beyond the samples f is
// held at its first or last value. 0 when b <= a.
double integrate(const Eigen::VectorXd& t, const Eigen::VectorXd& f, double a, double b);

// The trial from a processed force record.
TrialResult analyse(const forceplate::ForceTrial& force, const reconstruction::Trajectories& markers,
                    const TrialOptions& options);

// The trial from a raw force record: processes it, and when that fails
// (dropfit::Error) returns a rejected trial carrying the error text and the
// video-only measurements (impact velocity, deformation, tilt).
TrialResult analyse(const forceplate::Resultants& raw_force, const forceplate::ProcessOptions& force_options,
                    const reconstruction::Trajectories& markers, const TrialOptions& options);

// The trial without a usable force record (e.g. one that could not be
// converted): rejected with `force_error` as the reason, video-only
// measurements (impact velocity, deformation, tilt) still reported.
TrialResult analyse_without_force(const reconstruction::Trajectories& markers, const TrialOptions& options,
                                  const std::string& force_error);

// What the calibration achieved on its own points, and whether it failed
// its own check. `problem` is empty for a usable calibration; otherwise it
// says why every trial reconstructed with it is rejected:
// - a camera's fit RMS above max_fit_rms_px (10 px: 30-50 times the 0.2-0.3
//   px digitising noise and above what an uncorrected lens gives, a few px
//   at the image corners; only a mislabelled or sign-flipped point gets
//   there), or
// - the check markers' 3-D RMS error above max_check_rms_m (10 mm: ten times
//   the 1 mm a lab calibration is built for; good ones read 0.5-1.6 mm).
//
// vertical_scale_sd: the relative uncertainty of lengths measured along the
// lab's z axis, the check markers' RMS error in z over the z span of the
// calibration markers (the error field's slope across the structure); NaN
// without check markers or span. A vertical velocity carries it in full.
struct CalibrationQuality {
  double fit_rms_px = std::numeric_limits<double>::quiet_NaN();    // largest over cameras
  double check_rms_m = std::numeric_limits<double>::quiet_NaN();   // 3-D (norm of the per-axis RMS)
  double vertical_scale_sd = std::numeric_limits<double>::quiet_NaN();
  std::string problem;
  // Why vertical_scale_sd could not be measured (said with the declared
  // term), and whether the declared term applies (false: positions that no
  // camera calibration of the session measured, e.g. a motion-capture
  // system's markers.c3d; the interval is then the free-fall fit's, said so).
  std::string unchecked_reason = "the calibration was not checked (no check markers spanning a height)";
  bool declared_term = true;
};
constexpr double kMaxCalibrationFitRmsPx = 10.0;
constexpr double kMaxCalibrationCheckRmsM = 0.010;
// markers_z_span_m: the calibration markers' extent along z (max - min).
CalibrationQuality calibration_quality(const calibration::CalibrationResult& calibration,
                                       double markers_z_span_m = std::numeric_limits<double>::quiet_NaN());

// Widens the impact velocity's 95 % interval (the free-fall fit's, which
// sees only the digitising noise) by the calibration's vertical scale
// uncertainty: half-width = sqrt(fit^2 + (1.96 v scale_sd)^2). On 433
// trials of 87 independent sessions the fit's interval alone covered the
// true velocity in 74 %, this one in 96 %. scale_sd is the check markers'
// vertical_scale_sd; a calibration that was not checked (coefficients
// given without check markers, or check markers spanning no height) has
// no measured one, and the term is not dropped: it is the declared
// kDeclaredCalibrationScaleSd, and result.calibration_uncertainty says so.
// Also sets result.calibration_scale_sd, and contact_height_se_m where the
// contact height is the manifest's (the calibration's error at that height,
// scale_sd over the height).
constexpr double kDeclaredCalibrationScaleSd = 1e-3;
void add_calibration_uncertainty(TrialResult& result, const CalibrationQuality& quality);

// Rejects `result` (adding the reason) when the calibration failed its own
// check, or when the median reprojection residual of the base markers over
// the trial exceeds max(kMinResidualLimitPx, kResidualFactor x the
// calibration's fit RMS): a correctly labelled track reprojects to within
// the digitising noise (0.1-0.5 px here); a camera order swapped in the
// manifest or points crossed between cameras give tens of pixels. Sets
// result.reprojection_residual_px.
// Also rejects it when the rays miss each other steadily: the digitising
// noise makes the residual change from frame to frame by about its own
// size, while a camera moved after calibration (a bumped tripod) or a
// calibration of another setup makes a residual that stays while the noise
// rides on it. The trial is rejected when the median residual exceeds
// kSteadyResidualFactor x both the median frame-to-frame change of the
// residual and the calibration's fit RMS (what the calibration itself
// leaves between its rays).
// The cameras' rows must be the same instants (markers.camera_lags): a
// camera whose lag changes part-way (it alone lost or repeated a frame;
// CameraLag::changes_part_way) and whose two lags leave the rays within
// kLagResidualFactor times the calibration's fit RMS is named with the row
// it changes at (a camera moved after calibration can also be split into
// two lags, which trade its steady miss against the marker's motion before
// and after the bottom, but its rays still miss by several times that); one
// lag for the whole trial other than 0 (CameraLag::desynchronised) with
// that lag. Either is the trial's first reason.
// The tracks' columns in another order than [video].points
// (trial.cpp, point_order_reason): a point other than the base markers
// moves more than kPointOrderFallM vertically, and more than
// kPointOrderRatio times as far as the base markers.
constexpr double kPointOrderFallM = 0.3;
constexpr double kPointOrderRatio = 3.0;
constexpr double kMinResidualLimitPx = 5.0;
constexpr double kResidualFactor = 10.0;
constexpr double kSteadyResidualFactor = 5.0;
void apply_calibration_gates(TrialResult& result, const reconstruction::Trajectories& markers,
                             const TrialOptions& options, const CalibrationQuality& quality);

}  // namespace dropfit::trial
