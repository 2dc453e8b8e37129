// dropfit-synth: writes a synthetic drop-test session with known truth.
//
//   dropfit-synth --out SESSION_DIR --truth FILE [--world lab|independent|classic]
//                 [--seed N] [--model 1..4] [--effect name=magnitude ...]
//                 [--fault name=magnitude ...] [--random-effects] [... every option of SynthOptions: --help]
//
// The session folder follows docs/formats.md (written by
// capture::write_session); the truth JSON goes elsewhere (keep it out of
// the session folder: nothing in there may reveal the injected effects).
#include <CLI/CLI.hpp>
#include <fmt/format.h>
#include <fmt/ranges.h>

#include <cstdint>
#include <exception>
#include <filesystem>
#include <string>
#include <utility>
#include <vector>

#include "capture/io.h"
#include "core/error.h"
#include "samples/generator/synth.h"

namespace {

// "name=magnitude" of --effect or --fault (`option`) -> (name, magnitude); throws dropfit::Error.
std::pair<std::string, double> parse_magnitude(const std::string& option, const std::string& text) {
  const auto eq = text.find('=');
  if (eq == std::string::npos || eq == 0 || eq + 1 == text.size())
    throw dropfit::Error(fmt::format("{} '{}': expected name=magnitude", option, text));
  const std::string name = text.substr(0, eq);
  const std::string value = text.substr(eq + 1);
  double magnitude = 0.0;
  std::size_t used = 0;
  try {
    magnitude = std::stod(value, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != value.size()) throw dropfit::Error(fmt::format("{} '{}': '{}' is not a number", option, text, value));
  return {name, magnitude};
}

// "TRIAL:POINT:CAMERA:FIRST:COUNT" (trial and camera 1-based, camera 0 = all).
dropfit::synth::Gap parse_gap(const std::string& text) {
  std::vector<std::string> f;
  std::size_t start = 0;
  for (std::size_t i = 0; i <= text.size(); ++i)
    if (i == text.size() || text[i] == ':') {
      f.push_back(text.substr(start, i - start));
      start = i + 1;
    }
  if (f.size() != 5) throw dropfit::Error(fmt::format("--gap '{}': expected TRIAL:POINT:CAMERA:FIRST:COUNT", text));
  try {
    dropfit::synth::Gap g;
    g.trial = std::stoi(f[0]) - 1;
    g.point = f[1];
    g.camera = std::stoi(f[2]) - 1;
    g.first_frame = std::stoi(f[3]);
    g.n_frames = std::stoi(f[4]);
    return g;
  } catch (const std::exception&) {
    throw dropfit::Error(fmt::format("--gap '{}': TRIAL, CAMERA, FIRST and COUNT must be integers", text));
  }
}

// The value following `name` in argv (the preset must exist before the
// other options are bound to its fields), or empty.
std::string prescan(int argc, char** argv, const std::string& name) {
  for (int i = 1; i < argc; ++i) {
    const std::string a = argv[i];
    if (a == name && i + 1 < argc) return argv[i + 1];
    if (a.rfind(name + "=", 0) == 0) return a.substr(name.size() + 1);
  }
  return {};
}

// "name=value" for a mat parameter (k1_n_m, r2_n_s_m, m1_kg, ...).
void parse_param(dropfit::synth::MatParams& p, const std::string& text) {
  const auto eq = text.find('=');
  if (eq == std::string::npos) throw dropfit::Error(fmt::format("--param '{}': expected name=value", text));
  const std::string name = text.substr(0, eq);
  double value = 0.0;
  try {
    std::size_t used = 0;
    value = std::stod(text.substr(eq + 1), &used);
    if (used != text.size() - eq - 1) throw std::invalid_argument("trailing");
  } catch (const std::exception&) {
    throw dropfit::Error(fmt::format("--param '{}': '{}' is not a number", text, text.substr(eq + 1)));
  }
  double* field = nullptr;
  if (name == "k1_n_m") field = &p.k1_n_m;
  if (name == "k2_n_m") field = &p.k2_n_m;
  if (name == "k3_n_m") field = &p.k3_n_m;
  if (name == "r1_n_s_m") field = &p.r1_n_s_m;
  if (name == "r2_n_s_m") field = &p.r2_n_s_m;
  if (name == "r3_n_s_m") field = &p.r3_n_s_m;
  if (name == "m_eff_kg") field = &p.m_eff_kg;
  if (name == "m1_kg") field = &p.m1_kg;
  if (name == "m2_kg") field = &p.m2_kg;
  if (!field)
    throw dropfit::Error(fmt::format("--param '{}': unknown parameter (k1_n_m k2_n_m k3_n_m r1_n_s_m r2_n_s_m r3_n_s_m "
                                     "m_eff_kg m1_kg m2_kg)",
                                     text));
  *field = value;
}

// The command-line values that are not fields of SynthOptions (applied after parsing).
struct CliValues {
  std::string out_dir, truth_path, world;
  int model = 1;
  std::vector<std::string> effects, faults, gaps, params;
  bool drift_whole = false, random_effects = false;
  std::string mat_markers, base_markers;
  std::vector<double> window;
};

// The options of the world preset chosen by --world and --seed (prescanned); false after printing an error.
bool preset_options(int argc, char** argv, std::string& world, dropfit::synth::SynthOptions& o) {
  // The world preset first (every other option starts from its values).
  world = prescan(argc, argv, "--world");
  if (world.empty()) world = "lab";
  std::uint64_t seed = 1;
  const std::string seed_text = prescan(argc, argv, "--seed");
  if (!seed_text.empty()) {
    try {
      seed = std::stoull(seed_text);
    } catch (const std::exception&) {
      fmt::print(stderr, "dropfit-synth: error: --seed '{}' is not a non-negative integer\n", seed_text);
      return false;
    }
  }
  try {
    if (world == "classic")
      o.seed = seed;
    else if (world == "lab")
      o = dropfit::synth::lab_session_options(seed);
    else if (world == "independent")
      o = dropfit::synth::independent_world_options(seed);
    else if (world == "foam")
      o = dropfit::synth::foam_world_options(seed);
    else
      throw dropfit::Error(fmt::format("--world '{}': expected classic, lab, independent or foam", world));
  } catch (const std::exception& e) {
    fmt::print(stderr, "dropfit-synth: error: {}\n", e.what());
    return false;
  }
  return true;
}

// The CLI values' defaults, taken from the preset's options.
void init_cli_values(const dropfit::synth::SynthOptions& o, CliValues& v) {
  v.model = o.model.number;
  v.drift_whole = o.effects.baseline_drift_whole_record;
  v.random_effects = false;
  v.mat_markers = o.mat_marker_motion == dropfit::synth::MatMarkerMotion::Dish ? "dish" : "surface";
  v.base_markers = o.base_marker_layout == dropfit::synth::BaseMarkerLayout::DiagonalCorners ? "corners" : "front-back";
  v.window = {o.digitised_from_s, o.digitised_to_s};
}

// Options for the outputs, world, seed, model, parameters and effects.
void add_run_options(CLI::App& app, CliValues& v, dropfit::synth::SynthOptions& o) {
  app.add_option("--out", v.out_dir, "session folder to create (must not exist or be empty)")->required();
  app.add_option("--truth", v.truth_path, "truth JSON to write (outside the session folder)")->required();
  app.add_option("--world", v.world,
                 "preset: lab (default: a realistic lab session, generator's default mat), independent (lab with a "
                 "random plausible mat and impact speeds drawn from the seed), foam (lab on a random foam column: a "
                 "continuum mat), classic (the older tests' world)")
      ->capture_default_str();
  app.add_option("--seed", o.seed, "random seed")->capture_default_str();
  app.add_option("--model", v.model, "mat model 1..4 (paper's Models 1-4; Model 5 is not generated)")
      ->check(CLI::Range(1, 4))
      ->capture_default_str();
  app.add_option("--param", v.params, "a true mat parameter: name=value (k1_n_m, r1_n_s_m, m1_kg, ...); repeatable");
  app.add_option("--effect", v.effects,
                 "inject an effect: name=magnitude; names: lens_distortion (k1), lens_distortion_px (px at the "
                 "outermost trial marker), outlier_marker (px), outlier_swap (1: two fit markers swapped in cam2), "
                 "time_offset (ms, video clock ahead), baseline_drift (N/s), force_scale (gain), "
                 "stiffness_nonlinearity (k1_cubic N/m^3), hysteresis (r1_unload N s/m: extra damping), "
                 "hysteresis_elastic (h: elastic force (1-h) lower while unloading), rate_dependence (Maxwell k N/m), "
                 "layer_mass (kg moved to the top layer)");
  app.add_option("--fault", v.faults,
                 "inject an instrument fault: name=magnitude; names: dead_channel, reversed_channel (channel 0-7: "
                 "Fx12 Fx34 Fy14 Fy23 Fz1 Fz2 Fz3 Fz4), exchanged_channels (two digits: 47 exchanges channels 4 and "
                 "7), saturation (N per channel), amplifier_lowpass (Hz: Butterworth corner before sampling), "
                 "softening (stiffness fraction lost per trial), declared_mass (kg in the manifest), second_impact "
                 "(1: not caught, lands again)");
  app.add_option("--lowpass-order", o.faults.amplifier_lowpass_order, "order of the amplifier_lowpass fault (2 or 4)")
      ->check(CLI::IsMember({2, 4}))
      ->capture_default_str();
  app.add_flag("--random-effects", v.random_effects, "add a random mix of effects (none, one or several) from the seed");
  app.add_option("--maxwell-tau", o.effects.maxwell_tau_s, "time constant of the rate_dependence Maxwell arm (s)")
      ->capture_default_str();
  app.add_option("--hysteresis-transition", o.effects.hysteresis_transition_m_s,
                 "v_h of hysteresis_elastic's tanh switch (m/s)")
      ->capture_default_str();
  app.add_flag("--drift-whole-record,!--drift-from-trigger", v.drift_whole,
               "baseline_drift ramps from the first sample (else from the trigger)");
}

// Options for the trials: velocities, video frames, gaps, force samples and noise.
void add_trial_options(CLI::App& app, CliValues& v, dropfit::synth::SynthOptions& o) {
  app.add_option("--velocities", o.impact_velocities_m_s, "impact velocities, one trial each (m/s)")
      ->capture_default_str();
  app.add_option("--frames", o.n_frames, "video frames per trial")->capture_default_str();
  app.add_option("--trigger-frame", o.trigger_frame, "0-based frame at the force trigger")->capture_default_str();
  app.add_option("--window", v.window, "digitised window FROM TO (s about contact; NaN outside)")
      ->expected(2)
      ->capture_default_str();
  app.add_option("--random-gaps", o.random_gaps_per_trial, "random 1..--gap-max-frames gaps per trial")
      ->capture_default_str();
  app.add_option("--gap-max-frames", o.gap_max_frames, "longest random gap (frames)")->capture_default_str();
  app.add_option("--gap-both-fraction", o.gap_both_cameras_fraction, "share of random gaps in both cameras")
      ->capture_default_str();
  app.add_option("--samples", o.n_samples, "force samples per trial")->capture_default_str();
  app.add_option("--pretrigger-fraction", o.pretrigger_fraction, "share of the force record before the trigger")
      ->capture_default_str();
  app.add_option("--pixel-noise", o.pixel_noise_px, "marker pixel noise SD (px)")->capture_default_str();
  app.add_option("--calibration-noise", o.calibration_pixel_noise_px,
                 "calibration pixel noise SD (px; negative = --pixel-noise)")
      ->capture_default_str();
  app.add_option("--channel-noise", o.channel_noise_n, "force channel noise SD (N)")->capture_default_str();
}

// Options for the markers, impact point and tilt, and the explicit gaps.
void add_marker_options(CLI::App& app, CliValues& v, dropfit::synth::SynthOptions& o) {
  app.add_option("--mat-markers", v.mat_markers, "surface (follow the mat top under the impactor) or dish (top layer x w)")
      ->check(CLI::IsMember({"surface", "dish"}))
      ->capture_default_str();
  app.add_option("--mat-marker-radius", o.mat_marker_min_radius_m, "dish markers: least distance from the centre (m)")
      ->capture_default_str();
  app.add_option("--mat-marker-radius-max", o.mat_marker_max_radius_m, "dish markers: largest distance (m)")
      ->capture_default_str();
  app.add_option("--base-markers", v.base_markers, "front-back or corners (the face's diagonal corners)")
      ->check(CLI::IsMember({"front-back", "corners"}))
      ->capture_default_str();
  app.add_option("--base-marker-height", o.base_marker_height_m, "base markers above the face (m)")
      ->capture_default_str();
  app.add_option("--impact-scatter", o.impact_point_sd_m, "impact point SD about the plate centre, per axis (m)")
      ->capture_default_str();
  app.add_option("--tilt-mean", o.tilt_mean_deg, "impactor tilt mean (deg)")->capture_default_str();
  app.add_option("--tilt-sd", o.tilt_sd_deg, "impactor tilt SD (deg)")->capture_default_str();
  app.add_flag("--tilt-random-axis,!--tilt-about-y", o.tilt_random_axis, "tilt about a random horizontal axis")
      ->capture_default_str();
  app.add_flag("--catch-at-apex,!--free-rebound", o.catch_at_apex,
               "the impactor is caught at the top of its rebound (else it may land again)")
      ->capture_default_str();
  app.add_option("--gap", v.gaps, "hide a marker: TRIAL:POINT:CAMERA:FIRST:COUNT (1-based trial and camera, 0 = all)");
}

// Applies the parsed CLI values to the options; throws dropfit::Error.
void apply_cli_values(const CliValues& v, dropfit::synth::SynthOptions& o) {
  o.model = static_cast<dropfit::synth::ModelKind>(v.model);
  if (!v.params.empty()) {
    if (o.use_default_params) o.params = dropfit::synth::default_mat_params(o.model, o.layers);
    o.use_default_params = false;
    for (const std::string& p : v.params) parse_param(o.params, p);
  }
  if (v.random_effects) dropfit::synth::add_random_effects(o, o.seed);
  for (const std::string& e : v.effects) {
    const auto [name, magnitude] = parse_magnitude("--effect", e);
    dropfit::synth::set_effect(o.effects, name, magnitude);
  }
  for (const std::string& f : v.faults) {
    const auto [name, magnitude] = parse_magnitude("--fault", f);
    dropfit::synth::set_fault(o, name, magnitude);
  }
  o.effects.baseline_drift_whole_record = v.drift_whole;
  for (const std::string& g : v.gaps) o.gaps.push_back(parse_gap(g));
  o.mat_marker_motion =
      v.mat_markers == "dish" ? dropfit::synth::MatMarkerMotion::Dish : dropfit::synth::MatMarkerMotion::FollowSurface;
  o.base_marker_layout = v.base_markers == "corners" ? dropfit::synth::BaseMarkerLayout::DiagonalCorners
                                                   : dropfit::synth::BaseMarkerLayout::FrontBack;
  o.digitised_from_s = v.window[0];
  o.digitised_to_s = v.window[1];

}

// Refuses a non-empty output folder and a truth file inside it; throws dropfit::Error.
void check_output_paths(const std::string& out_dir, const std::string& truth_path) {
  namespace fs = std::filesystem;
  std::error_code ec;
  if (fs::exists(out_dir, ec) && !(fs::is_directory(out_dir, ec) && fs::is_empty(out_dir, ec)))
    throw dropfit::Error(fmt::format("{} exists and is not an empty folder; remove it first", out_dir));
  const fs::path truth_abs = fs::absolute(truth_path).lexically_normal();
  const fs::path out_abs = fs::absolute(out_dir).lexically_normal();
  const auto rel = truth_abs.lexically_relative(out_abs);
  if (!rel.empty() && *rel.begin() != "..")
    throw dropfit::Error("--truth must lie outside the session folder (it names the injected effects)");

}

}  // namespace

int main(int argc, char** argv) {
  using dropfit::synth::SynthOptions;
  SynthOptions o;
  CliValues v;
  if (!preset_options(argc, argv, v.world, o)) return 1;
  init_cli_values(o, v);

  CLI::App app{"dropfit-synth: a synthetic drop-test session with known truth"};
  add_run_options(app, v, o);
  add_trial_options(app, v, o);
  add_marker_options(app, v, o);
  CLI11_PARSE(app, argc, argv);

  try {
    apply_cli_values(v, o);
    check_output_paths(v.out_dir, v.truth_path);
    dropfit::synth::SyntheticSession s = dropfit::synth::make_session(o);
    s.session.root = v.out_dir;
    dropfit::capture::write_session(v.out_dir, s.session);
    dropfit::synth::write_truth_json(v.truth_path, s.truth);
    std::vector<std::string> names;
    for (const auto& e : s.truth.effects) names.push_back(e.name);
    fmt::print("wrote {} ({} world, {} trials, model{}, effects: {}) and {}\n", v.out_dir, o.world,
               s.session.trials.size(), v.model, names.empty() ? "none" : fmt::format("{}", fmt::join(names, " ")),
               v.truth_path);
  } catch (const std::exception& e) {
    fmt::print(stderr, "dropfit-synth: error: {}\n", e.what());
    return 1;
  }
  return 0;
}
