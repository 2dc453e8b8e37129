// Synthetic drop-test sessions with known truth: see synth.h for the world
// it simulates. make_session() assembles a session from its parts: the mat
// (with the mat effects), the markers, the cameras and calibration
// (synth_cameras.cpp), the manifest, the effects and faults noted in the
// truth, and the trials (synth_trial.cpp). Plain computation, no files.
#include "samples/generator/synth.h"

#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cmath>
#include <iterator>

#include "samples/generator/synth_internal.h"

namespace dropfit::synth {
namespace detail {
namespace {

MatParams apply_mat_effects(const SynthOptions& o, SynthTruth& truth) {
  const Effects& fx = o.effects;
  MatParams params = o.use_default_params ? default_mat_params(o.model, o.layers) : o.params;
  if (fx.k1_cubic_n_m3 != 0.0) {
    params.k1_cubic_n_m3 = fx.k1_cubic_n_m3;
    truth.effects.push_back({"mat", "stiffness_nonlinearity", fx.k1_cubic_n_m3, "N/m^3",
                             fmt::format("element 1 force gains k1_cubic d^3, k1_cubic = {:.6g} N/m^3", fx.k1_cubic_n_m3)});
  }
  if (fx.r1_unload_n_s_m >= 0.0) {
    params.r1_unload_n_s_m = fx.r1_unload_n_s_m;
    truth.effects.push_back({"mat", "hysteresis", fx.r1_unload_n_s_m, "N s/m",
                             fmt::format("element 1 damping while extending is {:.6g} N s/m instead of r1 = {:.6g} N s/m",
                                         fx.r1_unload_n_s_m, params.r1_n_s_m)});
  }
  if (fx.hysteresis_h != 0.0) {
    require(fx.hysteresis_h > 0.0 && fx.hysteresis_h < 1.0, "hysteresis_elastic h must lie in (0, 1)");
    params.k1_hysteresis = fx.hysteresis_h;
    params.hysteresis_transition_m_s = fx.hysteresis_transition_m_s;
    truth.effects.push_back(
        {"mat", "hysteresis", fx.hysteresis_h, "h",
         fmt::format("element 1's elastic force times (1 - h (1 - tanh(d'/{:.3g}))/2), h = {:.6g}: {:.3g} times lower "
                     "while unloading (not extra damping)",
                     fx.hysteresis_transition_m_s, fx.hysteresis_h, 1.0 - fx.hysteresis_h)});
  }
  if (fx.maxwell_k_n_m > 0.0) {
    require(fx.maxwell_tau_s > 0.0, "rate_dependence needs a positive Maxwell time constant");
    params.maxwell_k_n_m = fx.maxwell_k_n_m;
    params.maxwell_tau_s = fx.maxwell_tau_s;
    truth.effects.push_back({"mat", "rate_dependence", fx.maxwell_k_n_m, "N/m",
                             fmt::format("Maxwell arm k = {:.6g} N/m, tau = {:.6g} s in parallel with element 1",
                                         fx.maxwell_k_n_m, fx.maxwell_tau_s)});
  }
  if (fx.layer_mass_shift_kg != 0.0) {
    require(o.model == ModelKind::Model3 || o.model == ModelKind::Model4,
            "layer_mass needs a layered model (3 or 4)");
    params.m1_kg += fx.layer_mass_shift_kg;
    params.m2_kg -= fx.layer_mass_shift_kg;
    require(params.m1_kg > 0.0 && params.m2_kg > 0.0,
            fmt::format("layer_mass {} kg leaves a layer without mass", fx.layer_mass_shift_kg));
    truth.effects.push_back({"mat", "layer_mass", fx.layer_mass_shift_kg, "kg",
                             fmt::format("true m1 = {:.6g} kg, m2 = {:.6g} kg (declared layers unchanged, total kept)",
                                         params.m1_kg, params.m2_kg)});
  }
  return params;
}

// Places the base and mat markers and records them in the truth.
MarkerLayout place_markers(const SynthOptions& o, SynthTruth& truth) {
  const double h_base = o.base_marker_height_m;
  MarkerLayout layout;
  Eigen::Vector3d(&base_offset)[2] = layout.base_offset;
  if (o.base_marker_layout == BaseMarkerLayout::DiagonalCorners) {
    const double ax = 0.5 * o.footprint_m.x(), ay = 0.5 * o.footprint_m.y();
    base_offset[0] = {ax, ay, h_base};
    base_offset[1] = {-ax, -ay, h_base};
  } else {
    base_offset[0] = {o.base_marker_spacing_m, 0.0, h_base};
    base_offset[1] = {-o.base_marker_spacing_m, 0.0, h_base};
  }
  Eigen::Vector2d(&mat_xy)[4] = layout.mat_xy;
  if (o.mat_marker_motion == MatMarkerMotion::Dish) {
    Rng lay(o.seed, kStreamLayout);
    const Eigen::Vector2d dirs[4] = {{0.0, 1.0}, {0.0, -1.0}, {1.0, 0.0}, {-1.0, 0.0}};
    for (int i = 0; i < 4; ++i) {
      // Within the range and at least 2 cm inside the mat's edge.
      const double edge = 0.5 * (i < 2 ? o.mat_width_m : o.mat_length_m) - 0.02;
      const double hi = std::max(o.mat_marker_min_radius_m, std::min(o.mat_marker_max_radius_m, edge));
      const double r = o.mat_marker_min_radius_m + (hi - o.mat_marker_min_radius_m) * lay.uniform();
      mat_xy[i] = r * dirs[i];
    }
  } else {
    const double ry = 0.5 * o.footprint_m.y() + o.surface_marker_clearance_m;
    const double rx = 0.5 * o.footprint_m.x() + o.surface_marker_clearance_m;
    mat_xy[0] = {0.0, ry}, mat_xy[1] = {0.0, -ry}, mat_xy[2] = {rx, 0.0}, mat_xy[3] = {-rx, 0.0};
  }
  truth.base_markers_impactor_m = {base_offset[0], base_offset[1]};
  truth.mat_markers_xy_m.assign(std::begin(mat_xy), std::end(mat_xy));
  return layout;
}

// The session manifest: impactor, mat, video and force plate.
void fill_manifest(const SynthOptions& o, double mat_top_m, const SynthTruth& truth, Session& session) {
  const double g = o.gravity_m_s2;
  Manifest& m = session.manifest;
  m.name = fmt::format("synthetic session (dropfit-synth, seed {})", o.seed);
  m.gravity_m_s2 = g;
  m.impactor.mass_kg = o.faults.declared_mass_kg > 0.0 ? o.faults.declared_mass_kg : o.impactor_mass_kg;
  m.impactor.footprint_m = o.footprint_m;
  m.impactor.base_markers = {"imp_base_front", "imp_base_back"};
  m.impactor.base_marker_height_m = o.base_marker_height_m;
  m.mat.length_m = o.mat_length_m;
  m.mat.width_m = o.mat_width_m;
  m.mat.surface_markers = {"mat_n", "mat_s", "mat_e", "mat_w"};
  m.mat.layers = o.layers;
  for (const TrueCamera& c : truth.cameras) m.video.cameras.push_back(c.camera.name);
  m.video.frame_rate_hz = o.frame_rate_hz;
  m.video.points = {"imp_base_front", "imp_base_back", "mat_n", "mat_s", "mat_e", "mat_w"};
  m.video.trigger_frame = o.trigger_frame;
  m.video.image_origin = ImageOrigin::TopLeft;
  m.forceplate.model = "Kistler 9281B";
  m.forceplate.sample_rate_hz = o.force_rate_hz;
  m.forceplate.trigger_threshold_n = o.trigger_threshold_n;
  m.forceplate.pretrigger_fraction = o.pretrigger_fraction;
  m.forceplate.a_m = o.plate_a_m;
  m.forceplate.b_m = o.plate_b_m;
  m.forceplate.az0_m = o.plate_az0_m;
  m.forceplate.mat_top_z_m = mat_top_m;
}

// Notes the sync and force-plate effects (time_offset, baseline_drift, force_scale) in the truth.
void note_sync_and_plate_effects(const SynthOptions& o, SynthTruth& truth) {
  const Effects& fx = o.effects;
  const double offset_s = fx.time_offset_ms * 1e-3;
  if (fx.time_offset_ms != 0.0)
    truth.effects.push_back({"sync", "time_offset", fx.time_offset_ms, "ms",
                             fmt::format("video clock minus force clock is {:.6g} s, not 0 as trigger_frame says",
                                         offset_s)});
  if (fx.baseline_drift_n_s != 0.0)
    truth.effects.push_back({"forceplate", "baseline_drift", fx.baseline_drift_n_s, "N/s",
                             fmt::format("Fz offset ramps at {} N/s {} (split equally over Fz1-Fz4)",
                                         fx.baseline_drift_n_s,
                                         fx.baseline_drift_whole_record ? "from the first sample"
                                                                        : "from the trigger sample on")});
  if (fx.force_scale != 1.0)
    truth.effects.push_back({"forceplate", "force_scale", fx.force_scale, "gain",
                             fmt::format("every channel reads {} times the true load", fx.force_scale)});
}

// Notes the instrument faults in the truth (stage "instrument").
void note_faults(const SynthOptions& o, SynthTruth& truth) {
  const InstrumentFaults& f = o.faults;
  static const char* const channel[8] = {"Fx12", "Fx34", "Fy14", "Fy23", "Fz1", "Fz2", "Fz3", "Fz4"};
  const std::string which = f.trials.empty() ? std::string("every trial")
                                             : fmt::format("trials (0-based) {}", fmt::join(f.trials, " "));
  if (f.dead_channel >= 0)
    truth.effects.push_back({"instrument", "dead_channel", static_cast<double>(f.dead_channel), "channel",
                             fmt::format("{} reads only its noise and offset in {}", channel[f.dead_channel], which)});
  if (f.reversed_channel >= 0)
    truth.effects.push_back({"instrument", "reversed_channel", static_cast<double>(f.reversed_channel), "channel",
                             fmt::format("{} reads the negative of its load in {}", channel[f.reversed_channel],
                                         which)});
  if (f.exchange_a >= 0 && f.exchange_b >= 0)
    truth.effects.push_back({"instrument", "exchanged_channels", 10.0 * f.exchange_a + f.exchange_b, "channels",
                             fmt::format("columns {} and {} exchanged in {}", channel[f.exchange_a],
                                         channel[f.exchange_b], which)});
  if (f.saturation_n > 0.0)
    truth.effects.push_back({"instrument", "saturation", f.saturation_n, "N",
                             fmt::format("each channel clipped at +-{} N before the ADC noise in {}", f.saturation_n,
                                         which)});
  if (f.amplifier_lowpass_hz > 0.0)
    truth.effects.push_back({"instrument", "amplifier_lowpass", f.amplifier_lowpass_hz, "Hz",
                             fmt::format("the analog force through a Butterworth low-pass of order {} at {} Hz",
                                         f.amplifier_lowpass_order, f.amplifier_lowpass_hz)});
  if (f.softening_per_trial > 0.0)
    truth.effects.push_back({"mat", "softening", f.softening_per_trial, "per trial",
                             "every stiffness of trial k (recording order, 0-based) times (1 - s)^k"});
  if (f.declared_mass_kg > 0.0 && f.declared_mass_kg != o.impactor_mass_kg)
    truth.effects.push_back({"instrument", "declared_mass", f.declared_mass_kg, "kg",
                             fmt::format("the manifest declares {} kg; the impactor has {} kg", f.declared_mass_kg,
                                         o.impactor_mass_kg)});
}

}  // namespace
}  // namespace detail

SyntheticSession make_session(const SynthOptions& o) {
  using namespace detail;
  validate(o);
  const Effects& fx = o.effects;
  SyntheticSession out;
  Session& session = out.session;
  SynthTruth& truth = out.truth;

  double mat_top_m = 0.0;
  for (const LayerSpec& l : o.layers) mat_top_m += l.thickness_m;
  const double g = o.gravity_m_s2;

  const MatParams params = apply_mat_effects(o, truth);
  const MarkerLayout layout = place_markers(o, truth);
  make_true_cameras(o, mat_top_m, layout, truth);
  const int n_cam = static_cast<int>(truth.cameras.size());
  make_calibration(o, mat_top_m, truth, session);
  fill_manifest(o, mat_top_m, truth, session);
  Manifest& m = session.manifest;
  note_sync_and_plate_effects(o, truth);
  note_faults(o, truth);
  const double offset_s = fx.time_offset_ms * 1e-3;

  const int n_pts = static_cast<int>(m.video.points.size());

  const int n = o.n_samples;
  const int npre = static_cast<int>(std::lround(o.pretrigger_fraction * n));
  const double fs = o.force_rate_hz;
  const double t_end_force = (n - 1 - npre) / fs;
  const double t_end_video = (o.n_frames - 1 - o.trigger_frame) / o.frame_rate_hz - offset_s;

  truth.seed = o.seed;
  truth.world = o.world;
  truth.model = o.model;
  truth.params = params;
  truth.foam = o.foam;
  truth.points = m.video.points;
  truth.mat_top_z_m = mat_top_m;
  truth.pixel_noise_px = o.pixel_noise_px;
  truth.channel_noise_n = o.channel_noise_n;

  const TrialSetup setup{o, params, layout, truth.cameras, m, g, mat_top_m, offset_s, fs, t_end_force, t_end_video,
                         n, npre, n_pts, n_cam};
  for (std::size_t ti = 0; ti < o.impact_velocities_m_s.size(); ++ti) {
    SimulatedTrial st = simulate_trial(setup, ti);
    m.trials.push_back(st.trial.spec);
    session.trials.push_back(std::move(st.trial));
    truth.trials.push_back(std::move(st.tt));
  }
  return out;
}

}  // namespace dropfit::synth
