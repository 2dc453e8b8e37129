// Synthetic sessions' options: their checks, the named effects and faults,
// the default mats and the world presets (samples/generator/synth.h).
//
// Default Model 4 parameters: a quick scan about the paper's Table 2 Model 4
// set (k1 72075, k2 1061532, k3 748625 N/m; r1 263, r2 761, r3 1007 N s/m;
// m1 2.44, m2 3.66 kg): k1 x {0.9, 1.0, 1.1, 1.2, 1.3}, k2 and k3 x {0.8, 1,
// 1.25}, each r x {0.5, 1, 2, 3}, scored by the summed squared relative
// errors of peak GRF and largest impactor travel against the paper's Table 1
// over its five velocities. Kept: k1 x 1.1, k2 x 0.8, k3 x 1, every r x 0.5:
//   k1 79282.5, k2 849226, k3 748625 N/m; r1 131.5, r2 380.5, r3 503.5 N s/m
//   v (m/s)          4.30    4.80    5.25    5.75    6.50
//   peak GRF (N)     5718    6355    6929    7566    8523   (Table 1: 5593-9597)
//   deformation (m)  0.0804  0.0894  0.0975  0.1064  0.1199 (Table 1: 0.088-0.118)
//   time to peak 29 ms, separation after 60 ms.
// (A linear model cannot follow the real mat's stiffening: its peak force
// and deformation both grow in proportion to v; the scan's optimum with
// damping x 0.25 fitted slightly better but bounced back more than a landing
// mat does.)
#include <fmt/format.h>
#include <fmt/ranges.h>

#include <algorithm>
#include <cmath>

#include "samples/generator/synth_internal.h"

namespace dropfit::synth {
namespace detail {

void validate(const SynthOptions& o) {
  require(!o.impact_velocities_m_s.empty(), "no trials: impact_velocities_m_s is empty");
  for (double v : o.impact_velocities_m_s)
    require(std::isfinite(v) && v > 0.0, fmt::format("impact velocity {} m/s must be positive", v));
  require(o.gravity_m_s2 > 0.0, "gravity must be positive");
  require(o.impactor_mass_kg > 0.0, "impactor mass must be positive");
  require(o.footprint_m.minCoeff() > 0.0, "impactor footprint must be positive");
  require(o.mat_length_m > 0.0 && o.mat_width_m > 0.0, "mat size must be positive");
  require(!o.layers.empty(), "the mat needs at least one layer");
  for (const LayerSpec& l : o.layers)
    require(l.thickness_m > 0.0 && l.mass_kg >= 0.0, fmt::format("layer '{}' needs a positive thickness", l.name));
  require(o.image_width_px > 0 && o.image_height_px > 0, "image size must be positive");
  require(o.camera_angle_deg > 10.0 && o.camera_angle_deg < 170.0, "camera angle must be within 10-170 deg");
  require(o.camera_distance_m > 0.5, "cameras must stand at least 0.5 m from the volume");
  require(o.image_fill > 0.0 && o.image_fill <= 1.0, "image_fill must be within (0, 1]");
  require(o.pixel_noise_px >= 0.0, "pixel noise must not be negative");
  require(o.extra_distortion.size() == 4, "extra_distortion holds k2 p1 p2 k3 (4 values)");
  require(o.frame_rate_hz > 0.0 && o.force_rate_hz > 0.0, "frame and sample rates must be positive");
  require(o.n_frames >= 2, "at least two video frames");
  require(o.trigger_frame >= 0 && o.trigger_frame < o.n_frames,
          fmt::format("trigger_frame {} outside the {} frames", o.trigger_frame, o.n_frames));
  require(o.n_samples >= 2, "at least two force samples");
  require(o.pretrigger_fraction > 0.0 && o.pretrigger_fraction < 1.0, "pretrigger_fraction must be within (0, 1)");
  const long npre = std::lround(o.pretrigger_fraction * o.n_samples);
  require(npre >= 1 && npre < o.n_samples,
          fmt::format("pretrigger fraction {} of {} samples leaves no pre-trigger part", o.pretrigger_fraction,
                      o.n_samples));
  require(o.trigger_threshold_n > 0.0, "trigger threshold must be positive");
  require(o.channel_noise_n >= 0.0 && o.channel_offset_sd_n >= 0.0, "channel noise and offsets must not be negative");
  require(o.effects.force_scale > 0.0, "force_scale must be positive");
  require(o.digitised_from_s < o.digitised_to_s, "the digitised window must end after it starts");
  require(o.random_gaps_per_trial >= 0 && o.gap_max_frames >= 1, "random gaps: a count >= 0 and lengths >= 1 frame");
  require(o.mat_marker_min_radius_m > 0.0 && o.mat_marker_max_radius_m >= o.mat_marker_min_radius_m &&
              o.mat_marker_max_radius_m < 0.5 * std::max(o.mat_length_m, o.mat_width_m) &&
              o.mat_marker_min_radius_m < 0.5 * std::min(o.mat_length_m, o.mat_width_m),
          "mat marker radii must be positive, ordered and on the mat");
  require(o.dish_width_m > 0.0, "dish width must be positive");
  require(o.effects.lens_distortion_px >= 0.0, "lens_distortion_px must not be negative");
  require(o.effects.hysteresis_h >= 0.0 && o.effects.hysteresis_h < 1.0, "hysteresis_elastic h must lie in [0, 1)");
  require(o.effects.outlier_marker_px >= 0.0, "outlier_marker must not be negative");
  const InstrumentFaults& f = o.faults;
  for (int c : {f.dead_channel, f.reversed_channel, f.exchange_a, f.exchange_b})
    require(c >= -1 && c < 8, fmt::format("fault channel {} is not one of 0-7", c));
  require(f.saturation_n >= 0.0 && f.amplifier_lowpass_hz >= 0.0 && f.declared_mass_kg >= 0.0,
          "saturation, low-pass corner and declared mass must not be negative");
  require(f.amplifier_lowpass_order == 2 || f.amplifier_lowpass_order == 4, "the low-pass order is 2 or 4");
  require(f.softening_per_trial >= 0.0 && f.softening_per_trial < 1.0, "softening per trial must lie in [0, 1)");
  for (const Gap& g : o.gaps)
    require(g.trial >= 0 && g.trial < static_cast<int>(o.impact_velocities_m_s.size()) && g.n_frames >= 0 &&
                g.first_frame >= 0,
            fmt::format("gap of trial {} frames {}+{}: no such trial or a negative frame", g.trial + 1,
                        g.first_frame, g.n_frames));
}

}  // namespace detail

using detail::Rng;

std::vector<std::string> effect_names() {
  return {"lens_distortion",        "lens_distortion_px", "outlier_marker",     "outlier_swap",
          "time_offset",            "baseline_drift",     "force_scale",        "stiffness_nonlinearity",
          "hysteresis",             "hysteresis_elastic", "rate_dependence",    "layer_mass"};
}

void set_effect(Effects& e, const std::string& name, double magnitude) {
  if (!std::isfinite(magnitude)) throw Error(fmt::format("effect {}: magnitude must be finite", name));
  if (name == "lens_distortion")
    e.lens_distortion_k1 = magnitude;
  else if (name == "lens_distortion_px")
    e.lens_distortion_px = magnitude;
  else if (name == "outlier_swap")
    e.outlier_swap = magnitude != 0.0;
  else if (name == "hysteresis_elastic")
    e.hysteresis_h = magnitude;
  else if (name == "outlier_marker")
    e.outlier_marker_px = magnitude;
  else if (name == "time_offset")
    e.time_offset_ms = magnitude;
  else if (name == "baseline_drift")
    e.baseline_drift_n_s = magnitude;
  else if (name == "force_scale")
    e.force_scale = magnitude;
  else if (name == "stiffness_nonlinearity")
    e.k1_cubic_n_m3 = magnitude;
  else if (name == "hysteresis")
    e.r1_unload_n_s_m = magnitude;
  else if (name == "rate_dependence")
    e.maxwell_k_n_m = magnitude;
  else if (name == "layer_mass")
    e.layer_mass_shift_kg = magnitude;
  else
    throw Error(fmt::format("unknown effect '{}' (known: {})", name, fmt::join(effect_names(), ", ")));
}

std::vector<std::string> fault_names() {
  return {"dead_channel", "reversed_channel", "exchanged_channels", "saturation", "amplifier_lowpass",
          "softening",    "declared_mass",    "second_impact"};
}

void set_fault(SynthOptions& o, const std::string& name, double magnitude) {
  if (!std::isfinite(magnitude)) throw Error(fmt::format("fault {}: magnitude must be finite", name));
  InstrumentFaults& f = o.faults;
  const int whole = static_cast<int>(std::lround(magnitude));
  if (name == "dead_channel")
    f.dead_channel = whole;
  else if (name == "reversed_channel")
    f.reversed_channel = whole;
  else if (name == "exchanged_channels")
    f.exchange_a = whole / 10, f.exchange_b = whole % 10;
  else if (name == "saturation")
    f.saturation_n = magnitude;
  else if (name == "amplifier_lowpass")
    f.amplifier_lowpass_hz = magnitude;
  else if (name == "softening")
    f.softening_per_trial = magnitude;
  else if (name == "declared_mass")
    f.declared_mass_kg = magnitude;
  else if (name == "second_impact")
    o.catch_at_apex = magnitude == 0.0;
  else
    throw Error(fmt::format("unknown fault '{}' (known: {})", name, fmt::join(fault_names(), ", ")));
}

MatParams default_mat_params(ModelChoice model_choice, const std::vector<LayerSpec>& layers) {
  const ModelKind model = model_choice.kind();
  MatParams p;
  double total = 0.0;
  for (const LayerSpec& l : layers) total += l.mass_kg;
  const double m2 = layers.empty() ? 0.0 : layers.back().mass_kg;
  const double m1 = total - m2;
  switch (model) {
    case ModelKind::Model1:  // Table 2, Model 1
      p.k1_n_m = 84183.0;
      p.r1_n_s_m = 5700.0;
      break;
    case ModelKind::Model2:  // Table 2, Model 2; m_eff not published: 40 % of the mat
      p.k1_n_m = 84183.0;
      p.r1_n_s_m = 5700.0;
      p.m_eff_kg = 0.4 * total;
      break;
    case ModelKind::Model3:  // Table 2, Model 3
      p.k1_n_m = 76700.0;
      p.k2_n_m = 807380.0;
      p.r1_n_s_m = 490.0;
      p.r2_n_s_m = 980.0;
      p.m1_kg = m1;
      p.m2_kg = m2;
      break;
    case ModelKind::Model4:  // scanned about Table 2 (this file's header comment)
      p.k1_n_m = 79282.5;
      p.k2_n_m = 849226.0;
      p.k3_n_m = 748625.0;
      p.r1_n_s_m = 131.5;
      p.r2_n_s_m = 380.5;
      p.r3_n_s_m = 503.5;
      p.m1_kg = m1;
      p.m2_kg = m2;
      break;
    case ModelKind::Model5:  // Table 2, Model 5
      p.k1_n_m = 70880.0;
      p.k2_n_m = 787200.0;
      p.k3_n_m = 617120.0;
      p.r1_n_s_m = 260.0;
      p.r2_n_s_m = 280.0;
      p.r3_n_s_m = 850.0;
      p.m1_kg = m1;
      p.m2_kg = m2;
      break;
  }
  return p;
}

// ---- Presets ------------------------------------------------------------------

SynthOptions lab_session_options(std::uint64_t seed) {
  SynthOptions o;
  o.seed = seed;
  o.world = "lab";
  // Impactor and markers.
  o.base_marker_layout = BaseMarkerLayout::DiagonalCorners;
  o.base_marker_height_m = 0.0;
  o.impact_point_sd_m = 0.015;
  o.tilt_random_axis = true;
  o.catch_at_apex = true;
  o.mat_marker_motion = MatMarkerMotion::Dish;
  // Video: one second around the trigger, digitised -0.1 .. +0.15 s about
  // contact with a few 1-5-frame gaps.
  o.n_frames = 1000;
  o.trigger_frame = 500;
  o.digitised_from_s = -0.10;
  o.digitised_to_s = 0.15;
  o.random_gaps_per_trial = 4;
  o.gap_max_frames = 5;
  o.gap_both_cameras_fraction = 0.3;
  o.pixel_noise_px = 0.3;
  o.calibration_pixel_noise_px = 0.2;
  // Force: 5 s records, 10 % before the trigger, 1.5 N per channel.
  o.n_samples = 5000;
  o.pretrigger_fraction = 0.10;
  o.channel_noise_n = 1.5;
  o.effects.baseline_drift_whole_record = true;
  o.effects.maxwell_tau_s = 0.025;
  return o;
}

SynthOptions foam_world_options(std::uint64_t seed) {
  SynthOptions o = lab_session_options(seed);
  o.world = "foam";
  Rng r(seed, 9101);
  auto log_uniform = [&](double lo, double hi) { return lo * std::pow(hi / lo, r.uniform()); };
  auto uniform = [&](double lo, double hi) { return lo + (hi - lo) * r.uniform(); };
  o.impact_velocities_m_s.clear();
  for (int i = 0; i < 5; ++i) o.impact_velocities_m_s.push_back(std::round(uniform(4.0, 6.5) * 100.0) / 100.0);
  const double v_max = *std::max_element(o.impact_velocities_m_s.begin(), o.impact_velocities_m_s.end());
  for (int attempt = 0; attempt < 500; ++attempt) {
    FoamColumn f;
    f.top.thickness_m = std::round(uniform(0.095, 0.13) * 1000.0) / 1000.0;
    f.top.mass_kg = std::round(uniform(2.0, 2.9) * 100.0) / 100.0;
    f.top.plateau_pa = log_uniform(1.5e3, 5e3);
    f.top.modulus_pa = f.top.plateau_pa * uniform(12.0, 30.0);
    f.top.hardening_pa = log_uniform(2.5e4, 8e4);
    f.top.densification_pa = log_uniform(150.0, 1500.0);
    f.top.densification_strain = uniform(0.78, 0.9);
    f.top.densification_exponent = uniform(1.6, 3.0);
    f.base.thickness_m = std::round(uniform(0.06, 0.09) * 1000.0) / 1000.0;
    f.base.mass_kg = std::round(uniform(3.0, 4.2) * 100.0) / 100.0;
    f.base.plateau_pa = log_uniform(3e4, 9e4);
    f.base.modulus_pa = f.base.plateau_pa * uniform(12.0, 25.0);
    f.base.hardening_pa = log_uniform(7e4, 2.5e5);
    f.base.densification_pa = log_uniform(2e3, 1.5e4);
    f.base.densification_strain = uniform(0.72, 0.86);
    f.base.densification_exponent = uniform(1.6, 3.0);
    f.g1 = uniform(0.2, 0.8);
    f.tau1_s = log_uniform(1e-3, 4e-3);
    f.g2 = uniform(0.1, 0.5);
    f.tau2_s = log_uniform(0.02, 0.08);
    f.viscosity_pa_s = log_uniform(100.0, 500.0);
    ChainImpact im;
    im.mass_kg = o.impactor_mass_kg;
    im.velocity_m_s = v_max;
    im.gravity_m_s2 = o.gravity_m_s2;
    im.duration_s = 0.15;
    im.output_dt_s = 1e-4;
    const ChainSimulation sim = simulate_foam_column(f, im);
    const double thickness = f.top.thickness_m + f.base.thickness_m;
    if (!(sim.impactor_m.maxCoeff() < 0.88 * thickness) || !std::isfinite(sim.separation_s)) continue;
    // A landing mat like the paper's: the fastest trial's peak within 25 %
    // and its travel within 20 mm of Table 1 at that speed (interpolated).
    const double tv[5] = {4.30, 4.80, 5.25, 5.75, 6.50}, tf[5] = {5593, 6341, 7054, 8398, 9597},
                 td[5] = {0.088, 0.099, 0.100, 0.113, 0.118};
    auto table = [&](const double* y) {
      const double v = std::clamp(v_max, tv[0], tv[4]);
      int i = 0;
      while (i < 3 && v > tv[i + 1]) ++i;
      return y[i] + (y[i + 1] - y[i]) * (v - tv[i]) / (tv[i + 1] - tv[i]);
    };
    if (std::abs(sim.grf_n.maxCoeff() / table(tf) - 1.0) > 0.25 ||
        std::abs(sim.impactor_m.maxCoeff() - table(td)) > 0.02)
      continue;
    o.foam = f;
    o.layers = {{"top_foam", f.top.thickness_m, f.top.mass_kg}, {"base_foam", f.base.thickness_m, f.base.mass_kg}};
    return o;
  }
  throw Error(fmt::format("foam_world_options: no plausible foam drawn for seed {}", seed));
}

SynthOptions independent_world_options(std::uint64_t seed) {
  SynthOptions o = lab_session_options(seed);
  o.world = "independent";
  Rng r(seed, 9001);
  auto log_uniform = [&](double lo, double hi) { return lo * std::pow(hi / lo, r.uniform()); };
  o.impact_velocities_m_s.clear();
  for (int i = 0; i < 5; ++i) o.impact_velocities_m_s.push_back(std::round((4.0 + 2.2 * r.uniform()) * 100.0) / 100.0);
  const double v_max = *std::max_element(o.impact_velocities_m_s.begin(), o.impact_velocities_m_s.end());
  double thickness = 0.0;
  for (const LayerSpec& l : o.layers) thickness += l.thickness_m;
  const MatParams base = default_mat_params(ModelKind::Model4, o.layers);
  for (int attempt = 0; attempt < 500; ++attempt) {
    MatParams p = base;
    p.k1_n_m = log_uniform(2e4, 1e5);
    p.k2_n_m = log_uniform(5e5, 2e6);
    p.k3_n_m = log_uniform(5e5, 2e6);
    p.r1_n_s_m = log_uniform(30.0, 300.0);
    p.r2_n_s_m = log_uniform(80.0, 800.0);
    p.r3_n_s_m = log_uniform(80.0, 800.0);
    p.k1_cubic_n_m3 = r.uniform() < 0.5 ? 0.0 : 2e6 + 6e6 * r.uniform();
    // Plausible: the fastest trial stays within 75 % of the mat's thickness
    // and the impactor leaves the mat.
    ChainImpact im;
    im.mass_kg = o.impactor_mass_kg;
    im.velocity_m_s = v_max;
    im.gravity_m_s2 = o.gravity_m_s2;
    im.duration_s = 0.3;
    im.output_dt_s = 1e-4;
    im.catch_at_apex = true;
    const ChainSimulation sim = simulate_chain(ModelKind::Model4, p, im);
    if (!(sim.impactor_m.maxCoeff() < 0.75 * thickness) || !std::isfinite(sim.separation_s)) continue;
    o.use_default_params = false;
    o.effects.k1_cubic_n_m3 = p.k1_cubic_n_m3;  // named in the truth as stiffness_nonlinearity
    p.k1_cubic_n_m3 = 0.0;
    o.params = p;
    return o;
  }
  throw Error(fmt::format("independent_world_options: no plausible mat drawn for seed {}", seed));
}

void add_random_effects(SynthOptions& o, std::uint64_t seed) {
  Rng r(seed, 9002);
  const double u = r.uniform();
  const int count = u < 0.25 ? 0 : (u < 0.6 ? 1 : 2 + static_cast<int>(r.uniform() * 3.0));  // 0, 1 or 2-4
  std::vector<int> pool{0, 1, 2, 3, 4, 5, 6, 7};
  Effects& e = o.effects;
  const double record_s = static_cast<double>(o.n_samples) / o.force_rate_hz;
  for (int k = 0; k < count && !pool.empty(); ++k) {
    const std::size_t i = std::min(pool.size() - 1, static_cast<std::size_t>(r.uniform() * pool.size()));
    const int which = pool[i];
    pool.erase(pool.begin() + static_cast<std::ptrdiff_t>(i));
    const double sign = r.uniform() < 0.5 ? -1.0 : 1.0;
    switch (which) {
      case 0:
        e.lens_distortion_px = 0.7 + 0.8 * r.uniform();
        break;
      case 1:
        e.outlier_swap = true;
        break;
      case 2:
        e.time_offset_ms = sign * (1.0 + 3.0 * r.uniform());
        break;
      case 3:
        e.baseline_drift_n_s = sign * (10.0 + 30.0 * r.uniform()) / record_s;  // 10-40 N over the record
        e.baseline_drift_whole_record = true;
        break;
      case 4:
        e.force_scale = 1.0 + sign * (0.03 + 0.04 * r.uniform());
        break;
      case 5:
        e.hysteresis_h = 0.15 + 0.15 * r.uniform();
        break;
      case 6:
        e.maxwell_k_n_m = 25000.0 + 5000.0 * r.uniform();
        e.maxwell_tau_s = 0.020 + 0.010 * r.uniform();
        break;
      case 7:
        e.layer_mass_shift_kg = sign * (0.5 + 0.7 * r.uniform());
        break;
    }
  }
}

}  // namespace dropfit::synth
