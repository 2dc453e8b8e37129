// dropfit-synth: writes a synthetic drop-test session with known truth.
//
//   dropfit-synth --out SESSION_DIR --truth FILE [--seed N] [--model 1..5]
//                 [--effect name=magnitude ...] [--frames N --samples N]
//
// The session folder follows shared/spec/session-format.md (written by
// capture::write_session); the truth JSON goes elsewhere (keep it out of
// the session folder: nothing in there may reveal the injected effects).
#include <CLI/CLI.hpp>
#include <fmt/format.h>

#include <exception>
#include <filesystem>
#include <string>
#include <vector>

#include "capture/io.h"
#include "core/error.h"
#include "samples/generator/synth.h"

namespace {

// "name=magnitude" -> set on the effects; throws dropfit::Error.
void parse_effect(dropfit::synth::Effects& effects, const std::string& text) {
  const auto eq = text.find('=');
  if (eq == std::string::npos || eq == 0 || eq + 1 == text.size())
    throw dropfit::Error(fmt::format("--effect '{}': expected name=magnitude", text));
  const std::string name = text.substr(0, eq);
  const std::string value = text.substr(eq + 1);
  double magnitude = 0.0;
  std::size_t used = 0;
  try {
    magnitude = std::stod(value, &used);
  } catch (const std::exception&) {
    used = 0;
  }
  if (used != value.size()) throw dropfit::Error(fmt::format("--effect '{}': '{}' is not a number", text, value));
  dropfit::synth::set_effect(effects, name, magnitude);
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

}  // namespace

int main(int argc, char** argv) {
  namespace fs = std::filesystem;
  using dropfit::synth::SynthOptions;
  SynthOptions o;
  std::string out_dir, truth_path;
  int model = 4;
  std::vector<std::string> effects, gaps;
  bool drift_whole = false;

  CLI::App app{"dropfit-synth: a synthetic drop-test session with known truth"};
  app.add_option("--out", out_dir, "session folder to create (must not exist or be empty)")->required();
  app.add_option("--truth", truth_path, "truth JSON to write (outside the session folder)")->required();
  app.add_option("--seed", o.seed, "random seed")->capture_default_str();
  app.add_option("--model", model, "mat model 1..5 (paper's Models 1-5)")->check(CLI::Range(1, 5))->capture_default_str();
  app.add_option("--effect", effects,
                 "inject an effect: name=magnitude; names: lens_distortion (k1), outlier_marker (px), time_offset (ms), "
                 "baseline_drift (N/s), force_scale (gain), stiffness_nonlinearity (k1_cubic N/m^3), hysteresis "
                 "(r1_unload N s/m), rate_dependence (Maxwell k N/m), layer_mass (kg moved to the top layer)");
  app.add_option("--maxwell-tau", o.effects.maxwell_tau_s, "time constant of the rate_dependence Maxwell arm (s)")
      ->capture_default_str();
  app.add_flag("--drift-whole-record", drift_whole, "baseline_drift ramps from the first sample, not the trigger");
  app.add_option("--velocities", o.impact_velocities_m_s, "impact velocities, one trial each (m/s)")
      ->capture_default_str();
  app.add_option("--frames", o.n_frames, "video frames per trial")->capture_default_str();
  app.add_option("--trigger-frame", o.trigger_frame, "0-based frame at the force trigger")->capture_default_str();
  app.add_option("--samples", o.n_samples, "force samples per trial")->capture_default_str();
  app.add_option("--pixel-noise", o.pixel_noise_px, "pixel noise SD (px)")->capture_default_str();
  app.add_option("--channel-noise", o.channel_noise_n, "force channel noise SD (N)")->capture_default_str();
  app.add_option("--gap", gaps, "hide a marker: TRIAL:POINT:CAMERA:FIRST:COUNT (1-based trial and camera, 0 = all)");
  CLI11_PARSE(app, argc, argv);

  try {
    o.model = static_cast<dropfit::fitting::ModelKind>(model);
    for (const std::string& e : effects) parse_effect(o.effects, e);
    o.effects.baseline_drift_whole_record = drift_whole;
    for (const std::string& g : gaps) o.gaps.push_back(parse_gap(g));

    std::error_code ec;
    if (fs::exists(out_dir, ec) && !(fs::is_directory(out_dir, ec) && fs::is_empty(out_dir, ec)))
      throw dropfit::Error(fmt::format("{} exists and is not an empty folder; remove it first", out_dir));
    const fs::path truth_abs = fs::absolute(truth_path).lexically_normal();
    const fs::path out_abs = fs::absolute(out_dir).lexically_normal();
    const auto rel = truth_abs.lexically_relative(out_abs);
    if (!rel.empty() && *rel.begin() != "..")
      throw dropfit::Error("--truth must lie outside the session folder (it names the injected effects)");

    dropfit::synth::SyntheticSession s = dropfit::synth::make_session(o);
    s.session.root = out_dir;
    dropfit::capture::write_session(out_dir, s.session);
    dropfit::synth::write_truth_json(truth_path, s.truth);
    fmt::print("wrote {} ({} trials, model{}, {} effects) and {}\n", out_dir, s.session.trials.size(), model,
               s.truth.effects.size(), truth_path);
  } catch (const std::exception& e) {
    fmt::print(stderr, "dropfit-synth: error: {}\n", e.what());
    return 1;
  }
  return 0;
}
