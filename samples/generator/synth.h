#pragma once
// Synthetic drop-test sessions with known truth (samples/).
//
// make_session() builds, in memory, exactly the capture::Session that
// capture::read_session would return for a lab's session folder, together
// with the truth it was made from, so that every stage can be tested against
// values it did not compute. The world it simulates:
//
// * Lab frame as in docs/formats.md: origin at the centre of
//   the force-plate top, Z up, X along the mat's long side. The mat lies on
//   the plate, centred, its undeformed top at the sum of the layer
//   thicknesses (0.205 m by default).
// * Impactor: falls freely under gravity (held at rest before its release,
//   v^2 / 2g above the mat) until its face centre reaches the mat top; from
//   then on its face follows the generator's OWN mat physics
//   (samples/generator/physics.h: its own equations of Models 1-4 and its own
//   Dormand-Prince integrator; nothing from fitting/), sampled at 10 us and
//   linearly interpolated. The physics is one-dimensional: the impactor keeps
//   a constant tilt (per trial |N(2.6, 0.87)| deg, about lab Y or, with
//   tilt_random_axis, about a random horizontal axis) and a constant
//   horizontal impact point scattered about the plate centre. After the
//   rebound it flies freely (and may land again) or, with catch_at_apex, is
//   caught at the top of its rebound, as a lab's catcher does.
// * Markers: two on the impactor base, either front/back along the
//   impactor's X (base_marker_spacing_m) or at the face's diagonal corners
//   (BaseMarkerLayout::DiagonalCorners), base_marker_height_m above the face
//   and rotated with the tilt; four on the mat top (north/south along +-Y,
//   east/west along +-X). MatMarkerMotion::FollowSurface (the classic world)
//   moves them with the mat top under the impactor; MatMarkerMotion::Dish
//   (the lab world) puts them 0.22-0.32 m from the mat centre, beside the
//   footprint, moving with the TOP LAYER's travel times a dish factor
//   w = exp(-((d - 0.125) / 0.25)^2) of their distance d from the impact point.
// * Cameras: two pinhole cameras K [R | t] with square pixels, optical axes
//   camera_angle_deg apart, camera_distance_m from the centre of the
//   calibrated volume, seen from the mat's -Y side and slightly from above,
//   with a small roll each; the focal length makes the calibrated volume
//   fill `image_fill` of the image. The truth holds each camera's exact
//   11-parameter DLT (P normalised by P(3,4)), and, when lens distortion is
//   injected, Bouguet's k1 k2 p1 p2 k3 applied to the pinhole pixel about the
//   principal point with the radius normalised by the focal length (the
//   convention of calibration/calibration.h, so a dlt16 fit can represent
//   it exactly).
// * Calibration structure: 20 non-coplanar markers spanning the mat volume
//   and the impactor's last ~0.5 m of fall; ids c01..c20, odd ones `fit`,
//   even ones `check`.
// * Force plate: Kistler eight-channel record (spec formulas). Fz is the
//   model's ground reaction force times the plate gain, plus drift, channel
//   noise and per-channel zero offsets; Fx and Fy are small fixed fractions
//   of Fz; the centre of pressure is the impact point. The four vertical
//   sensor loads are solved from Fz, Mx, My and a zero-twist condition
//   (Fz1 - Fz2 + Fz3 - Fz4 = 0), the shear pairs split equally (Mz = 0).
//   The trigger sample (first zeroed Fz >= trigger threshold) is t = 0 and
//   sits at index `pretrigger samples`; first contact falls at a random
//   sub-sample phase before it.
// * Clocks: video frame i is at video time (i - trigger_frame) / frame rate;
//   its force-clock time is that minus the true video offset (zero unless
//   time_offset is injected; results-format.md's video_offset_s).
//
// * Digitising (lab world): tracks only from digitised_from_s to
//   digitised_to_s about contact, NaN elsewhere, with random 1-5-frame gaps
//   (some in both cameras).
//
// Worlds: SynthOptions{} is the CLASSIC world the older tests were written
// for (mat markers follow the surface, whole records digitised, 1 N noise,
// 1 s force records). lab_session_options() is the realistic session a lab
// has (every option above at its lab value: dish markers, corner base
// markers at face height, 15 mm impact scatter, tilt about a random axis,
// -0.1..+0.15 s digitised windows with gaps, 5 s force records with 1.5 N
// noise per channel, 0.3 px marker and 0.2 px calibration noise, the
// impactor caught at its apex); independent_world_options(seed) adds a
// random plausible mat and impact speeds; add_random_effects() a random mix
// of effects (for archives: scripts/make-archive).
//
// Injected effects (Effects below) are not declared anywhere in the session
// folder; only the truth names them, with their magnitudes.
#include <Eigen/Core>
#include <cstdint>
#include <limits>
#include <optional>
#include <string>
#include <vector>

#include "calibration/calibration.h"
#include "capture/session.h"
#include "samples/generator/foam.h"
#include "samples/generator/physics.h"

namespace dropfit::synth {

// Effects to inject; every default is "off". Names and stages follow
// docs/formats.md's effect table.
struct Effects {
  // calibration / lens_distortion: Bouguet k1 on both cameras (k2 p1 p2 k3 from
  // SynthOptions::extra_distortion).
  double lens_distortion_k1 = 0.0;
  // calibration / lens_distortion given as its size: the radial k1 that
  // moves the trial marker farthest from the image centre by this many
  // pixels (about 1 px in a lab; overrides lens_distortion_k1 when > 0).
  double lens_distortion_px = 0.0;
  // calibration / outlier_marker as a labelling slip: in the last camera two
  // fit markers' image points swapped.
  bool outlier_swap = false;
  // calibration / outlier_marker: one fit marker misplaced in the last camera
  // by exactly this many pixels, towards the marker whose image distance is
  // closest to it (so a magnitude equal to that distance is a mislabel: the
  // row holds the other marker's pixel). 0 = off.
  double outlier_marker_px = 0.0;
  // sync / time_offset: true video offset (video clock minus force clock) in ms.
  double time_offset_ms = 0.0;
  // forceplate / baseline_drift: Fz offset ramp in N/s, from the trigger
  // sample on (or from the first sample when baseline_drift_whole_record).
  double baseline_drift_n_s = 0.0;
  bool baseline_drift_whole_record = false;
  // forceplate / force_scale: plate gain error (1 = off), applied to all channels.
  double force_scale = 1.0;
  // mat / stiffness_nonlinearity: MatParams::k1_cubic_n_m3.
  double k1_cubic_n_m3 = 0.0;
  // mat / hysteresis: MatParams::r1_unload_n_s_m (negative = off).
  double r1_unload_n_s_m = -1.0;
  // mat / hysteresis as a lower ELASTIC force while unloading: element 1's
  // elastic force times (1 - h (1 - tanh(d'/v_h)) / 2) (0 = off; 0.1-0.3 real).
  double hysteresis_h = 0.0;
  double hysteresis_transition_m_s = 0.05;
  // mat / rate_dependence: Maxwell arm stiffness (0 = off) and time constant.
  double maxwell_k_n_m = 0.0;
  double maxwell_tau_s = 0.01;
  // mat / layer_mass: mass moved from the bottom layer to the top one (kg;
  // negative moves it down); the declared layers and the total stay.
  double layer_mass_shift_kg = 0.0;
};

// Sets one effect by its results-format name (or a variant): lens_distortion
// (k1), lens_distortion_px (px at the outermost trial marker), outlier_swap
// (any non-zero: two fit markers swapped in one camera), hysteresis_elastic
// (h), ...
// outlier_marker (px), time_offset (ms), baseline_drift (N/s), force_scale
// (gain), stiffness_nonlinearity (k1_cubic, N/m^3), hysteresis (r1_unload,
// N s/m), rate_dependence (Maxwell k, N/m), layer_mass (kg moved to the top
// layer). Throws dropfit::Error on an unknown name.
void set_effect(Effects& effects, const std::string& name, double magnitude);
std::vector<std::string> effect_names();

// A marker hidden from one camera (or all, camera = -1) for some frames.
struct Gap {
  int trial = 0;           // 0-based
  std::string point;       // a name from the session's [video].points
  int camera = -1;         // 0-based; -1 = every camera
  int first_frame = 0;
  int n_frames = 0;
};

// Instrument faults a lab meets (not effects of the results format: the
// instrument is broken, not the model incomplete). Every default is "off";
// the truth names each one set. Channels are numbered 0-7 in the file's
// order Fx12 Fx34 Fy14 Fy23 Fz1 Fz2 Fz3 Fz4.
struct InstrumentFaults {
  int dead_channel = -1;       // reads only its noise and zero offset (a broken cable or amplifier)
  int reversed_channel = -1;   // reads the negative of its load (a wrongly wired charge amplifier)
  int exchange_a = -1;         // two columns exchanged in the file (both >= 0 to apply)
  int exchange_b = -1;
  // Charge amplifier range: each channel clipped at +- this after the drift
  // and before the noise (the ADC's); 0 = off.
  double saturation_n = 0.0;
  // The analog force through an Nth-order Butterworth low-pass at this
  // corner before sampling (0 = off); the noise is the ADC's, after it.
  double amplifier_lowpass_hz = 0.0;
  int amplifier_lowpass_order = 2;
  // The mat loses stiffness between trials: every stiffness of trial k
  // (0-based, recording order = the order of impact_velocities_m_s) is
  // (1 - softening_per_trial)^k times the mat's.
  double softening_per_trial = 0.0;
  // The impactor mass the manifest declares (0: the true impactor_mass_kg).
  double declared_mass_kg = 0.0;
  // The trials (0-based) the channel faults and saturation apply to; empty = every trial.
  std::vector<int> trials;
};

// Sets one instrument fault by name: dead_channel, reversed_channel
// (channel 0-7), exchanged_channels (a two-digit number: 47 exchanges
// channels 4 and 7), saturation (N per channel), amplifier_lowpass (Hz),
// softening (fraction per trial), declared_mass (kg), second_impact (any
// non-zero: the impactor is not caught and lands again). Throws
// dropfit::Error on an unknown name.
std::vector<std::string> fault_names();

enum class MatMarkerMotion {
  FollowSurface,  // classic: the mat top under the impactor
  Dish,           // lab: top layer travel times exp(-((d - dish_centre) / dish_width)^2)
};
enum class BaseMarkerLayout {
  FrontBack,        // classic: +-base_marker_spacing_m along the impactor's X
  DiagonalCorners,  // lab: the face's (+x, +y) and (-x, -y) corners
};

struct SynthOptions {
  std::uint64_t seed = 1;
  std::string world = "classic";  // a label for the truth file (classic, lab, independent)
  // One trial per velocity (downward speed at first contact), the paper's Table 1.
  std::vector<double> impact_velocities_m_s{4.30, 4.80, 5.25, 5.75, 6.50};
  double gravity_m_s2 = 9.81;

  // Impactor.
  double impactor_mass_kg = 24.0;
  Eigen::Vector2d footprint_m{0.25, 0.25};
  double base_marker_height_m = 0.03;   // above the contact face
  double base_marker_spacing_m = 0.10;  // front/back of the face centre
  double tilt_mean_deg = 2.6;           // per-trial tilt ~ N(mean, sd), about lab Y, random sign
  double tilt_sd_deg = 0.87;
  double impact_point_sd_m = 0.01;      // impact point's offset from the plate centre, per axis
  bool tilt_random_axis = false;        // tilt about a random horizontal axis (else about lab Y)
  BaseMarkerLayout base_marker_layout = BaseMarkerLayout::FrontBack;
  // After the rebound: caught at its apex (true) or free to land again.
  bool catch_at_apex = false;

  // Mat (declared in the manifest; the true masses are in `params`).
  double mat_length_m = 0.90;
  double mat_width_m = 0.60;
  std::vector<LayerSpec> layers{{"carpet", 0.005, 0.0}, {"stiff", 0.05, 2.44}, {"soft", 0.15, 3.66}};
  double surface_marker_clearance_m = 0.03;  // outside the footprint edge (FollowSurface)
  MatMarkerMotion mat_marker_motion = MatMarkerMotion::FollowSurface;
  double mat_marker_min_radius_m = 0.22;  // Dish: each marker's distance from the mat centre,
  double mat_marker_max_radius_m = 0.32;  //   drawn uniformly in this range
  double dish_centre_m = 0.125;
  double dish_width_m = 0.25;

  // Mat physics. use_default_params: default_mat_params(model, layers).
  ModelChoice model = ModelKind::Model4;
  bool use_default_params = true;
  MatParams params;
  // A foam column (foam.h) in place of the chain when set: the continuum
  // world (model and params are then unused; layers declare the two foams).
  std::optional<FoamColumn> foam;

  // Cameras.
  int image_width_px = 1024;
  int image_height_px = 1024;
  double camera_angle_deg = 86.0;     // between the optical axes
  double camera_distance_m = 3.0;     // from the centre of the calibrated volume
  double camera_elevation_deg = 12.0; // optical axes look down by this much
  double image_fill = 0.85;           // calibrated volume's half-extent / half-image
  double pixel_noise_px = 0.25;       // Gaussian SD per coordinate (tracks; calibration too unless below)
  double calibration_pixel_noise_px = -1.0;  // negative: pixel_noise_px
  std::vector<double> extra_distortion{0.0, 0.0, 0.0, 0.0};  // k2 p1 p2 k3, used with lens_distortion

  // Video.
  double frame_rate_hz = 1000.0;
  int n_frames = 600;
  int trigger_frame = 200;
  // Digitised window about first contact (force-clock seconds from contact);
  // frames outside it are NaN. Infinite = every frame.
  double digitised_from_s = -std::numeric_limits<double>::infinity();
  double digitised_to_s = std::numeric_limits<double>::infinity();
  // Random gaps per trial inside the window: count, 1..gap_max_frames long,
  // a fraction of them in both cameras.
  int random_gaps_per_trial = 0;
  int gap_max_frames = 5;
  double gap_both_cameras_fraction = 0.3;

  // Force plate.
  double force_rate_hz = 1000.0;
  int n_samples = 1000;
  double pretrigger_fraction = 0.10;
  double trigger_threshold_n = 25.0;
  double plate_a_m = 0.120;
  double plate_b_m = 0.200;
  double plate_az0_m = -0.040;
  double channel_noise_n = 1.0;       // Gaussian SD per channel
  double channel_offset_sd_n = 2.0;   // per-channel zero offsets ~ N(0, sd)
  double shear_fraction_max = 0.02;   // |Fx| / Fz and |Fy| / Fz drawn uniformly below this

  std::vector<Gap> gaps;
  Effects effects;
  InstrumentFaults faults;
};

void set_fault(SynthOptions& options, const std::string& name, double magnitude);

// The paper-like default parameters of each model (see synth_options.cpp for how the
// Model 4 set was chosen); masses from the declared layers (m1 = all layers
// but the last, m2 = the last).
MatParams default_mat_params(ModelChoice model, const std::vector<LayerSpec>& layers);

struct TrueCamera {
  calibration::Camera camera;          // dlt, and distortion with principal point and focal when injected
  Eigen::Matrix3d k = Eigen::Matrix3d::Identity();  // intrinsics (square pixels, no skew)
  Eigen::Matrix3d cam_from_lab_r = Eigen::Matrix3d::Identity();
  Eigen::Vector3d cam_from_lab_t = Eigen::Vector3d::Zero();
  Eigen::Vector3d centre_lab_m = Eigen::Vector3d::Zero();
  int width_px = 0;
  int height_px = 0;
};

struct TrueCalibrationMarker {
  std::string id;
  Eigen::Vector3d lab_m;
  MarkerRole role = MarkerRole::Fit;
  std::vector<Eigen::Vector2d> image_px;  // noise-free (distorted when injected), per camera
};

struct InjectedEffect {
  std::string stage;   // calibration, sync, forceplate, mat
  std::string name;    // results-format effect name
  double magnitude = 0.0;
  std::string unit;
  std::string detail;  // what exactly was done
};

struct TrialTruth {
  std::string id;
  double impact_velocity_m_s = 0.0;
  double max_deformation_m = 0.0;   // largest impactor-face travel below the mat top
  double max_surface_travel_m = 0.0;
  double peak_force_n = 0.0;        // true GRF peak (before the plate's gain)
  double time_to_peak_s = 0.0;      // from first contact
  double tilt_deg = 0.0;            // largest deviation from vertical during contact (>= 0)
  double tilt_about_y_deg = 0.0;    // signed rotation about lab +Y at first contact (+: +X side lower)
  double contact_time_s = 0.0;      // first contact on the force clock (trigger = 0)
  double separation_time_s = 0.0;   // impactor leaves the mat, force clock (NaN if not)
  double video_offset_s = 0.0;      // video clock minus force clock
  double drop_height_m = 0.0;       // v^2 / 2g
  int trigger_index = 0;            // always the pretrigger sample count
  Eigen::Vector2d cop_m = Eigen::Vector2d::Zero();           // plate frame = lab x, y
  Eigen::Vector2d impact_point_m = Eigen::Vector2d::Zero();  // face centre's x, y
  Eigen::Vector2d shear_fraction = Eigen::Vector2d::Zero();  // Fx / Fz, Fy / Fz
  Eigen::Matrix<double, 8, 1> channel_offsets_n = Eigen::Matrix<double, 8, 1>::Zero();
  ModelChoice model = ModelKind::Model4;
  MatParams params;        // true, effects included
  // On the force clock, one per force sample: the true (unscaled, noise-free)
  // GRF and the impactor-face and mat-surface travel below the mat top.
  Eigen::VectorXd t_s, grf_n, impactor_travel_m, surface_travel_m;
  // Also per force sample: the mat masses' travel (Model 2: m_eff; 3, 4: m1,
  // m2) and what the plate reads before noise and zero offsets (gain and
  // drift included, zeroed Fz).
  Eigen::VectorXd layer1_travel_m, layer2_travel_m, plate_fz_noise_free_n;
  double tilt_axis_deg = 90.0;      // the tilt's horizontal axis from lab +X (90 = about +Y)
  std::vector<double> dish_factors; // per mat marker (1 for FollowSurface)
  int digitised_first_frame = 0;    // digitised window (inclusive), before gaps
  int digitised_last_frame = 0;
  double impact_velocity_after_m_s = 0.0;  // upward speed at separation (NaN if none)
  // Per video frame: its force-clock time and the true 3-D marker positions
  // (n_frames x 3 n_points, point p in columns 3p..3p+2, [video].points order).
  Eigen::VectorXd frame_force_time_s;
  Eigen::MatrixXd markers_lab_m;
  std::vector<Gap> gaps;
};

struct SynthTruth {
  std::uint64_t seed = 0;
  ModelChoice model = ModelKind::Model4;
  MatParams params;  // true, effects included (the same in every trial)
  std::optional<FoamColumn> foam;  // the continuum world's mat (params unused then)
  std::vector<TrueCamera> cameras;
  std::vector<TrueCalibrationMarker> calibration_markers;
  std::vector<std::string> points;  // [video].points
  // Marker layout: base markers in the impactor's frame (origin at the face
  // centre, X front, Z up; rotated by the tilt), mat markers' lab x, y.
  std::vector<Eigen::Vector3d> base_markers_impactor_m;
  std::vector<Eigen::Vector2d> mat_markers_xy_m;
  std::string world;
  double mat_top_z_m = 0.0;
  double pixel_noise_px = 0.0;
  double calibration_pixel_noise_px = 0.0;
  double channel_noise_n = 0.0;
  std::vector<InjectedEffect> effects;
  std::vector<TrialTruth> trials;
};

struct SyntheticSession {
  Session session;  // root is empty: set by whoever writes it
  SynthTruth truth;
};

// Throws dropfit::Error on impossible options (no trials, a record too short
// to hold the trigger, a trial that never reaches the trigger threshold, ...).
SyntheticSession make_session(const SynthOptions& options);

// ---- Presets ------------------------------------------------------------------

// The realistic session a lab has (see the header comment), with the
// generator's default Model 4 mat and no effect.
SynthOptions lab_session_options(std::uint64_t seed = 1);
// The lab session with a random plausible mat (k1 2e4-1e5 N/m, k2 and k3
// 5e5-2e6 N/m, cubic 0 or 2e6-8e6 N/m^3, damping tens to hundreds N s/m;
// drawn until the fastest trial stays within 75 % of the mat thickness) and
// five impact speeds in 4.0-6.2 m/s. The cubic term is named in the truth
// as stiffness_nonlinearity.
SynthOptions independent_world_options(std::uint64_t seed);
// The lab session on a foam column (foam.h) drawn from the seed: a soft
// top foam (0.095-0.13 m, 2.0-2.9 kg) over a stiff base (0.06-0.09 m,
// 3.0-4.2 kg), each with its plateau, hardening and densification, two
// relaxing stresses (1-4 ms and 20-80 ms) and a little viscosity; drawn
// until the fastest trial stays within 88 % of the column and leaves it,
// its peak within 25 % and its travel within 20 mm of the paper's Table 1;
// five impact speeds in 4.0-6.5 m/s. No mat effect is named in the truth
// (the chain's effect names do not describe a continuum).
SynthOptions foam_world_options(std::uint64_t seed);
// A random mix of effects (none, one or several), drawn from the seed, at
// realistic sizes: lens_distortion (~1 px), outlier swap, time_offset,
// baseline_drift, force_scale, elastic hysteresis, a weak Maxwell arm
// (25-30 kN/m, tau 20-30 ms), layer_mass.
void add_random_effects(SynthOptions& options, std::uint64_t seed);

// ---- Pieces, public for the tests -------------------------------------------

// The eight Kistler channels (Fx12 Fx34 Fy14 Fy23 Fz1 Fz2 Fz3 Fz4) whose spec
// formulas give back force f_n (Fx Fy Fz) with centre of pressure cop_m
// (ax, ay), Mz = 0 and zero twist of the vertical sensors.
Eigen::Matrix<double, 8, 1> kistler_channels(const Eigen::Vector3d& f_n, const Eigen::Vector2d& cop_m, double a_m,
                                             double b_m, double az0_m);

// The 11 DLT coefficients of a 3 x 4 projection matrix (divided by P(3,4)).
// Throws dropfit::Error when P(3,4) is (nearly) zero.
calibration::Dlt11 dlt_from_projection(const Eigen::Matrix<double, 3, 4>& image_from_lab);

// Bouguet distortion (k1 k2 p1 p2 k3) of an ideal pinhole pixel about the
// principal point, radius normalised by the focal length.
Eigen::Vector2d distort_px(const Eigen::Vector2d& ideal_px, const Eigen::Vector2d& principal_point_px, double focal_px,
                           const std::vector<double>& k);

// Projects a lab point with a true camera (distortion included).
Eigen::Vector2d project_px(const TrueCamera& camera, const Eigen::Vector3d& lab_m);

// ---- Edges ------------------------------------------------------------------

// The truth as JSON (nlohmann-json); written whole (temporary name, rename).
void write_truth_json(const std::string& path, const SynthTruth& truth);

}  // namespace dropfit::synth
